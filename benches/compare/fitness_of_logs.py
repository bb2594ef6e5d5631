#!/usr/bin/env python3
"""Open3D's fitness of a result log's poses next to the ground truth's, pair by pair.

A check that a peer's result logs follow the dataset's convention (source j mapped into fragment i, as gt.log):
where a peer's poses fail, a wrong convention gives the ground truth a high fitness and the logged pose a low
one; a genuine confusion between repeated structure gives the logged pose the higher fitness.

    python3 benches/compare/fitness_of_logs.py DATASET LOGS [--scene scene_00] [--pairs 8] [--voxel 0.05]

LOGS holds `<scene>.log` per scene (as `open3d_fpfh_logs.py` writes them).
"""
import argparse
import os
from typing import Dict, Tuple

import numpy as np
import open3d as o3d

reg = o3d.pipelines.registration


def read_log(path: str) -> Dict[Tuple[int, int], np.ndarray]:
    """(i, j) -> 4x4 of every record of a 3DMatch-format log."""
    lines = [line for line in open(path).read().splitlines() if line.strip()]
    out = {}
    for k in range(0, len(lines) - 4, 5):
        i, j = (int(v) for v in lines[k].split()[:2])
        out[(i, j)] = np.array([[float(x) for x in lines[k + r].split()] for r in range(1, 5)])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("dataset")
    parser.add_argument("logs")
    parser.add_argument("--scene", default="scene_00")
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--voxel", type=float, default=0.05)
    args = parser.parse_args()
    folder = os.path.join(args.dataset, args.scene)
    truth = read_log(os.path.join(folder, "gt.log"))
    logged = read_log(os.path.join(args.logs, f"{args.scene}.log"))

    def load(k: int):
        return o3d.io.read_point_cloud(os.path.join(folder, f"cloud_bin_{k}.ply")).voxel_down_sample(args.voxel)

    distance = 1.5 * args.voxel
    print("i j fitness_gt fitness_log rotation_error_deg")
    for (i, j), i_from_j in list(truth.items())[: args.pairs]:
        if (i, j) not in logged:
            continue
        source, target = load(j), load(i)
        fit_gt = reg.evaluate_registration(source, target, distance, i_from_j).fitness
        fit_log = reg.evaluate_registration(source, target, distance, logged[(i, j)]).fitness
        r = i_from_j[:3, :3].T @ logged[(i, j)][:3, :3]
        angle = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
        print(f"{i} {j} {fit_gt:.3f} {fit_log:.3f} {angle:.1f}")


if __name__ == "__main__":
    main()
