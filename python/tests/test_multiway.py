"""dpr_gpu.multiway: a collection of scans with known poses comes back as one trajectory."""

from __future__ import annotations

import numpy as np
import pytest

import dpr_gpu
from conftest import RECOVER, known_pose, room_corner, rotation_error_deg, transform


@pytest.fixture(scope="module")
def three_scans():
    """Three independent samples of the room, each moved by its own known world_from_scan inverse."""
    rng = np.random.default_rng(11)
    world_from_scan = [np.eye(4)] + [known_pose(rng) for _ in range(2)]
    scans = [
        transform(np.linalg.inv(pose), room_corner(rng, 4000)).astype(np.float32) for pose in world_from_scan
    ]
    return scans, world_from_scan


def test_multiway_recovers_every_relative_pose(three_scans):
    scans, truth = three_scans
    result = dpr_gpu.multiway(scans, pairs="all", **RECOVER)
    poses = result["world_from_scan"]
    assert poses.shape == (3, 4, 4) and poses.dtype == np.float64
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    for k in (1, 2):
        assert rotation_error_deg(poses[k], truth[k]) < 2.0
        assert np.linalg.norm(poses[k][:3, 3] - truth[k][:3, 3]) < 0.05
    edges = result["edges"]
    assert [(e["i"], e["j"]) for e in edges] == [(0, 1), (1, 2), (0, 2)]
    assert [e["kind"] for e in edges] == ["odometry", "odometry", "loop"]
    # Odometry edges always enter the pose graph; a loop closure only when the verdict trusts it.
    assert all(e["in_graph"] for e in edges[:2]) and edges[2]["in_graph"] == edges[2]["trusted"]
    assert edges[0]["information"].shape == (6, 6) and edges[0]["information"][0, 0] > 0
    assert result["connected"] == [True, True, True]


def test_multiway_is_deterministic_and_matches_the_registrar_method(three_scans):
    scans, _ = three_scans
    a = dpr_gpu.multiway(scans[:2], **RECOVER)
    b = dpr_gpu.Registrar(**RECOVER).multiway(scans[:2])
    np.testing.assert_array_equal(a["world_from_scan"], b["world_from_scan"])


def test_multiway_refuses_bad_input(three_scans):
    scans, _ = three_scans
    with pytest.raises(ValueError, match="at least 2 scans"):
        dpr_gpu.multiway(scans[:1], backend="cpu")
    with pytest.raises(ValueError, match="pairs"):
        dpr_gpu.multiway(scans, pairs="some", backend="cpu")
    with pytest.raises(ValueError, match="normal arrays"):
        dpr_gpu.multiway(scans, normals=[scans[0]], backend="cpu")
