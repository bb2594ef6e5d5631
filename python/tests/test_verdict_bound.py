"""benches/compare/verdict_bound.py's two bounds against a search over every monotone verdict of small sets."""
import importlib.util
import itertools
import random
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "benches" / "compare" / "verdict_bound.py"
spec = importlib.util.spec_from_file_location("verdict_bound", SCRIPT)
verdict_bound = importlib.util.module_from_spec(spec)
spec.loader.exec_module(verdict_bound)


def searched_bounds(poses):
    """Every trusted set closed upwards under "supported at least as well" (every monotone verdict), searched."""
    n = len(poses)
    best_ur, best_tw = n + 1, n + 1
    for trust in itertools.product((False, True), repeat=n):
        closed = all(
            trust[j]
            for i in range(n) if trust[i]
            for j in range(n) if verdict_bound.at_least_as_supported(poses[j][3], poses[i][3])
        )
        if not closed:
            continue
        tw = sum(1 for k in range(n) if trust[k] and not poses[k][2])
        ur = sum(1 for k in range(n) if not trust[k] and poses[k][2])
        if tw == 0:
            best_ur = min(best_ur, ur)
        if ur <= 1:
            best_tw = min(best_tw, tw)
    return best_ur, best_tw


def test_bounds_match_a_search_over_every_monotone_verdict():
    rng = random.Random(35)
    for case in range(300):
        n, dims = rng.randint(1, 9), rng.randint(1, 3)
        poses = [
            (f"p{k}", rng.random() < 0.5, rng.random() < 0.5, tuple(rng.randint(0, 3) for _ in range(dims)))
            for k in range(n)
        ]
        _, least_ur, least_tw, untrustable = verdict_bound.bounds(poses)
        assert (least_ur, least_tw) == searched_bounds(poses), (case, poses)
        assert len(untrustable) == least_ur


def test_support_orders_every_statistic_so_larger_is_better():
    run = {"estimator_inliers": 12, "correspondences": 200, "free_space": {"agree": 0.3, "violate": 0.02}}
    fewer = {"estimator_inliers": 12, "correspondences": 200, "free_space": {"agree": 0.3, "violate": 0.05}}
    stats = ["inliers", "ratio", "agree", "violate"]
    a, b = verdict_bound.support(run, stats), verdict_bound.support(fewer, stats)
    assert verdict_bound.at_least_as_supported(a, b) and not verdict_bound.at_least_as_supported(b, a)
    assert verdict_bound.support({"estimator_inliers": 3}, stats) is None
