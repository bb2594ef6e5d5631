"""dpr_gpu.distributed: multiway registration on a local Ray (two worker actors on this machine) equals the
single-process dpr_gpu.multiway on the same generated collection, and the work really ran on the actors.

Ray is an optional dependency: without it these tests are skipped, except in CI (CI=true), where .ci/run
installs it and a missing Ray fails them."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import dpr_gpu
from conftest import RECOVER, cli_binary, known_pose, room_corner, rotation_error_deg, transform
from dpr_gpu import distributed

# conftest's RECOVER settings (ICP recovers this collection's poses) with a low inlier minimum (see MIXED below
# for a verdict that trusts some pairs and not others, so the pose graph has certain, uncertain and excluded
# edges).
# The small generated scans were sized for the defaults before 0.60 m patches: 0.30 m patches and, computed as
# the library computed them then (in float32), a radius / 12 voxel, a radius / 3 inlier threshold and a radius / 6
# ICP distance.
_R = np.float32(0.3)
SMALL = {
    "radius": float(_R),
    "voxel": float(_R * np.float32(1 / 12)),
    "inlier_threshold": float(_R / np.float32(3)),
    "icp_max_correspondence_distance": float(_R / np.float32(6)),
}
SETTINGS = {**RECOVER, "min_inliers": 3, **SMALL}
FLAGS = ["--radius", repr(SMALL["radius"]), "--voxel", repr(SMALL["voxel"])]
FLAGS += ["--inlier-threshold", repr(SMALL["inlier_threshold"])]
FLAGS += ["--icp-distance", repr(SMALL["icp_max_correspondence_distance"])]
FLAGS += ["--keypoints", "150", "--keypoint-mode", "uniform", "--estimator", "ransac", "--icp", "--seed", "7"]
FLAGS += ["--backend", "cpu", "--min-inliers", "3", "--pairs", "consecutive+retrieval", "--retrieval-k", "1"]


@pytest.fixture(scope="module")
def ray():
    """A local Ray with 2 CPUs for this module, shut down after it."""
    if os.environ.get("CI"):
        import ray  # CI installs Ray (.ci/run): a missing Ray must fail the tests, not skip them
    else:
        ray = pytest.importorskip("ray", reason="pip install ray (or './python[distributed]') to test this")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def collection():
    """Four samples of the room, scan k seen from world_from_scan[k] (scan 0: the identity), every scanner at
    the room's centre (the world origin) and turned by a uniform random rotation: normals estimated without a
    file face each scan's origin (the default viewpoint), so they face the same way in every scan. (Scanners
    placed elsewhere flipped some scans' normals, and the pairs registered only by chance.)"""
    rng = np.random.default_rng(11)
    centre = np.array([1.0, 1.0, 0.75])
    turned = [known_pose(rng) for _ in range(3)]
    for w in turned:
        w[:3, 3] = 0.0
    world_from_scan = [np.eye(4)] + turned
    room = [room_corner(rng, 4000) - centre for _ in world_from_scan]
    scans = [transform(np.linalg.inv(w), r).astype(np.float32) for w, r in zip(world_from_scan, room)]
    return scans, world_from_scan


def assert_same_multiway(a, b):
    """Two multiway dicts agree: poses to 1e-9 (they are bit-identical in practice), every edge field exactly."""
    np.testing.assert_allclose(a["world_from_scan"], b["world_from_scan"], rtol=0, atol=1e-9)
    assert a["connected"] == b["connected"]
    assert a["line_process_weight"] == pytest.approx(b["line_process_weight"], rel=1e-12)
    assert [(e["i"], e["j"]) for e in a["edges"]] == [(e["i"], e["j"]) for e in b["edges"]]
    for ea, eb in zip(a["edges"], b["edges"]):
        assert ea.keys() == eb.keys()
        for key in ea:
            np.testing.assert_array_equal(ea[key], eb[key], err_msg=f"edge ({ea['i']}, {ea['j']}) {key}")


# The default context radius rescues every pair of this collection at min_inliers=3 (the context round of (0, 3)
# goes from 2 to 16 inliers); at 18, pairs (1, 2) and (0, 3) stay untrusted after it (17 and 16 inliers) while
# the others have 19-34, with the bf16 and the f32 encoders alike.
MIXED = {**SETTINGS, "min_inliers": 18}


