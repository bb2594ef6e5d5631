"""dpr_gpu.multiway: a collection of scans with known poses comes back as one trajectory."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

import dpr_gpu
from dpr_gpu import _dpr_gpu
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
    # Every point kept: these clouds (about 8 cm spacing) are sparser than the default voxel, which would only
    # reorder them, and so the uniform keypoints, from those this check was written for.
    result = dpr_gpu.multiway(scans, pairs="all", **RECOVER, voxel=0)
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


# The stages of multiway as separate calls (what dpr_gpu.distributed schedules): the same result, bit for bit.


def stages(scans, settings, **options):
    """dpr_gpu.multiway rebuilt from its stages in this process, with every described scan and pair result sent
    through pickle on the way, as Ray sends them between processes. With no radius in ``settings``, the radius is
    chosen from every scan first, as multiway chooses it (``scan_size``, ``choose_radius``)."""
    origin = dpr_gpu.multiway_origin(scans[0])
    if settings.get("radius") is None:
        radius = dpr_gpu.choose_radius([dpr_gpu.scan_size(s, origin=origin) for s in scans])
        settings = {**settings, "radius": radius}
    registrar = dpr_gpu.Registrar(**settings)
    described = [
        pickle.loads(pickle.dumps(registrar.describe_scan(s, index=k, origin=origin))) for k, s in enumerate(scans)
    ]
    pairs = options.get("pairs", "consecutive+retrieval")
    pooled = [d.pooled_codeword for d in described] if pairs != "all" else None
    selected = dpr_gpu.select_pairs(
        len(scans), pooled, pairs=pairs, retrieval_k=options.get("retrieval_k", 5), max_pairs=options.get("max_pairs")
    )
    results = [
        pickle.loads(pickle.dumps(registrar.register_described(described[i], described[j]))) for i, j in selected
    ]
    graph = dpr_gpu.optimize_pairs(
        len(scans), results, information_distance=registrar.inlier_threshold, origin=origin
    )
    return graph, described, results


def assert_same_multiway(a, b):
    """Two multiway dicts agree exactly: poses, edges (every field) and the graph's verdicts."""
    np.testing.assert_array_equal(a["world_from_scan"], b["world_from_scan"])
    assert a["connected"] == b["connected"] and a["line_process_weight"] == b["line_process_weight"]
    assert len(a["edges"]) == len(b["edges"])
    for ea, eb in zip(a["edges"], b["edges"]):
        assert ea.keys() == eb.keys()
        for key in ea:
            np.testing.assert_array_equal(ea[key], eb[key], err_msg=f"edge ({ea['i']}, {ea['j']}) {key}")


@pytest.mark.parametrize("pairs", ["all", "consecutive+retrieval"])
def test_multiway_stages_reproduce_multiway(three_scans, pairs):
    scans, _ = three_scans
    registrar = dpr_gpu.Registrar(**RECOVER)
    whole = registrar.multiway(scans, pairs=pairs, retrieval_k=1)
    graph, described, results = stages(scans, RECOVER, pairs=pairs, retrieval_k=1)
    assert_same_multiway(graph.to_dict(), whole)
    assert [(r.i, r.j) for r in results] == [(e["i"], e["j"]) for e in whole["edges"]]
    assert [d.index for d in described] == [0, 1, 2] and all(len(d) > 0 for d in described)
    # Pooled codewords are unit vectors; a scan is most similar to itself.
    pooled = np.stack([d.pooled_codeword for d in described])
    np.testing.assert_allclose(np.linalg.norm(pooled, axis=1), 1.0, atol=1e-5)


def test_described_scans_and_pair_results_pickle_bit_for_bit(three_scans):
    scans, _ = three_scans
    registrar = dpr_gpu.Registrar(**RECOVER)
    a, b = (registrar.describe_scan(s, index=k) for k, s in enumerate(scans[:2]))
    a2, b2 = pickle.loads(pickle.dumps(a)), pickle.loads(pickle.dumps(b))
    for x, y in ((a, a2), (b, b2)):
        assert (y.index, y.origin, y.points, len(y)) == (x.index, x.origin, x.points, len(x))
        np.testing.assert_array_equal(y.keypoints, x.keypoints)
        np.testing.assert_array_equal(y.keypoint_normals, x.keypoint_normals)
        np.testing.assert_array_equal(y.pooled_codeword, x.pooled_codeword)
        assert y.timings == x.timings
    # A second registrar with the same settings (as on another worker) registers the unpickled scans exactly as
    # the first registers the originals.
    direct = registrar.register_described(a, b)
    elsewhere = dpr_gpu.Registrar(**RECOVER).register_described(a2, b2)
    restored = pickle.loads(pickle.dumps(elsewhere))
    for r in (elsewhere, restored):
        assert (r.i, r.j, r.correspondences, r.inliers, r.trusted, r.reason) == (
            0, 1, direct.correspondences, direct.inliers, direct.trusted, direct.reason
        )
        assert (r.fitness, r.inlier_rmse) == (direct.fitness, direct.inlier_rmse)
        np.testing.assert_array_equal(r.i_from_j, direct.i_from_j)
        np.testing.assert_array_equal(r.information, direct.information)
    assert restored.seconds == elsewhere.seconds
    assert direct.correspondences > 0 and direct.information[0, 0] > 0  # a registration, not a failed pair


