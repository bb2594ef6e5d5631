"""Registration through the Python API: a known transform recovered, the result's fields checked against
independent recomputation, the step-by-step API reproducing register, and the GIL released while computing."""

from __future__ import annotations

import pickle
import sys
import threading
import time

import numpy as np
import pytest

import dpr_gpu
from conftest import QUICK, RECOVER, rotation_error_deg


def test_a_known_transform_is_recovered_with_the_built_in_weights(room_pair):
    source, target, truth = room_pair
    result = dpr_gpu.register(source, target, **RECOVER)
    t = result.target_from_source
    assert t.shape == (4, 4) and t.dtype == np.float64
    assert rotation_error_deg(t, truth) < 0.5, rotation_error_deg(t, truth)
    assert np.linalg.norm(t[:3, 3] - truth[:3, 3]) < 0.01
    np.testing.assert_allclose(t[3], [0, 0, 0, 1])
    assert result.backend.startswith("cpu")
    assert result.hypotheses_scored >= 1


def test_the_result_fields_agree_with_each_other(room_pair):
    source, target, _ = room_pair
    # Every point kept (no default voxel for these normal-less arrays), so keypoints are input points.
    registrar = dpr_gpu.Registrar(**RECOVER, voxel=0)
    result = registrar.register(source, target)
    pairs = result.correspondences
    assert pairs.dtype == np.int64 and pairs.ndim == 2 and pairs.shape[1] == 2 and len(pairs) >= 3
    src_kp, tgt_kp = result.source_keypoints, result.target_keypoints
    assert src_kp.shape[1] == 3 and tgt_kp.shape[1] == 3
    assert 0 <= pairs[:, 0].min() and pairs[:, 0].max() < len(src_kp)
    assert 0 <= pairs[:, 1].min() and pairs[:, 1].max() < len(tgt_kp)
    assert len(src_kp) + result.empty_patches <= RECOVER["keypoints"] * 2
    assert result.feature_distances.shape == (len(pairs),)
    # Keypoints are points of the input clouds.
    for kp, cloud in ((src_kp, source), (tgt_kp, target)):
        nearest = np.min(np.linalg.norm(kp[:, None, :] - cloud[None, ::1, :], axis=2), axis=1)
        assert nearest.max() < 1e-6
    # Inliers, fitness and RMSE recomputed from the correspondences under the returned pose.
    t = result.target_from_source
    residuals = np.linalg.norm(src_kp[pairs[:, 0]] @ t[:3, :3].T + t[:3, 3] - tgt_kp[pairs[:, 1]], axis=1)
    # register chose its own scale from the two clouds (no radius given): count with the threshold it used,
    # not the registrar's, which is the steps' default.
    inlier = residuals < result.scale["inlier_threshold"]
    assert result.inliers == inlier.sum()
    assert result.fitness == pytest.approx(inlier.sum() / len(pairs))
    assert result.inlier_rmse == pytest.approx(np.sqrt(np.mean(residuals[inlier] ** 2)), rel=1e-4)
    # The verdict: success exactly when there is no reason.
    assert (result.reason is None) == result.success
    assert list(result.timings)[:3] == ["source.downsample", "source.index", "source.keypoints"]
    assert {"matching", "pc_encoder", "estimation", "target.ppf_encoder"} <= set(result.timings)
    assert all(s >= 0 for s in result.timings.values())
    assert result.dropped_points == 0
    assert "RegistrationResult(success=" in repr(result)


