"""How far any verdict could go on the poses an evaluation returned (issue 35; docs/experiments/verdict-bound.md).

A verdict that trusts a pose should trust every pose the scans support at least as well: as many inliers or more,
as high an inlier ratio, as large a share of points on the other scan's first surface, no more in its seen-empty
space. Call such a verdict monotone. Then the trusted poses form an up-set of the "supported at least as well"
order, and two bounds follow from `dpr-gpu eval`'s report alone, whatever thresholds or combination a verdict uses:

- with no trusted wrong pose, every right pose that some wrong pose is supported at least as well as stays
  untrusted: the least number of untrusted right poses;
- with at most one untrusted right pose, every wrong pose supported at least as well as a trusted right one is
  trusted: the least number of trusted wrong poses (the right pose left out chosen to make it least).

    python benches/compare/verdict_bound.py REPORT.json [REPORT.json ...] [--stats inliers,ratio,agree,violate]

Statistics (per pair, from the report's run): `inliers` (the estimator's), `ratio` (inliers over
correspondences), `agree` and `violate` (the free-space shares), `violate_explained` (only in reports of builds
that record it). A pair is named `SCENE SOURCE>TARGET` (fragment j onto fragment i of gt.log). Pairs without
the statistics (no pose, an error) are left out and counted. Standard library only.
"""
import argparse
import json
import sys

HIGHER_IS_BETTER = {"inliers": True, "ratio": True, "agree": True, "violate": False, "violate_explained": False}


def support(run, stats):
    """The pair's statistics as a tuple where larger is better in every place; None when one is missing."""
    free_space = run.get("free_space") or {}
    inliers = run.get("estimator_inliers")
    values = {
        "inliers": inliers,
        "ratio": None if inliers is None else inliers / max(1, run.get("correspondences") or 0),
        "agree": free_space.get("agree"),
        "violate": free_space.get("violate"),
        "violate_explained": free_space.get("violate_explained"),
    }
    if any(values[s] is None for s in stats):
        return None
    return tuple(values[s] if HIGHER_IS_BETTER[s] else -values[s] for s in stats)


def at_least_as_supported(a, b):
    return all(x >= y for x, y in zip(a, b))


def bounds(poses):
    """`poses`: (name, trusted, right, support) tuples. The counts today and the two bounds of the module text."""
    right = [p for p in poses if p[2]]
    wrong = [p for p in poses if not p[2]]
    outsupported_by = [[w[0] for w in wrong if at_least_as_supported(w[3], r[3])] for r in right]

    def wrong_trusted_with(trusted_right):
        return [w for w in wrong if any(at_least_as_supported(w[3], r[3]) for r in trusted_right)]

    least_tw = min((len(wrong_trusted_with([r for r in right if r is not out])) for out in right), default=0)
    today = {
        "trusted_right": sum(1 for p in right if p[1]),
        "trusted_wrong": sum(1 for p in wrong if p[1]),
        "untrusted_right": sum(1 for p in right if not p[1]),
        "untrusted_wrong": sum(1 for p in wrong if not p[1]),
    }
    untrustable = [
        {"pair": r[0], "trusted_today": r[1], "outsupported_by": by} for r, by in zip(right, outsupported_by) if by
    ]
    return today, len(untrustable), least_tw, untrustable


def poses_of(estimator, stats):
    poses, left_out = [], 0
    for scene in estimator["scenes"]:
        for pair in scene["pairs"]:
            if not pair.get("in_gt") or pair.get("success") is None:
                continue
            run = pair.get("run") or {}
            s = support(run, stats) if run.get("trusted") is not None else None
            if s is None:
                left_out += 1
                continue
            poses.append((f"{scene['scene']} {pair['j']}>{pair['i']}", bool(run["trusted"]), bool(pair["success"]), s))
    return poses, left_out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("reports", nargs="+")
    parser.add_argument("--stats", default="inliers,ratio,agree,violate")
    args = parser.parse_args()
    stats = args.stats.split(",")
    unknown = [s for s in stats if s not in HIGHER_IS_BETTER]
    if unknown:
        sys.exit(f"unknown statistics {unknown}; known: {sorted(HIGHER_IS_BETTER)}")
    for path in args.reports:
        with open(path) as f:
            report = json.load(f)
        for estimator in report["estimators"]:
            poses, left_out = poses_of(estimator, stats)
            today, least_ur, least_tw, untrustable = bounds(poses)
            row = dict(report=path, estimator=estimator["estimator"], stats=stats, pairs=len(poses), left_out=left_out,
                       today=today, least_untrusted_right_with_no_trusted_wrong=least_ur,
                       least_trusted_wrong_with_at_most_one_untrusted_right=least_tw, untrustable=untrustable)
            print(json.dumps(row))


if __name__ == "__main__":
    main()
