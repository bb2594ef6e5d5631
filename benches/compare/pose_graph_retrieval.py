#!/usr/bin/env python3
"""Writes a generated multiway-shaped pose graph in g2o: what `multiway --pairs consecutive+retrieval` builds for
a long collection that revisits its places (for the 10,000-scan cost model of docs/experiments/multiway-scale.md).

N scans along a drive of --laps laps around a 400 m x 200 m block (so every place is seen --laps times, far apart
in scan order), a scan every --step metres, heading along the road; edges: odometry k -> k+1 and, per scan, its
--k nearest scans in space that are not its neighbours in order (retrieval's loop closures: near in space, any
distance in order), deduplicated; each measurement perturbed by Exp(noise) (translation sigma S, rotation sigma
S/2, seeded); information diag(100, 100, 100, 400, 400, 400); vertices are the chained odometry. With --false F,
a share F of the loop closures is replaced by a random relative pose (wrong retrievals).

    python3 benches/compare/pose_graph_retrieval.py N OUT.g2o [--laps 4] [--k 5] [--sigma 0.02] [--false 0]
        [--seed 1]   (needs numpy)
"""
import argparse

import numpy as np

from g2o_text import write_g2o


def exp_so3(w):
    """Rotation matrix of the rotation vector w."""
    angle = np.linalg.norm(w)
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def quaternion_xyzw(m):
    """Unit quaternion (x, y, z, w) of a rotation matrix."""
    t = np.trace(m)
    if t > 0:
        s = 2 * np.sqrt(1 + t)
        return [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    k = int(np.argmax(np.diag(m)))
    i, j = (k + 1) % 3, (k + 2) % 3
    s = 2 * np.sqrt(1 + m[k, k] - m[i, i] - m[j, j])
    q = [0.0] * 4
    q[k], q[i], q[j], q[3] = s / 4, (m[i, k] + m[k, i]) / s, (m[j, k] + m[k, j]) / s, (m[j, i] - m[i, j]) / s
    return q


def block_drive(n, laps):
    """world_from_scan of n scans spread over `laps` laps of a 400 x 200 m rectangle (z = 0, heading along it)."""
    perimeter = 2 * (400 + 200)
    poses = []
    for s in np.linspace(0, laps * perimeter, n, endpoint=False):
        d = s % perimeter
        if d < 400:
            p, heading = (d, 0), 0.0
        elif d < 600:
            p, heading = (400, d - 400), np.pi / 2
        elif d < 1000:
            p, heading = (400 - (d - 600), 200), np.pi
        else:
            p, heading = (0, 200 - (d - 1000)), -np.pi / 2
        pose = np.eye(4)
        pose[:3, :3] = exp_so3(np.array([0, 0, heading]))
        pose[:3, 3] = [p[0], p[1], 0.0]
        poses.append(pose)
    return poses


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scans", type=int)
    parser.add_argument("out")
    parser.add_argument("--laps", type=int, default=4)
    parser.add_argument("--k", type=int, default=5)
    parser.add_argument("--sigma", type=float, default=0.02)
    parser.add_argument("--false", type=float, default=0.0)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    truth = block_drive(args.scans, args.laps)
    positions = np.array([p[:3, 3] for p in truth])
    pairs = {(k, k + 1) for k in range(args.scans - 1)}
    for k in range(args.scans):
        d = np.linalg.norm(positions - positions[k], axis=1)
        d[max(0, k - 1) : k + 2] = np.inf
        for j in np.argsort(d)[: args.k]:
            pairs.add((min(k, int(j)), max(k, int(j))))
    edges = []
    for i, j in sorted(pairs):
        z = np.linalg.inv(truth[i]) @ truth[j]
        if j != i + 1 and rng.uniform() < args.false:
            z = np.eye(4)
            z[:3, :3] = exp_so3(rng.normal(size=3) * np.pi)
            z[:3, 3] = rng.uniform(-5, 5, 3)
        noise = np.eye(4)
        noise[:3, :3] = exp_so3(rng.normal(size=3) * 0.5 * args.sigma)
        noise[:3, 3] = rng.normal(size=3) * args.sigma
        edges.append((i, j, z @ noise))
    start = [truth[0]]
    for i, j, z in edges:
        if j == i + 1:
            start.append(start[i] @ z)

    def pose(p):
        return [*p[:3, 3], *quaternion_xyzw(p[:3, :3])]

    write_g2o(args.out, [pose(p) for p in start], [(i, j, pose(z)) for i, j, z in edges])
    print(f"{args.scans} poses, {len(edges)} edges ({len(edges) - (args.scans - 1)} loop closures)")


if __name__ == "__main__":
    main()
