#!/usr/bin/env python3
"""Open3D FPFH + RANSAC on every gt.log pair of every scene of a 3DMatch-format dataset, written as result logs.

The settings are those of `open3d_fpfh.py` (the speed comparison). Score the logs with the project's evaluator:

    python3 benches/compare/open3d_fpfh_logs.py DATASET OUT [--voxel 0.05] [--seed 0]
    dpr-gpu eval DATASET --log 'OUT/{scene}.log'
"""
import argparse
import os
from typing import Dict, List, Tuple

import numpy as np
import open3d as o3d

reg = o3d.pipelines.registration


def describe(path: str, voxel: float):
    cloud = o3d.io.read_point_cloud(path)
    if cloud.is_empty():
        raise SystemExit(f"{path}: no points read")
    down = cloud.voxel_down_sample(voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    fpfh = reg.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
    return down, fpfh


def gt_pairs(path: str) -> List[Tuple[int, int, int]]:
    """(i, j, fragments) of every record of a gt.log (a header line and four matrix rows each)."""
    lines = [line for line in open(path).read().splitlines() if line.strip()]
    return [tuple(int(v) for v in lines[k].split()[:3]) for k in range(0, len(lines) - 4, 5)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("dataset")
    parser.add_argument("out")
    parser.add_argument("--voxel", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    v = args.voxel
    for scene in sorted(os.listdir(args.dataset)):
        gt = os.path.join(args.dataset, scene, "gt.log")
        if not os.path.isfile(gt):
            continue
        o3d.utility.random.seed(args.seed)
        described: Dict[int, tuple] = {}
        records = []
        for i, j, n in gt_pairs(gt):
            for k in (i, j):
                if k not in described:
                    described[k] = describe(os.path.join(args.dataset, scene, f"cloud_bin_{k}.ply"), v)
            (source, source_fpfh), (target, target_fpfh) = described[j], described[i]
            result = reg.registration_ransac_based_on_feature_matching(
                source, target, source_fpfh, target_fpfh, True, 1.5 * v,
                reg.TransformationEstimationPointToPoint(False), 3,
                [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * v)],
                reg.RANSACConvergenceCriteria(100000, 0.999),
            )
            rows = "\n".join(" ".join(f"{x:.8e}" for x in row) for row in np.asarray(result.transformation))
            records.append(f"{i}\t{j}\t{n}\n{rows}\n")
            print(scene, i, j, flush=True)
        with open(os.path.join(args.out, f"{scene}.log"), "w") as f:
            f.write("".join(records))


if __name__ == "__main__":
    main()
