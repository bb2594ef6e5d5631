#!/usr/bin/env python3
"""GTSAM against `dpr-gpu pose-graph` on a g2o graph, side by side, both scored by GTSAM.

GTSAM runs Levenberg-Marquardt (default parameters, first pose fixed by a tight prior) from the file's poses and
from its chordal initialisation (InitializePose3). dpr-gpu runs as a separate process; its output vertices are
read back with gtsam.readG2o and scored with graph.error (0.5 sum e^T Omega e over the file's edges), the same
call that scores GTSAM's own result. Times: GTSAM's optimisation alone (reading excluded, as GTSAM is usually
quoted) and its whole process (interpreter start, import, reading, optimising); dpr-gpu's whole process
(reading and writing included).

With --false-loops F: a copy of the graph with round(F x edges) false loop closures (random pairs of
non-adjacent vertices, random relative poses up to --false-reach metres and any rotation, information copied
from random real edges; --seed) is written beside --work, solved robustly by dpr-gpu (--robust geman-mcclure,
--init file), and its poses are compared with GTSAM's clean optimum (ATE: RMS distance of the positions, no
alignment, first pose fixed in both); GTSAM LM on the corrupted graph is shown for reference.

    python3 -m venv /tmp/gtsam-venv && /tmp/gtsam-venv/bin/pip install gtsam numpy
    /tmp/gtsam-venv/bin/python benches/compare/pose_graph_gtsam.py GRAPH.g2o --dpr target/release/dpr-gpu \
        [--work DIR] [--false-loops 0.1] [--seed 0]
    (inner modes, used by the above: --solve odometry|chordal prints one JSON line)
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

import gtsam


def with_prior(graph, initial):
    """The graph plus a tight prior holding the lowest-key pose where the file puts it."""
    first = min(initial.keys())
    fixed = gtsam.NonlinearFactorGraph(graph)
    noise = gtsam.noiseModel.Diagonal.Variances(np.full(6, 1e-8))
    fixed.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), noise))
    return fixed


def gtsam_solve(path, init):
    """GTSAM LM from `init` ('odometry': the file's poses; 'chordal': InitializePose3); (error, seconds, values)."""
    graph, initial = gtsam.readG2o(path, True)
    started = time.perf_counter()
    fixed = with_prior(graph, initial)
    if init == "chordal":
        initial = gtsam.InitializePose3.initialize(fixed)
    result = gtsam.LevenbergMarquardtOptimizer(fixed, initial, gtsam.LevenbergMarquardtParams()).optimize()
    seconds = time.perf_counter() - started
    return graph.error(result), seconds, result


def score(path, solution_path):
    """graph.error of `path`'s edges at the vertices of `solution_path`."""
    graph, _ = gtsam.readG2o(path, True)
    _, values = gtsam.readG2o(solution_path, True)
    return graph.error(values)


def timed(command):
    """Runs `command`; (wall seconds, stdout)."""
    started = time.perf_counter()
    done = subprocess.run(command, check=True, capture_output=True, text=True)
    return time.perf_counter() - started, done.stdout


def positions(values, keys):
    return np.array([values.atPose3(k).translation() for k in keys])


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q  # x y z w, uniform on SO(3)


def write_false_loops(path, out, fraction, reach, seed):
    """Copies `path` to `out` with false loop closures appended (see the module docs); returns their count."""
    rng = np.random.default_rng(seed)
    lines = open(path).read().splitlines()
    vertices = [int(l.split()[1]) for l in lines if l.startswith("VERTEX_SE3:QUAT")]
    infos = [l.split()[10:] for l in lines if l.startswith("EDGE_SE3:QUAT")]
    count = round(fraction * len(infos))
    extra = []
    while len(extra) < count:
        i, j = rng.choice(vertices, size=2, replace=False)
        if abs(int(i) - int(j)) <= 1:
            continue
        direction = rng.normal(size=3)
        t = direction / np.linalg.norm(direction) * rng.uniform(0.0, reach)
        q = random_rotation(rng)
        info = infos[rng.integers(len(infos))]
        numbers = " ".join(f"{v:.17g}" for v in [*t, *q])
        extra.append(f"EDGE_SE3:QUAT {i} {j} {numbers} {' '.join(info)}")
    with open(out, "w") as f:
        f.write("\n".join(lines + extra) + "\n")
    return count


def run_dpr(args, graph_path, out, extra):
    seconds, stdout = timed([args.dpr, "pose-graph", graph_path, "--out", out, *extra])
    return seconds, stdout.strip()


def compare(args):
    os.makedirs(args.work, exist_ok=True)
    name = os.path.splitext(os.path.basename(args.graph))[0]
    rows = []
    best = math.inf
    clean = None
    for init in ["odometry", "chordal"]:
        wall, stdout = timed([sys.executable, __file__, args.graph, "--solve", init])
        line = json.loads(stdout)
        best = min(best, line["error"])
        rows.append((f"GTSAM LM ({init} init)", line["error"], line["seconds"], wall))
        if init == "odometry":
            clean = gtsam_solve(args.graph, init)[2]
    for init in ["chordal", "file"]:
        out = os.path.join(args.work, f"{name}.dpr-{init}.g2o")
        wall, summary = run_dpr(args, args.graph, out, ["--init", init])
        rows.append((f"dpr-gpu pose-graph (--init {init})", score(args.graph, out), None, wall))
        print(f"# {summary}")
    print(f"| {name} | error (GTSAM graph.error) | optimisation s | process s |")
    print("|---|---|---|---|")
    for label, error, seconds, wall in rows:
        opt = f"{seconds:.3f}" if seconds is not None else "-"
        print(f"| {label} | {error:.6f} ({error / best:.6f} x best) | {opt} | {wall:.3f} |")
    if args.false_loops > 0:
        false_loops(args, name, clean)


def false_loops(args, name, clean):
    noisy = os.path.join(args.work, f"{name}.false{args.false_loops:g}-seed{args.seed}.g2o")
    count = write_false_loops(args.graph, noisy, args.false_loops, args.false_reach, args.seed)
    out = os.path.join(args.work, f"{name}.false.dpr.g2o")
    wall, summary = run_dpr(args, noisy, out, ["--robust", "geman-mcclure", "--init", "file"])
    print(f"# {summary}")
    keys = sorted(clean.keys())
    _, robust = gtsam.readG2o(out, True)
    ate = np.sqrt(np.mean(np.sum((positions(robust, keys) - positions(clean, keys)) ** 2, axis=1)))
    error, seconds, plain = gtsam_solve(noisy, "odometry")
    plain_ate = np.sqrt(np.mean(np.sum((positions(plain, keys) - positions(clean, keys)) ** 2, axis=1)))
    print(f"false loops: {count} added (seed {args.seed}, up to {args.false_reach} m, any rotation)")
    print(f"| solver | ATE to the clean optimum (m) | error on the clean graph | s |")
    print("|---|---|---|---|")
    print(f"| dpr-gpu --robust geman-mcclure --init file | {ate:.4f} | {score(args.graph, out):.4f} | {wall:.3f} (process) |")
    print(f"| GTSAM LM (odometry init, no robust kernel) | {plain_ate:.4f} | error {error:.1f} on the corrupted graph | {seconds:.3f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("graph")
    parser.add_argument("--dpr", default="target/release/dpr-gpu")
    parser.add_argument("--work", default="target/pose-graph-compare")
    parser.add_argument("--solve", choices=["odometry", "chordal"])
    parser.add_argument("--false-loops", type=float, default=0.0)
    parser.add_argument("--false-reach", type=float, default=5.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.solve:
        error, seconds, _ = gtsam_solve(args.graph, args.solve)
        print(json.dumps({"error": error, "seconds": seconds}))
    else:
        compare(args)


if __name__ == "__main__":
    main()