def test_the_steps_reproduce_register(room_pair):
    source, target, _ = room_pair
    whole = dpr_gpu.Registrar(**QUICK).register(source, target)
    # The steps see one scan at a time: give them the radius register chose from the two clouds.
    registrar = dpr_gpu.Registrar(**QUICK, radius=whole.scale["radius"])
    a = registrar.describe(source, stream=0)
    b = registrar.describe(target, stream=1)
    np.testing.assert_array_equal(a.keypoints, whole.source_keypoints)
    np.testing.assert_array_equal(b.keypoints, whole.target_keypoints)
    assert len(a) == len(whole.source_keypoints) and a.stream == 0
    assert a.keypoint_normals.shape == a.keypoints.shape
    np.testing.assert_allclose(np.linalg.norm(a.keypoint_normals, axis=1), 1, atol=1e-5)
    pairs = registrar.correspond(a, b)
    np.testing.assert_array_equal(pairs, whole.correspondences)
    estimate = registrar.estimate(a, b, pairs)
    np.testing.assert_array_equal(estimate.target_from_source, whole.target_from_source)
    assert (estimate.inliers, estimate.hypotheses_scored) == (whole.inliers, whole.hypotheses_scored)
    # Other integer dtypes are accepted; the estimator can be overridden.
    same = registrar.estimate(a, b, pairs.astype(np.uint32))
    np.testing.assert_array_equal(same.target_from_source, whole.target_from_source)
    assert registrar.estimate(a, b, pairs, estimator="ransac").hypotheses_scored >= 1


def test_the_steps_refuse_foreign_features_and_bad_indices(room_pair):
    source, target, _ = room_pair
    registrar = dpr_gpu.Registrar(**QUICK)
    a, b = registrar.describe(source), registrar.describe(target, stream=1)
    pairs = registrar.correspond(a, b)
    # Scans described with other settings have descriptors that do not match: refused. A registrar with the same
    # settings takes them (as it takes pickled ones) and finds the same correspondences.
    other = dpr_gpu.Registrar(**{**QUICK, "keypoints": QUICK["keypoints"] + 1})
    with pytest.raises(ValueError, match="other settings or weights"):
        other.correspond(a, b)
    np.testing.assert_array_equal(dpr_gpu.Registrar(**QUICK).correspond(a, b), pairs)
    # One wrapper for every described scan: the steps' scans pickle like the collection's.
    assert isinstance(a, dpr_gpu.DescribedScan) and dpr_gpu.Features is dpr_gpu.DescribedScan
    np.testing.assert_array_equal(registrar.correspond(pickle.loads(pickle.dumps(a)), b), pairs)
    bad = pairs.copy()
    bad[0, 1] = len(b)
    with pytest.raises(ValueError, match="out of range"):
        registrar.estimate(a, b, bad)
    with pytest.raises(ValueError, match="at least 3"):
        registrar.estimate(a, b, pairs[:2])
    with pytest.raises(ValueError, match=r"\(K, 2\)"):
        registrar.estimate(a, b, pairs.astype(np.float64))
    with pytest.raises(ValueError, match="unknown estimator"):
        registrar.estimate(a, b, pairs, estimator="icp")


def test_same_inputs_and_seed_give_the_same_result_and_seeds_matter(room_pair):
    source, target, _ = room_pair
    first = dpr_gpu.register(source, target, **QUICK)
    again = dpr_gpu.register(source, target, **QUICK)
    np.testing.assert_array_equal(first.target_from_source, again.target_from_source)
    np.testing.assert_array_equal(first.correspondences, again.correspondences)
    other = dpr_gpu.register(source, target, **{**QUICK, "seed": QUICK["seed"] + 1})
    assert not np.array_equal(first.source_keypoints, other.source_keypoints)


def test_the_gil_is_released_while_registering(room_pair):
    source, target, _ = room_pair
    # Long enough to tell: every keypoint described at once, three times (each call about 0.4 s with the pruned
    # model's bf16 encoders on 2 cores, several times that with f32); a call that held the GIL would stop the
    # loop below for its whole length.
    registrar = dpr_gpu.Registrar(**{**QUICK, "keypoints": 1500, "first_keypoints": None})

    def register_three_times():
        for _ in range(3):
            registrar.register(source, target)

    worker = threading.Thread(target=register_three_times)
    started = time.perf_counter()
    worker.start()
    ticks = 0
    while worker.is_alive():
        time.sleep(0.01)
        ticks += 1
    elapsed = time.perf_counter() - started
    assert elapsed > 0.5, "registration too short to tell"
    # Holding the GIL would stop this loop for the whole call; released, it ticks every ~10 ms.
    assert ticks > 0.25 * elapsed / 0.01, (ticks, elapsed)