def test_ray_run_equals_single_process_and_uses_every_actor(ray, collection):
    scans, truth = collection
    single = dpr_gpu.multiway(scans, pairs="all", **MIXED)
    outcome = distributed.run(scans, pairs="all", workers=2, batch_size=2, **MIXED)
    assert_same_multiway(outcome.result.to_dict(), single)

    # The work ran on the two actors (distinct Ray actor ids, neither the driver), both describing and
    # registering; a scan's features were fetched at most once per actor.
    actor_ids = {w["worker"] for w in outcome.workers}
    assert len(actor_ids) == 2 and all(len(a) == 32 for a in actor_ids)  # hex ActorID
    assert set(outcome.described_by) == actor_ids
    assert set(outcome.registered_by.values()) == actor_ids
    assert sorted(outcome.registered_by) == sorted((e["i"], e["j"]) for e in single["edges"])
    assert all(w["backend"].startswith("cpu") and 0 <= w["fetched_scans"] <= len(scans) for w in outcome.workers)
    assert len(outcome.describe_seconds) == 4 and all(s > 0 for s in outcome.describe_seconds)

    # The poses are near the truth, so the comparison above is between real registrations, not between two
    # identity trajectories; and the verdict trusted some pairs and not others.
    for k in range(1, 4):
        assert rotation_error_deg(single["world_from_scan"][k], truth[k]) < 2.0
        assert np.linalg.norm(single["world_from_scan"][k][:3, 3] - truth[k][:3, 3]) < 0.05
    trusted = [e["trusted"] for e in single["edges"]]
    assert any(trusted) and not all(trusted), trusted


@pytest.fixture(scope="module")
def folder_run(ray, collection, tmp_path_factory):
    """The collection as .xyz files in a folder, and `python -m dpr_gpu.distributed` run on it (2 workers,
    consecutive pairs plus 1 retrieved scan per scan); returns (folder, scan names, output folder)."""
    scans, _ = collection
    root = tmp_path_factory.mktemp("distributed")
    folder = root / "scans"
    folder.mkdir()
    # Names in natural order (scan_2 before scan_10) are how both command lines list a folder.
    names = ["scan_1.xyz", "scan_2.xyz", "scan_10.xyz", "scan_11.xyz"]
    for name, scan in zip(names, scans):
        np.savetxt(folder / name, scan, fmt="%.9g")
    (folder / "pairs.txt").write_text("metadata, not a scan\n")
    status = distributed.main([str(folder), "--out", str(root / "ray"), "--workers", "2", "--batch-size", "3", *FLAGS])
    assert status == 0
    return folder, names, root / "ray"


def test_ray_command_line_writes_the_single_process_result(folder_run):
    folder, names, out = folder_run
    assert [p.name for p in distributed.scan_paths(folder)] == names
    read = [dpr_gpu.read_cloud(folder / name)[0] for name in names]
    single = dpr_gpu.multiway(read, pairs="consecutive+retrieval", retrieval_k=1, **SETTINGS)
    assert any(e["kind"] == "loop" for e in single["edges"])  # retrieval added loop-closure candidates
    edges = json.loads((out / "edges.json").read_text())
    assert edges["scans"] == 4 and edges["connected"] == single["connected"]
    for written, e in zip(edges["edges"], single["edges"]):
        for key in ("i", "j", "kind", "trusted", "in_graph", "survived", "line_process"):
            assert written[key] == e[key], key
        np.testing.assert_array_equal(np.array(written["i_from_j"]), e["i_from_j"])
    assert len(edges["edges"]) == len(single["edges"])
    text = (out / "trajectory.log").read_text().split("\n")
    for k in range(4):
        assert text[5 * k].split() == [str(k), str(k), "4"]
        # The .log holds 9 significant digits.
        pose = np.array([[float(v) for v in text[5 * k + 1 + r].split()] for r in range(4)])
        np.testing.assert_allclose(pose, single["world_from_scan"][k], rtol=1e-8, atol=1e-9)
    assert (out / "scans.txt").read_text().split() == [str(folder / n) for n in names]

    # Paths instead of arrays: each worker reads the scans it describes, with the same result.
    paths = [str(folder / n) for n in names]
    by_path = distributed.multiway(paths, pairs="consecutive+retrieval", retrieval_k=1, workers=2, **SETTINGS)
    assert_same_multiway(by_path, single)


