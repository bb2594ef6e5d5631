"""Issue 36 case 4, second candidate: point-to-plane and normal agreement of the overlap, real vs mirrored
(docs/experiments/mirrored-scans.md).

For every pair of the shared sets (pairs.txt of stanford_bunny, 3dmatch_redkitchen, lidar_pair under DATA):
register it with `dpr-gpu register --json --backend cpu` as given and with the source mirrored (x -> -x, normals
too), then measure at the returned pose on voxel-downsampled clouds (the run's voxel) with PCA normals (k=30):
  overlap = source points within 2 tau (point-to-point) of the target, tau = the run's inlier threshold;
  plane8, plane4 = share of the overlap within tau/8, tau/4 point-to-plane (the target's normal);
  normal15 = share of the overlap whose normal agrees with the target's within 15 degrees (unsigned).
One JSON line per registration on stdout, all rows in WORK/rows.json.

    python benches/compare/mirrored_agreement.py target/release/dpr-gpu WORK [DATA]   (needs dpr_gpu, scipy)
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import dpr_gpu

from mirrored_pairs import default_data, mirrored_source, pairs, rot_err

CLI = sys.argv[1]
WORK = Path(sys.argv[2])
DATA = Path(sys.argv[3]) if len(sys.argv) > 3 else default_data()
WORK.mkdir(exist_ok=True)


def voxel(points, size):
    keys = np.floor(points / size).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def normals_of(points, k=30):
    tree = cKDTree(points)
    _, idx = tree.query(points, k=min(k, len(points)))
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


def measure(source, target, pose, scale):
    size, tau = scale["voxel"], scale["inlier_threshold"]
    s = voxel(source, size)
    t = voxel(target, size)
    moved = s @ pose[:3, :3].T + pose[:3, 3]
    ns = normals_of(s) @ pose[:3, :3].T
    nt = normals_of(t)
    d, j = cKDTree(t).query(moved)
    overlap = d < 2 * tau
    if overlap.sum() == 0:
        return 0, 0.0, 0.0, 0.0
    plane = np.abs(np.einsum("ni,ni->n", moved - t[j], nt[j]))
    cos = np.abs(np.einsum("ni,ni->n", ns, nt[j]))
    o = overlap
    return int(o.sum()), float((plane[o] < tau / 8).mean()), float((plane[o] < tau / 4).mean()), float((cos[o] > np.cos(np.radians(15))).mean())


rows = []
for k, (folder, src, tgt, truth) in enumerate(pairs(DATA)):
    mpath = WORK / f"mirrored_{k}.ply"
    points, mirrored = mirrored_source(src, mpath)
    target, _ = dpr_gpu.read_cloud(tgt)
    for kind, path, cloud in (("real", src, points), ("mirrored", mpath, mirrored)):
        out = subprocess.run([CLI, "register", str(path), str(tgt), "--json", "--backend", "cpu"], capture_output=True, text=True)
        r = json.loads(out.stdout)
        pose = np.array(r["target_from_source"])
        n, p8, p4, nrm = measure(cloud, target, pose, r["scale"])
        row = dict(set=folder, source=src.name, target=tgt.name, kind=kind, trusted=r["success"], rot=rot_err(pose, truth) if kind == "real" else None,
                   overlap=n, plane8=p8, plane4=p4, normal15=nrm, inliers=r["inliers"])
        rows.append(row)
        print(json.dumps(row), flush=True)
(WORK / "rows.json").write_text(json.dumps(rows, indent=1))
