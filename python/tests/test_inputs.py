"""Arrays in: dtypes and memory layouts give identical results, non-finite rows are dropped as the file readers
drop them, and bad arrays raise ValueError naming the argument."""

from __future__ import annotations

import numpy as np
import pytest

import dpr_gpu
from conftest import QUICK


def _same(a: dpr_gpu.RegistrationResult, b: dpr_gpu.RegistrationResult) -> None:
    np.testing.assert_array_equal(a.target_from_source, b.target_from_source)
    np.testing.assert_array_equal(a.correspondences, b.correspondences)
    np.testing.assert_array_equal(a.source_keypoints, b.source_keypoints)
    np.testing.assert_array_equal(a.target_keypoints, b.target_keypoints)
    assert (a.inliers, a.hypotheses_scored, a.success) == (b.inliers, b.hypotheses_scored, b.success)


def _strided(a: np.ndarray) -> np.ndarray:
    """A view of `a`'s values with non-unit strides along both axes."""
    big = np.zeros((2 * len(a), 7), dtype=a.dtype)
    big[::2, 1:6:2] = a
    view = big[::2, 1:6:2]
    assert not view.flags.c_contiguous and not view.flags.f_contiguous
    return view


def _reversed(a: np.ndarray) -> np.ndarray:
    """A view of `a`'s values (same order) with negative strides."""
    view = a[::-1, ::-1].copy()[::-1, ::-1]
    assert view.strides[0] < 0 and view.strides[1] < 0
    return view


@pytest.fixture(scope="module")
def baseline(room_pair):
    source, target, _ = room_pair
    assert source.dtype == np.float32 and source.flags.c_contiguous
    return dpr_gpu.register(source, target, **QUICK)


@pytest.mark.parametrize(
    "layout",
    [
        lambda a: a.astype(np.float64),
        lambda a: np.asfortranarray(a),
        lambda a: np.asfortranarray(a.astype(np.float64)),
        _strided,
        lambda a: _strided(a.astype(np.float64)),
        _reversed,
        lambda a: a.tolist(),
    ],
    ids=["float64", "fortran", "fortran-float64", "strided", "strided-float64", "negative-strides", "list"],
)
def test_dtypes_and_layouts_give_the_same_result_as_float32_c_order(room_pair, baseline, layout):
    source, target, _ = room_pair
    moved_source, moved_target = layout(source), layout(target)
    np.testing.assert_array_equal(np.asarray(moved_source, dtype=np.float32), source)
    _same(dpr_gpu.register(moved_source, moved_target, **QUICK), baseline)


def test_non_finite_rows_are_dropped_like_the_readers_drop_them(room_pair, baseline):
    source, target, _ = room_pair
    rng = np.random.default_rng(5)
    dirty_source = np.insert(source, [0, 10, 10, 500], [[np.nan, 0, 0], [1, np.inf, 2], [0, 0, -np.inf], [np.nan] * 3], axis=0)
    # A float64 value beyond the float32 range becomes infinite in float32: dropped as well.
    dirty_target = np.insert(target.astype(np.float64), rng.integers(0, len(target), 3), [[1e300, 0, 0]] * 3, axis=0)
    result = dpr_gpu.register(dirty_source, dirty_target, **QUICK)
    _same(result, baseline)
    assert result.dropped_points == 7


def test_rows_with_non_finite_normals_are_dropped(room_pair):
    source, _, _ = room_pair
    registrar = dpr_gpu.Registrar(**QUICK)
    normals = np.tile([0.0, 0.0, 1.0], (len(source), 1))
    clean = registrar.describe(source, normals)
    # Finite points whose normals are not: dropped with their normals, so the description does not change.
    extra = np.insert(source, [3, 9], [[0.5, 0.5, 0.5], [1.0, 0.2, 0.0]], axis=0)
    extra_normals = np.insert(normals, [3, 9], [[np.nan, 0, 1], [0, np.inf, 0]], axis=0)
    dirty = registrar.describe(extra, extra_normals)
    np.testing.assert_array_equal(dirty.keypoints, clean.keypoints)
    np.testing.assert_array_equal(dirty.keypoint_normals, clean.keypoint_normals)


def test_zero_rows_are_dropped_as_sensor_no_returns_by_default(room_pair, baseline):
    source, target, _ = room_pair
    zeros = np.insert(source, [5, 6], 0.0, axis=0)
    # Two or more rows exactly at the origin are no-returns: dropped by default, as with drop_zero_points=True.
    for drop in (None, True):
        result = dpr_gpu.register(zeros, target, drop_zero_points=drop, **QUICK)
        _same(result, baseline)
        assert result.dropped_points == 2
    assert dpr_gpu.register(zeros, target, drop_zero_points=False, **QUICK).dropped_points == 0
    # One alone can be a real sample: kept by default, dropped on request.
    lone = np.insert(source, [5], 0.0, axis=0)
    assert dpr_gpu.register(lone, target, **QUICK).dropped_points == 0
    assert dpr_gpu.register(lone, target, drop_zero_points=True, **QUICK).dropped_points == 1


@pytest.mark.parametrize(
    "points, needle",
    [
        (np.zeros((100, 2)), r"source: expected an array of shape \(N, 3\), got shape \(100, 2\)"),
        (np.zeros(300), r"source: expected an array of shape \(N, 3\), got shape \(300\)"),
        (np.zeros((10, 10, 3)), r"got shape \(10, 10, 3\)"),
        (np.zeros((0, 3)), "source: the array is empty"),
        (np.zeros((0, 3), dtype=np.float32), "source: the array is empty"),
        (np.full((50, 3), np.nan), "source: .*0 points"),
        (np.ones((5, 3)), "source: .*5 points"),
        # Rows all at the origin are sensor no-returns: dropped, which leaves nothing.
        (np.zeros((5, 3)), "source: 0 points"),
        ([[1.0, 2.0], [3.0]], "source: not an array of numbers"),
        (np.array([["a", "b", "c"]] * 20), "source: not an array of numbers"),
    ],
)
def test_bad_arrays_raise_value_error(room_pair, points, needle):
    _, target, _ = room_pair
    with pytest.raises(ValueError, match=needle):
        dpr_gpu.register(points, target, **QUICK)


def test_bad_normals_raise_value_error(room_pair):
    source, target, _ = room_pair
    with pytest.raises(ValueError, match="source: 10 normals for 4000 points"):
        dpr_gpu.register(source, target, source_normals=np.ones((10, 3)), **QUICK)
    with pytest.raises(ValueError, match=r"target normals: expected an array of shape \(N, 3\)"):
        dpr_gpu.register(source, target, target_normals=np.ones((4000, 4)), **QUICK)
    registrar = dpr_gpu.Registrar(**QUICK)
    with pytest.raises(ValueError, match="points: the array is empty"):
        registrar.describe(np.zeros((0, 3)))


def test_looking_for_an_adapter_without_a_session_prints_no_error():
    # Servers and containers have no XDG_RUNTIME_DIR; Mesa's device-select layer would print "error: ..." twice.
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "NODEVICE_SELECT")}
    code = "import dpr_gpu; print(dpr_gpu.Registrar(backend='auto', keypoints=100).backend)"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip(), "no backend named"
    assert "error" not in done.stderr.lower(), done.stderr
