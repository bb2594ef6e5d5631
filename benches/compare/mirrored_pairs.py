"""The pairs of the mirrored-scan experiments (docs/experiments/mirrored-scans.md): every pair of the shared sets'
pairs.txt (stanford_bunny, 3dmatch_redkitchen, lidar_pair), each also with its source mirrored (x -> -x, normals
too). Imported by mirrored_agreement.py and mirrored_verdict.py."""
from pathlib import Path

import numpy as np

import dpr_gpu

SETS = ("stanford_bunny", "3dmatch_redkitchen", "lidar_pair")
MIRROR = np.array([-1.0, 1.0, 1.0])


def default_data():
    return Path(__file__).resolve().parents[3] / "shared/data"


def pairs(data):
    """(set, source path, target path, target_from_source ground truth) for every line of the sets' pairs.txt."""
    for folder in SETS:
        for line in (data / folder / "pairs.txt").read_text().splitlines():
            if line.strip() and not line.startswith("#"):
                f = line.split()
                truth = np.array([float(v) for v in f[2:18]]).reshape(4, 4)
                yield folder, data / folder / f[0], data / folder / f[1], truth


def write_ply(path, points, normals):
    with open(path, "wb") as out:
        has_n = normals is not None
        header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\n" % len(points)
        if has_n:
            header += "property float nx\nproperty float ny\nproperty float nz\n"
        out.write((header + "end_header\n").encode())
        data = np.hstack([points, normals]) if has_n else points
        out.write(data.astype("<f4").tobytes())


def mirrored_source(source, path):
    """Writes the source mirrored (x -> -x) to `path`; returns (points, mirrored points)."""
    points, normals = dpr_gpu.read_cloud(source)
    write_ply(path, points * MIRROR, None if normals is None else normals * MIRROR)
    return points, points * MIRROR


def rot_err(a, b):
    r = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))