def test_settings_defaults_follow_the_library():
    import inspect

    defaults = dpr_gpu._dpr_gpu._library_defaults()
    # The signature Python shows (help(), IDEs), read from the text signature; the stable ABI gives compiled
    # classes one from Python 3.10 on.
    text_signature = dpr_gpu.Registrar.__text_signature__
    if text_signature is None:
        assert sys.version_info < (3, 10)
        text_signature = "(**settings)"
    namespace: dict = {}
    exec(f"def registrar{text_signature}: pass", namespace)
    parameters = inspect.signature(namespace["registrar"]).parameters
    # backend="cpu" only: the default "auto" would open a GPU device where one exists.
    effective = dpr_gpu.Registrar(backend="cpu").settings
    for name, value in defaults.items():
        if name == "backend":
            continue  # Python defaults to "auto" (a GPU when there is one); the library to "cpu".
        if name in ("icp_max_correspondence_distance", "icp_max_iterations"):
            continue  # resolved against the radius; checked below.
        assert effective[name] == value, name
        if sys.version_info >= (3, 10):
            default = parameters[name].default
            assert (tuple(default) if name == "viewpoint" else default) == value, name
    assert sys.version_info < (3, 10) or parameters["backend"].default == "auto"
    assert effective["icp"] is True  # on by default
    no_icp = dpr_gpu.Registrar(icp=False, backend="cpu").settings
    assert no_icp["icp_max_iterations"] is None and no_icp["icp_max_correspondence_distance"] is None
    icp = dpr_gpu.Registrar(backend="cpu")
    assert icp.settings["icp_max_iterations"] == 30
    assert icp.settings["icp_max_correspondence_distance"] == pytest.approx(icp.radius / 12)
    assert icp.radius == pytest.approx(0.60) and icp.inlier_threshold == pytest.approx(0.10)


@pytest.mark.parametrize(
    "settings, needle",
    [
        ({"keypoints": 0}, "keypoints must be"),
        ({"keypoints": -5}, "keypoints must not be negative"),
        ({"radius": -1.0}, "radius must be positive"),
        ({"estimator": "teaser"}, "unknown estimator 'teaser'"),
        ({"backend": "tpu"}, "unknown backend 'tpu'"),
        ({"keypoint_mode": "grid"}, "unknown keypoint_mode"),
        ({"matching": "mutual", "mutual_k": 7}, "mutual K must be 1..4"),
        ({"ransac_confidence": 1.5}, "RANSAC confidence"),
        ({"seed": -1}, "seed must be"),
        ({"min_inlier_ratio": 2.0}, "min inlier ratio"),
        ({"viewpoint": (0.0, float("nan"), 0.0)}, "viewpoint must be finite"),
        ({"context_radii": ((0.5, 1.0),)}, "context radius factor"),
        ({"context_radii": ((2.0, 0.0),)}, "context radius weight"),
        ({"context_when": "sometimes"}, "unknown context_when"),
        ({"pose_candidates": 0}, "pose candidates must be"),
        ({"pose_candidates": -2}, "pose_candidates must not be negative"),
    ],
)
def test_bad_settings_raise_value_error(settings, needle):
    with pytest.raises(ValueError, match=needle):
        dpr_gpu.Registrar(**{"backend": "cpu", **settings})


def test_unknown_settings_raise_type_error():
    with pytest.raises(TypeError):
        dpr_gpu.register(np.zeros((20, 3)), np.zeros((20, 3)), keypoint=10)


def test_snapshot_writes_the_documented_png_and_refuses_a_missing_folder(room_pair, tmp_path):
    import struct

    source, target, _ = room_pair
    result = dpr_gpu.register(source, target, **RECOVER)
    out = tmp_path / "pair.png"
    result.snapshot(out)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    # Three 360-pixel panels per row, two rows, 4-pixel gaps, and three 20-pixel bands of text (over each row,
    # the legend under them): the library's default layout.
    assert (width, height) == (3 * 360 + 4 * 4, 2 * 360 + 3 * 4 + 3 * 20)
    result.snapshot(tmp_path / "no_lines.png", inliers=False)
    assert (tmp_path / "no_lines.png").read_bytes() != data
    with pytest.raises((OSError, ValueError), match="does not exist"):
        result.snapshot(tmp_path / "missing" / "pair.png")
