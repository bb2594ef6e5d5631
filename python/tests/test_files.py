"""Files: read_cloud uses the command line's readers, file errors raise OSError, and register on arrays gives
exactly the command line's result on the same files and seed."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

import dpr_gpu
from conftest import REPO, cli_binary

EXAMPLE = REPO / "examples" / "pair"


def test_read_cloud_returns_points_and_normals_and_drops_non_finite_rows(tmp_path):
    rows = np.array(
        [
            [0.5, 1.25, -2.0, 0.0, 0.0, 1.0],
            [np.nan, 1.0, 1.0, 1.0, 0.0, 0.0],
            [3.0, 4.0, 5.0, 0.0, 1.0, 0.0],
            [6.0, 7.0, 8.0, np.inf, 0.0, 0.0],
        ]
    )
    path = tmp_path / "cloud.xyz"
    np.savetxt(path, rows, fmt="%.9g")
    # Column 4 of the last row is not a unit normal, so the columns are named (the default would refuse them).
    points, normals = dpr_gpu.read_cloud(path, xyz_columns="x,y,z,nx,ny,nz")
    assert points.dtype == np.float64 and normals.dtype == np.float64
    np.testing.assert_array_equal(points, rows[[0, 2], :3])
    np.testing.assert_array_equal(normals, rows[[0, 2], 3:])
    # Read as colours, column 4 no longer makes the last row invalid.
    only_points, none = dpr_gpu.read_cloud(str(path), xyz_columns="x,y,z,r,g,b")
    assert none is None
    np.testing.assert_array_equal(only_points, rows[[0, 2, 3], :3])


def test_read_cloud_reads_the_example_ply_with_normals():
    points, normals = dpr_gpu.read_cloud(EXAMPLE / "cloud_bin_1.ply")
    assert points.ndim == 2 and points.shape[1] == 3 and len(points) > 1000
    assert normals is not None and normals.shape == points.shape
    assert np.isfinite(points).all()


def test_georeferenced_coordinates_keep_their_magnitude(tmp_path):
    offset = np.array([512_345.0, 4_987_654.0, 250.0])
    rows = offset + np.array([[0.25, 0.5, 0.75], [1.5, -2.0, 3.25]])
    path = tmp_path / "geo.txt"
    np.savetxt(path, rows, fmt="%.17g")
    points, _ = dpr_gpu.read_cloud(path)
    np.testing.assert_array_equal(points, rows)


def test_file_errors_raise_os_error_and_bad_contents_value_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        dpr_gpu.read_cloud(tmp_path / "missing.ply")
    with pytest.raises(OSError):
        dpr_gpu.read_cloud(tmp_path)
    with pytest.raises(ValueError, match="unsupported extension '.obj'"):
        dpr_gpu.read_cloud(tmp_path / "mesh.obj")
    broken = tmp_path / "broken.ply"
    broken.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n")
    with pytest.raises(ValueError, match="broken.ply"):
        dpr_gpu.read_cloud(broken)
    with pytest.raises(FileNotFoundError, match="nowhere.safetensors"):
        dpr_gpu.Registrar(weights=tmp_path / "nowhere.safetensors", backend="cpu")
    not_weights = tmp_path / "w.safetensors"
    not_weights.write_bytes(b"not a safetensors file at all")
    with pytest.raises(ValueError, match="w.safetensors"):
        dpr_gpu.Registrar(weights=not_weights, backend="cpu")


def _cli_json(binary: Path, source: Path, target: Path, args: list[str]) -> dict:
    done = subprocess.run(
        [str(binary), "register", str(source), str(target), "--json", "--backend", "cpu", *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
    )
    # Exit status 3: registered, but the verdict does not trust the pose; the JSON is printed either way.
    assert done.returncode in (0, 3), done.stderr
    return json.loads(done.stdout)


CASES = {
    # The defaults (RelativeNet), float32 values, NaN rows in both files.
    "relativenet": ({"keypoints": 60, "seed": 11}, ["--keypoints", "60", "--seed", "11"], np.zeros(3)),
    # RANSAC, farthest-point keypoints, ICP, mutual-2 matching, and georeferenced coordinates (shifted by one
    # origin before the float32 conversion, as the command line shifts them).
    "ransac-icp-georeferenced": (
        {"keypoints": 60, "seed": 5, "estimator": "ransac", "keypoint_mode": "uniform", "icp": True, "mutual_k": 2},
        ["--keypoints", "60", "--seed", "5", "--estimator", "ransac", "--keypoint-mode", "uniform", "--icp",
         "--mutual", "2"],
        np.array([612_345.0, -4_321_987.0, 312.0]),
    ),
}


def _assert_same_as_cli(result: dpr_gpu.RegistrationResult, cli: dict) -> None:
    np.testing.assert_allclose(result.target_from_source, np.array(cli["target_from_source"]), rtol=0, atol=1e-9)
    assert result.inliers == cli["inliers"]
    assert result.fitness == pytest.approx(cli["fitness"], abs=1e-12)
    assert result.inlier_rmse == pytest.approx(cli["inlier_rmse"], abs=1e-12)
    assert len(result.correspondences) == cli["correspondences"]
    assert result.hypotheses_scored == cli["hypotheses_scored"]
    assert result.empty_patches == cli["empty_patches"]
    assert result.success == cli["success"] and result.reason == cli["reason"]
    assert result.backend == cli["backend"]
    # Python sums the times of a stage that ran in several rounds, under its first position.
    assert list(result.timings) == list(dict.fromkeys(t["stage"] for t in cli["timings"] if t["stage"] != "load"))


@pytest.mark.parametrize("case", sorted(CASES))
def test_register_equals_the_command_line_on_the_same_files_and_seed(tmp_path, room_pair, case):
    binary = cli_binary()
    if binary is None:
        pytest.skip("no dpr-gpu binary: build it (cargo build) or set DPR_GPU_CLI")
    assert binary.is_file(), f"DPR_GPU_CLI={binary} does not exist"
    settings, flags, offset = CASES[case]
    source, target, _ = room_pair
    source = np.insert(source.astype(np.float64), [0, 100], [[np.nan, 1, 2], [4, np.inf, 5]], axis=0) + offset
    target = np.insert(target.astype(np.float64), [7], [[np.nan] * 3], axis=0) + offset
    paths = tmp_path / "source.xyz", tmp_path / "target.xyz"
    for path, cloud in zip(paths, (source, target)):
        np.savetxt(path, cloud, fmt="%.17g")  # exact float64 text: the file and the arrays hold the same values
    cli = _cli_json(binary, *paths, flags)

    from_arrays = dpr_gpu.register(source, target, backend="cpu", **settings)
    _assert_same_as_cli(from_arrays, cli)
    # read_cloud returns each file's values through float32 relative to that file's own origin, so georeferenced
    # files read one by one can differ from the command line's single shift by a float32 rounding: there the
    # poses agree to that precision (compared where the scans lie, since 1e-9 of rotation moves the far origin).
    from_files = dpr_gpu.register(*[dpr_gpu.read_cloud(p)[0] for p in paths], backend="cpu", **settings)
    if not offset.any():
        _assert_same_as_cli(from_files, cli)
    else:
        near = source[np.isfinite(source).all(axis=1)][:100]
        moved = [near @ t[:3, :3].T + t[:3, 3] for t in (from_files.target_from_source, np.array(cli["target_from_source"]))]
        np.testing.assert_allclose(moved[0], moved[1], rtol=0, atol=1e-3)
    assert from_arrays.dropped_points == cli["dropped_points"] == 3
    assert cli["source_points"] == len(source) - 2 and cli["target_points"] == len(target) - 1
    assert (np.array(cli["origin"]) != 0).any() == offset.any()


def _readme_python_blocks() -> list[str]:
    """The ```python blocks of the top-level README, in order."""
    text = (REPO / "README.md").read_text()
    return [part.split("```", 1)[0] for part in text.split("```python\n")[1:]]


def test_the_readme_snippet_gives_the_command_lines_pose_and_writes_outside_the_checkout(tmp_path, monkeypatch):
    """The README's Python snippet, run as written from the repository root, registers the example pair to the
    pose `dpr-gpu register` gives on the same files, and writes its picture to the temporary folder."""
    binary = cli_binary()
    if binary is None:
        pytest.skip("no dpr-gpu binary: build it (cargo build) or set DPR_GPU_CLI")
    import tempfile

    monkeypatch.chdir(REPO)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    before = set(REPO.iterdir())
    namespace: dict = {}
    exec(compile(_readme_python_blocks()[0], "README.md", "exec"), namespace)
    result = namespace["result"]
    assert result.backend.startswith("cpu"), "the comparison below is with the CPU backend"
    cli = _cli_json(binary, EXAMPLE / "cloud_bin_1.ply", EXAMPLE / "cloud_bin_0.ply", ["--seed", "0"])
    _assert_same_as_cli(result, cli)
    assert result.success
    assert (tmp_path / "pair.png").is_file() and set(REPO.iterdir()) == before
