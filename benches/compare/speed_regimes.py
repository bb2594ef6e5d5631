#!/usr/bin/env python3
"""The speed issue's acceptance comparison: the whole `dpr-gpu register` process with no flags against Open3D
FPFH + RANSAC in-process with file loading (`open3d_fpfh.py`'s `wall_seconds`) at a voxel tuned per regime, side
by side, alternating, median of `--runs`. Prints one line per regime with both medians, their ratio, our stage
times (from `--json`) and both errors against the ground truth of the pair.

    python3 benches/compare/speed_regimes.py --binary target/release/dpr-gpu --data ../shared/data \
        [--runs 3] [--python venv/bin/python] [--extra-args "--backend cpu"] [--only lidar]
"""
import argparse
import json
import math
import os
import statistics
import subprocess
import time

import numpy as np

# name, source, target (relative to --data), Open3D voxel (metres), pairs.txt holding the ground truth
REGIMES = [
    ("room", "3dmatch_redkitchen/fragments/cloud_bin_1.ply", "3dmatch_redkitchen/fragments/cloud_bin_0.ply", 0.05),
    ("object", "stanford_bunny/xyz/bun000.ply", "stanford_bunny/xyz/bun045.ply", 0.005),
    ("lidar", "lidar_pair/source.ply", "lidar_pair/target.ply", 0.3),
]


def ground_truth(data: str, source: str, target: str):
    """target_from_source of the pair from its folder's pairs.txt (paths relative to the folder), or None."""
    folder = source.split("/")[0]
    path = os.path.join(data, folder, "pairs.txt")
    if not os.path.exists(path):
        return None
    for line in open(path):
        fields = line.split()
        if len(fields) != 18 or line.startswith("#"):
            continue
        s, t = (os.path.normpath(os.path.join(folder, f)) for f in fields[:2])
        if s == os.path.normpath(source) and t == os.path.normpath(target):
            return np.array([float(v) for v in fields[2:]]).reshape(4, 4)
    return None


def errors(pose, gt):
    if gt is None:
        return None
    t = np.asarray(pose, dtype=float)
    r = gt[:3, :3].T @ t[:3, :3]
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))
    return round(angle, 3), round(float(np.linalg.norm(gt[:3, 3] - t[:3, 3])), 4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--binary", default="target/release/dpr-gpu")
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--python", default="python3", help="a Python with open3d (open3d-cpu)")
    parser.add_argument("--extra-args", default="", help="flags added to every register command")
    parser.add_argument("--only", help="one regime: room, object or lidar")
    args = parser.parse_args()
    here = os.path.dirname(os.path.abspath(__file__))
    for name, source, target, voxel in REGIMES:
        if args.only and name != args.only:
            continue
        src, tgt = os.path.join(args.data, source), os.path.join(args.data, target)
        gt = ground_truth(args.data, source, target)
        ours, peer, last, last_peer = [], [], None, None
        for _ in range(args.runs):
            started = time.perf_counter()
            out = subprocess.run(
                [args.binary, "register", src, tgt, "--json", *args.extra_args.split()],
                capture_output=True, text=True, check=True,
            )
            ours.append(time.perf_counter() - started)
            last = json.loads(out.stdout)
            peer_out = subprocess.run(
                [args.python, os.path.join(here, "open3d_fpfh.py"), src, tgt, "--voxel", str(voxel)],
                capture_output=True, text=True, check=True,
            )
            last_peer = json.loads(peer_out.stdout.strip().splitlines()[-1])
            peer.append(last_peer["wall_seconds"])
        mine, theirs = statistics.median(ours), statistics.median(peer)
        stages = {}
        for t in last["timings"]:
            key = t["stage"].split(".")[-1]
            stages[key] = round(stages.get(key, 0.0) + t["seconds"], 3)
        print(json.dumps({
            "regime": name,
            "dpr_process_seconds": [round(x, 3) for x in ours],
            "open3d_in_process_seconds": [round(x, 3) for x in peer],
            "ratio_of_medians": round(mine / theirs, 2),
            "dpr_success": last["success"],
            "dpr_keypoints": last.get("keypoints"),
            "dpr_error_deg_m": errors(last["target_from_source"], gt),
            "open3d_error_deg_m": errors(last_peer["target_from_source"], gt),
            "dpr_total_seconds": round(last["total_seconds"], 3),
            "dpr_stages": stages,
        }))


if __name__ == "__main__":
    main()
