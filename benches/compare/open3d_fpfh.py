#!/usr/bin/env python3
"""Open3D FPFH + RANSAC on one pair, the baseline `dpr-gpu register --backend cpu` is timed against.

Settings from the speed issue: voxel 5 cm, normals radius 10 cm, FPFH radius 25 cm, RANSAC with mutual
feature matching, distance threshold 1.5 x voxel, 100,000 iterations, confidence 0.999. Prints one JSON line:
the pose, wall and CPU seconds of the whole process (file loading included), and, with --gt, the rotation
(degrees) and translation errors against a 4x4 ground truth given as 16 row-major numbers.

    pip install open3d-cpu   # Debian also needs libusb-1.0-0 and libgomp1
    python3 benches/compare/open3d_fpfh.py SOURCE TARGET [--gt 't00 ... t33'] [--seed 0]
"""
import argparse
import json
import math
import os
import resource
import time

import numpy as np
import open3d as o3d


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("source")
    parser.add_argument("target")
    parser.add_argument("--voxel", type=float, default=0.05)
    parser.add_argument("--gt", help="16 row-major numbers of target_from_source")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    o3d.utility.random.seed(args.seed)
    voxel = args.voxel
    started = time.perf_counter()

    def prepare(path: str):
        cloud = o3d.io.read_point_cloud(path)
        if cloud.is_empty():
            raise SystemExit(f"{path}: no points read")
        down = cloud.voxel_down_sample(voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        fpfh = o3d.pipelines.registration.compute_fpfh_feature(
            down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
        )
        return down, fpfh

    source, source_fpfh = prepare(args.source)
    target, target_fpfh = prepare(args.target)
    reg = o3d.pipelines.registration
    result = reg.registration_ransac_based_on_feature_matching(
        source,
        target,
        source_fpfh,
        target_fpfh,
        True,
        1.5 * voxel,
        reg.TransformationEstimationPointToPoint(False),
        3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100000, 0.999),
    )
    wall = time.perf_counter() - started
    usage = resource.getrusage(resource.RUSAGE_SELF)
    out = {
        "target_from_source": np.asarray(result.transformation).tolist(),
        "fitness": result.fitness,
        "inlier_rmse": result.inlier_rmse,
        "wall_seconds": wall,
        "cpu_seconds": usage.ru_utime + usage.ru_stime,
        "threads": os.cpu_count(),
    }
    if args.gt:
        gt = np.array([float(v) for v in args.gt.split()]).reshape(4, 4)
        t = np.asarray(result.transformation)
        r = gt[:3, :3].T @ t[:3, :3]
        out["rotation_error_deg"] = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))
        out["translation_error"] = float(np.linalg.norm(gt[:3, 3] - t[:3, 3]))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
