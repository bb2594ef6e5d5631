#!/usr/bin/env python3
"""Writes a generated helix pose graph in g2o (for scaling runs of `dpr-gpu bench --pose-graph`).

N poses on a helix (40 per turn, radius 10 m, 0.3 m rise per turn), odometry edges k -> k+1 and loop closures
k -> k+40 (one turn up), each measurement perturbed by Exp(noise) with translation sigma S and rotation sigma
S/2 (seeded); information diag(100, 100, 100, 400, 400, 400); vertices are the chained odometry.

    python3 benches/compare/pose_graph_helix.py N OUT.g2o [--sigma 0.02] [--seed 1]   (needs gtsam, numpy)
"""
import argparse

import numpy as np

import gtsam
from g2o_text import write_g2o


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("poses", type=int)
    parser.add_argument("out")
    parser.add_argument("--sigma", type=float, default=0.02)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    n, per = args.poses, 40
    truth = []
    for k in range(n):
        a = 2 * np.pi * k / per
        rotation = gtsam.Rot3.Rz(a) * gtsam.Rot3.Rx(0.05 * np.sin(a))
        truth.append(gtsam.Pose3(rotation, gtsam.Point3(10 * np.cos(a), 10 * np.sin(a), 0.3 * k / per)))
    edges = []
    for k in range(n):
        for j in (k + 1, k + per):
            if j < n:
                xi = np.concatenate([rng.normal(size=3) * 0.5 * args.sigma, rng.normal(size=3) * args.sigma])
                edges.append((k, j, truth[k].between(truth[j]).compose(gtsam.Pose3.Expmap(xi))))
    start = [truth[0]]
    for i, j, z in edges:
        if j == i + 1:
            start.append(start[i].compose(z))

    def pose(p):
        q, t = p.rotation().toQuaternion(), p.translation()
        return [t[0], t[1], t[2], q.x(), q.y(), q.z(), q.w()]

    write_g2o(args.out, [pose(p) for p in start], [(i, j, pose(z)) for i, j, z in edges])

if __name__ == "__main__":
    main()