def test_pickled_scans_carry_their_context_rows(three_scans):
    scans, _ = three_scans
    # A verdict nothing passes: the pair ends with the round that matches on the context radius's codewords too.
    untrusted = {**RECOVER, "min_inliers": 1_000_000}
    results = {}
    for context in (((2.0, 1.0),), ()):
        registrar = dpr_gpu.Registrar(**untrusted, context_radii=context)
        a, b = (registrar.describe_scan(s, index=k) for k, s in enumerate(scans[:2]))
        direct = registrar.register_described(a, b)
        a2, b2 = pickle.loads(pickle.dumps(a)), pickle.loads(pickle.dumps(b))
        elsewhere = dpr_gpu.Registrar(**untrusted, context_radii=context).register_described(a2, b2)
        assert not direct.trusted and direct.correspondences > 0
        assert (elsewhere.correspondences, elsewhere.inliers) == (direct.correspondences, direct.inliers)
        np.testing.assert_array_equal(elsewhere.i_from_j, direct.i_from_j)
        results[context] = (direct.correspondences, direct.i_from_j, len(pickle.dumps(a)))
    (matched, pose, size), (matched_main, pose_main, size_main) = results[((2.0, 1.0),)], results[()]
    assert size > size_main  # the context rows travel with the scan...
    assert matched != matched_main or not np.array_equal(pose, pose_main)  # ...and matching read them


def test_multiway_stages_refuse_bad_input(three_scans):
    scans, _ = three_scans
    registrar = dpr_gpu.Registrar(**RECOVER)
    a, b = (registrar.describe_scan(s, index=k) for k, s in enumerate(scans[:2]))
    with pytest.raises(ValueError, match="index must be below"):
        registrar.register_described(b, a)
    other = dpr_gpu.Registrar(**{**RECOVER, "keypoints": 90})
    with pytest.raises(ValueError, match="other settings"):
        other.register_described(a, b)
    with pytest.raises(ValueError, match="different origins"):
        registrar.register_described(a, registrar.describe_scan(scans[1], index=1, origin=(1, 0, 0)))
    with pytest.raises(ValueError, match="scan 4"):
        registrar.describe_scan(np.zeros((3, 3)), index=4)
    restore, (state,) = a.__reduce__()
    assert restore is _dpr_gpu._described_scan_from_state
    with pytest.raises(ValueError, match="truncated"):
        restore(state[:-3])
    with pytest.raises(ValueError, match="unexpected bytes"):
        restore(state + b"x")
    with pytest.raises(ValueError, match="not a pickled DescribedScan"):
        restore(registrar.register_described(a, b).__reduce__()[1][0])
    with pytest.raises(ValueError, match="pooled codeword"):
        dpr_gpu.select_pairs(3, pairs="consecutive+retrieval")
    with pytest.raises(ValueError, match="2 pooled codewords for 3 scans"):
        dpr_gpu.select_pairs(3, [a.pooled_codeword, b.pooled_codeword])
    assert dpr_gpu.select_pairs(4, pairs="all", max_pairs=4) == [(0, 1), (1, 2), (2, 3), (0, 2)]
    pair = registrar.register_described(a, b)
    with pytest.raises(ValueError, match="at least 2 scans"):
        dpr_gpu.optimize_pairs(1, [pair], information_distance=0.1)
    far_pair = registrar.register_described(a, registrar.describe_scan(scans[2], index=2))
    with pytest.raises(ValueError, match=r"pair \(0, 2\) is not i < j < 2"):
        dpr_gpu.optimize_pairs(2, [pair, far_pair], information_distance=0.1)
    with pytest.raises(ValueError, match="PairResult"):
        dpr_gpu.optimize_pairs(2, [a], information_distance=0.1)
    with pytest.raises(ValueError, match="preference"):
        dpr_gpu.optimize_pairs(2, [pair], information_distance=0.1, loop_preference=0.0)


def test_multiway_origin_and_result_files(three_scans, tmp_path):
    scans, _ = three_scans
    assert dpr_gpu.multiway_origin(scans[0]) == (0, 0, 0)
    far = scans[0].astype(np.float64) + [512_000.4, -7_000_000.6, 12.0]
    assert dpr_gpu.multiway_origin(far) == tuple(int(round(c)) for c in far[0])
    graph, _, _ = stages(scans[:2], RECOVER, pairs="all")
    graph.write(tmp_path / "run", ["a.ply", "b.ply"])
    log = (tmp_path / "run" / "trajectory.log").read_text().split("\n")
    # The .log format: a "k k n" line, then world_from_scan's four rows, per scan.
    assert log[0].split() == ["0", "0", "2"] and log[5].split() == ["1", "1", "2"]
    row = np.array([[float(v) for v in log[6 + r].split()] for r in range(4)])
    np.testing.assert_allclose(row, graph.world_from_scan[1], atol=1e-9)
    edges = json.loads((tmp_path / "run" / "edges.json").read_text())
    assert edges["scans"] == 2 and edges["connected"] == graph.connected
    assert [(e["i"], e["j"], e["kind"], e["survived"]) for e in edges["edges"]] == [(0, 1, "odometry", True)]
    assert (tmp_path / "run" / "scans.txt").read_text() == "a.ply\nb.ply\n"
