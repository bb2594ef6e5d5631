#!/usr/bin/env python3
"""The cost curve of `dpr-gpu register`: wall time, stage times and peak memory (the process's high-water
resident set, from wait4) for clouds of 10k to 5M points and for 250 to 5,000 keypoints.

Each size registers a seeded synthetic pair written as binary PLY (a room: floor, two walls, boxes and balls,
points spread uniformly over the surfaces, no normals; the target is the source scene seen from another pose,
cut to about 70 % overlap), so the figures need no data from outside the repository. Every run is one round
(`--first-keypoints 0 --context-radius off`): the curve measures the work, not how early the verdict
trusts.

    python3 benches/cost_curve.py --binary target/release/dpr-gpu [--points 10000,100000,1000000,5000000] \
        [--keypoints 250,500,1000,2500,5000] [--keypoint-cloud 100000] [--extra-args "--backend cpu"] \
        [--markdown] [--workdir DIR]

Needs numpy. Prints one JSON line per run (and a Markdown table with --markdown). The clouds are made by a
child Python process, so the launcher stays small: Linux counts the launcher's resident set into a spawned
child's high-water mark, so the peak memory reported includes at most the launcher's ~10 MiB.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time


def scene(rng, n: int):
    """n points on a 6 x 5 x 3 m room's floor and two walls, with 8 boxes and 5 balls, uniform by area."""
    boxes = [(rng.uniform([0.3, 0.3, 0.0], [5.0, 4.0, 0.0]), rng.uniform([0.3, 0.3, 0.3], [1.2, 1.0, 1.5])) for _ in range(8)]
    balls = [(rng.uniform([0.5, 0.5, 0.2], [5.5, 4.5, 1.5]), rng.uniform(0.15, 0.4)) for _ in range(5)]
    # (area, sampler) per surface
    surfaces = [
        (30.0, lambda k: np.c_[rng.uniform(0, 6, k), rng.uniform(0, 5, k), np.zeros(k)]),
        (18.0, lambda k: np.c_[rng.uniform(0, 6, k), np.zeros(k), rng.uniform(0, 3, k)]),
        (15.0, lambda k: np.c_[np.zeros(k), rng.uniform(0, 5, k), rng.uniform(0, 3, k)]),
    ]
    for corner, size in boxes:
        for axis in range(3):
            for side in (0.0, 1.0):
                a, b = [d for d in range(3) if d != axis]

                def face(k, corner=corner, size=size, axis=axis, side=side, a=a, b=b):
                    p = np.empty((k, 3))
                    p[:, axis] = corner[axis] + side * size[axis]
                    p[:, a] = corner[a] + rng.uniform(0, size[a], k)
                    p[:, b] = corner[b] + rng.uniform(0, size[b], k)
                    return p

                surfaces.append((size[a] * size[b], face))
    for centre, r in balls:

        def ball(k, centre=centre, r=r):
            v = rng.normal(size=(k, 3))
            return centre + r * v / np.linalg.norm(v, axis=1, keepdims=True)

        surfaces.append((4 * math.pi * r * r, ball))
    areas = np.array([s[0] for s in surfaces])
    counts = rng.multinomial(n, areas / areas.sum())
    return np.concatenate([s[1](k) for s, k in zip(surfaces, counts) if k > 0])


def rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def write_ply(path: str, points) -> None:
    with open(path, "wb") as f:
        f.write(b"ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(points))
        f.write(b"property float x\nproperty float y\nproperty float z\nend_header\n")
        f.write(points.astype("<f4").tobytes())


def make_pair(folder: str, n: int, seed: int):
    """source_n.ply / target_n.ply of about n points each, the target moved by a known pose, written by a child
    process; returns the paths."""
    subprocess.run([sys.executable, os.path.abspath(__file__), "--generate", str(n), str(seed), folder], check=True)
    return os.path.join(folder, f"source_{n}.ply"), os.path.join(folder, f"target_{n}.ply")


def generate(n: int, seed: int, folder: str) -> None:
    """The child's work: the pair of `make_pair`."""
    rng = np.random.default_rng(seed)
    room = scene(rng, int(n / 0.7))
    source = room[room[:, 0] < 6 * 0.7][:n]
    target = room[room[:, 0] > 6 * 0.3][:n]
    moved = target @ rotation(rng).T + rng.uniform(-1, 1, 3)
    write_ply(os.path.join(folder, f"source_{n}.ply"), source)
    write_ply(os.path.join(folder, f"target_{n}.ply"), moved)


def run_measured(binary: str, paths, keypoints: int, extra: str):
    cmd = [binary, "register", *paths, "--json", "--first-keypoints", "0", "--context-radius", "off",
           "--keypoints", str(keypoints), *extra.split()]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        started = time.perf_counter()
        pid = os.posix_spawn(cmd[0], cmd, dict(os.environ), file_actions=[
            (os.POSIX_SPAWN_DUP2, out.fileno(), 1), (os.POSIX_SPAWN_DUP2, err.fileno(), 2)])
        _, status, usage = os.wait4(pid, 0)
        wall = time.perf_counter() - started
        out.seek(0)
        err.seek(0)
        code = os.waitstatus_to_exitcode(status)
        if code not in (0, 3):  # 3: a pose the verdict does not trust, still reported
            raise SystemExit(f"{' '.join(cmd)} failed ({code}): {err.read().decode()[-2000:]}")
        report = json.loads(out.read())
    stages = {}
    for t in report["timings"]:
        key = t["stage"].split(".")[-1]
        stages[key] = round(stages.get(key, 0.0) + t["seconds"], 3)
    return {
        "points": None,
        "keypoints": keypoints,
        "wall_seconds": round(wall, 3),
        "peak_rss_mib": round(usage.ru_maxrss / 1024, 1),
        "success": report["success"],
        "radius": round(report["scale"]["radius"], 4),
        "stages": stages,
    }


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--generate":
        global np
        import numpy as np

        generate(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4])
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--binary", default="target/release/dpr-gpu")
    parser.add_argument("--points", default="10000,100000,1000000,5000000")
    parser.add_argument("--keypoints", default="250,500,1000,2500,5000")
    parser.add_argument("--cloud-keypoints", type=int, default=250, help="keypoints of the points sweep")
    parser.add_argument("--keypoint-cloud", type=int, default=100000, help="points per scan of the keypoint sweep")
    parser.add_argument("--extra-args", default="")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", help="where the clouds go (default: a temporary folder, removed)")
    parser.add_argument("--markdown", action="store_true")
    args = parser.parse_args()
    binary = os.path.abspath(args.binary)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.workdir or tmp
        os.makedirs(folder, exist_ok=True)
        for n in [int(v) for v in args.points.split(",") if v]:
            paths = make_pair(folder, n, args.seed)
            row = run_measured(binary, paths, args.cloud_keypoints, args.extra_args)
            row["points"] = n
            rows.append(("points", row))
            print(json.dumps({"sweep": "points", **row}), flush=True)
        paths = make_pair(folder, args.keypoint_cloud, args.seed)
        for k in [int(v) for v in args.keypoints.split(",") if v]:
            row = run_measured(binary, paths, k, args.extra_args)
            row["points"] = args.keypoint_cloud
            rows.append(("keypoints", row))
            print(json.dumps({"sweep": "keypoints", **row}), flush=True)
    if args.markdown:
        keys = ["load", "downsample", "normals", "patches", "ppf_encoder", "matching", "pc_encoder", "estimation"]
        seen = [k for k in keys if any(k in r["stages"] for _, r in rows)]
        print("\n| sweep | points per scan | keypoints | wall s | peak MiB | " + " | ".join(seen) + " |")
        print("|---" * (5 + len(seen)) + "|")
        for sweep, r in rows:
            cells = [str(r["stages"].get(k, "")) for k in seen]
            print(f"| {sweep} | {r['points']:,} | {r['keypoints']:,} | {r['wall_seconds']} | {r['peak_rss_mib']} | "
                  + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
