"""Shared helpers for the dpr_gpu tests: a generated scene, known poses, and the command-line binary."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Optional

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]

# Settings that recover the generated room's pose in seconds on a CPU with the built-in weights: 150
# farthest-point keypoints, RANSAC on their learned correspondences, then point-to-plane ICP. (RelativeNet's
# one-hypothesis-per-correspondence estimator needs more keypoints than that on this scene.)
RECOVER = {
    "backend": "cpu",
    "keypoints": 150,
    "keypoint_mode": "uniform",
    "estimator": "ransac",
    "icp": True,
    "seed": 7,
}

# For tests that compare two runs rather than check a pose: as few keypoints as still give correspondences.
QUICK = {"backend": "cpu", "keypoints": 40, "seed": 3}


def room_corner(rng: np.random.Generator, n: int) -> np.ndarray:
    """n points (float64, metres) sampled from a small room corner about 2 m across: floor, two walls, a box,
    a sphere and a cylinder; different generators give different samples of the same surfaces."""
    u, v = rng.random(n), rng.random(n)
    part = np.arange(n) % 6
    pts = np.empty((n, 3))
    floor, wall_x, wall_y, box, sphere, cyl = (part == k for k in range(6))
    pts[floor] = np.stack([2 * u[floor], 2 * v[floor], 0 * u[floor]], 1)
    pts[wall_x] = np.stack([2 * u[wall_x], 0 * u[wall_x], 1.5 * v[wall_x]], 1)
    pts[wall_y] = np.stack([0 * u[wall_y], 2 * u[wall_y], 1.5 * v[wall_y]], 1)
    # Box 0.5 x 0.4 x 0.6 at (1.2, 1.0): its top and four sides.
    face = rng.integers(0, 5, n)[box]
    bu, bv = u[box], v[box]
    x0, y0, sx, sy, sz = 1.2, 1.0, 0.5, 0.4, 0.6
    options = [
        np.stack([x0 + sx * bu, y0 + sy * bv, sz + 0 * bu], 1),
        np.stack([x0 + 0 * bu, y0 + sy * bu, sz * bv], 1),
        np.stack([x0 + sx + 0 * bu, y0 + sy * bu, sz * bv], 1),
        np.stack([x0 + sx * bu, y0 + 0 * bu, sz * bv], 1),
        np.stack([x0 + sx * bu, y0 + sy + 0 * bu, sz * bv], 1),
    ]
    pts[box] = np.choose(face[:, None], options)
    th, z = 2 * np.pi * u[sphere], 2 * v[sphere] - 1
    r = np.sqrt(1 - z * z) * 0.25
    pts[sphere] = np.stack([0.6 + r * np.cos(th), 1.4 + r * np.sin(th), 0.25 + 0.25 * z], 1)
    th = 2 * np.pi * u[cyl]
    pts[cyl] = np.stack([1.5 + 0.15 * np.cos(th), 0.5 + 0.15 * np.sin(th), 0.8 * v[cyl]], 1)
    return pts


def known_pose(rng: np.random.Generator) -> np.ndarray:
    """A 4x4 rigid transform with a sizeable random rotation (uniform unit quaternion) and translation."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = rng.uniform(-2, 2, 3)
    return pose


def transform(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """points (N, 3) mapped by the 4x4 pose."""
    return points @ pose[:3, :3].T + pose[:3, 3]


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between two poses, in degrees."""
    r = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


@pytest.fixture(scope="session")
def room_pair():
    """(source, target, target_from_source): two independent float32 samples of the room, the target moved."""
    rng = np.random.default_rng(2024)
    truth = known_pose(rng)
    source = room_corner(rng, 4000).astype(np.float32)
    target = transform(truth, room_corner(rng, 4000)).astype(np.float32)
    return source, target, truth


def cli_binary() -> Optional[Path]:
    """The dpr-gpu command line to compare with: $DPR_GPU_CLI, else the newer of the checkout's debug and
    release builds."""
    named = os.environ.get("DPR_GPU_CLI")
    if named:
        return Path(named)
    built = [p for p in (REPO / "target/debug/dpr-gpu", REPO / "target/release/dpr-gpu") if p.is_file()]
    if not built:
        found = shutil.which("dpr-gpu")
        return Path(found) if found else None
    return max(built, key=lambda p: p.stat().st_mtime)