def test_ray_command_line_writes_what_dpr_gpu_multiway_writes(folder_run):
    folder, _, out = folder_run
    cli = cli_binary()
    if cli is None:
        pytest.skip("no dpr-gpu command line built (cargo build) to compare the files with")
    done = subprocess.run(
        [str(cli), "multiway", str(folder), "--out", str(out.parent / "cli")] + FLAGS,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    # The same trajectory, character for character, and the same edges file but for the per-pair timings.
    assert (out.parent / "cli" / "trajectory.log").read_text() == (out / "trajectory.log").read_text()
    assert (out.parent / "cli" / "scans.txt").read_text() == (out / "scans.txt").read_text()
    cli_edges, ray_edges = (json.loads((d / "edges.json").read_text()) for d in (out.parent / "cli", out))
    for e in cli_edges["edges"] + ray_edges["edges"]:
        assert e.pop("seconds") >= 0
    assert cli_edges == ray_edges


def test_ray_run_reports_bad_input_before_starting_workers(ray, collection):
    scans, _ = collection
    with pytest.raises(ValueError, match="at least 2 scans"):
        distributed.run(scans[:1], **SETTINGS)
    with pytest.raises(ValueError, match="unknown pairs"):
        distributed.run(scans, pairs="some", **SETTINGS)
    with pytest.raises(ValueError, match="retrieval_k"):
        distributed.run(scans, retrieval_k=-1, **SETTINGS)
    with pytest.raises(ValueError, match="keypoint_mode"):
        distributed.run(scans, **{**SETTINGS, "keypoint_mode": "grid"})
    # A scan that cannot be described fails the run with the library's message, naming the scan.
    with pytest.raises(ValueError, match="scan 2"):
        distributed.run(scans[:2] + [np.zeros((4, 3))], workers=1, **SETTINGS)


def test_without_ray_the_error_names_the_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails as if Ray were not installed
    with pytest.raises(ImportError, match=r"pip install 'dpr-gpu\[distributed\]'"):
        distributed.run([np.zeros((10, 3))] * 2, backend="cpu")


def test_adapter_index_picks_the_adapter_by_position(monkeypatch):
    """What puts each GPU actor on its own GPU: DPR_GPU_ADAPTER_INDEX=k takes the k-th adapter (hardware ones
    first; `backend="gpu"` may take a software rasteriser after them, as CI's lavapipe), and an index past the
    last adapter is an error naming the variable. Needs a Vulkan adapter (CI installs lavapipe)."""
    for name in ("WGPU_ADAPTER_NAME", "DPR_GPU_ADAPTER_INDEX"):
        monkeypatch.delenv(name, raising=False)
    try:
        dpr_gpu.Registrar(backend="gpu", keypoints=10)
    except RuntimeError as e:
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no GPU adapter here: {e}")
    monkeypatch.setenv("DPR_GPU_ADAPTER_INDEX", "0")
    assert not dpr_gpu.Registrar(backend="gpu", keypoints=10).backend.startswith("cpu")
    monkeypatch.setenv("DPR_GPU_ADAPTER_INDEX", "99")
    with pytest.raises(RuntimeError, match="DPR_GPU_ADAPTER_INDEX=99 but only"):
        dpr_gpu.Registrar(backend="gpu", keypoints=10)
    monkeypatch.setenv("DPR_GPU_ADAPTER_INDEX", "first")
    with pytest.raises(RuntimeError, match="not an adapter index"):
        dpr_gpu.Registrar(backend="gpu", keypoints=10)


def test_context_radius_flags_parse_as_dpr_gpu_multiway_parses_them():
    defaults = dpr_gpu._dpr_gpu._library_defaults()
    assert distributed._context_radii(None) == defaults["context_radii"] == [(2.0, 1.0)]
    assert distributed._context_radii(["off"]) == []
    assert distributed._context_radii(["3:0.5", "1.5:2"]) == [(3.0, 0.5), (1.5, 2.0)]
    for bad, needle in ((["off", "2:1"], "cannot be combined"), (["2"], "FACTOR:WEIGHT"), (["a:b"], "FACTOR:WEIGHT")):
        with pytest.raises(ValueError, match=needle):
            distributed._context_radii(bad)
    parsed = distributed._arguments().parse_args(["in", "--out", "o", "--context-radius", "off"])
    settings = distributed._settings_of(parsed)
    assert (settings["context_radii"], settings["context_when"]) == ([], "untrusted")
