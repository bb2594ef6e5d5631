"""dpr_gpu.pose_graph: a graph whose true poses are known comes back at them; a g2o file gives what the command
line writes; wrong loop closures are pruned under the robust kernel; bad input raises a clear error."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import dpr_gpu
from conftest import cli_binary, known_pose, rotation_error_deg

INFORMATION = np.diag([100.0, 100.0, 100.0, 400.0, 400.0, 400.0])


def _quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    m = rotation
    t = np.trace(m)
    if t > 0:
        s = 2 * np.sqrt(1 + t)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        k = int(np.argmax(np.diag(m)))
        i, j = (k + 1) % 3, (k + 2) % 3
        s = 2 * np.sqrt(1 + m[k, k] - m[i, i] - m[j, j])
        q = [0.0] * 4
        q[k], q[i], q[j] = s / 4, (m[i, k] + m[k, i]) / s, (m[j, k] + m[k, j]) / s
        q[3] = (m[j, i] - m[i, j]) / s
    return np.array(q)


def _ring(n: int, seed: int):
    """True world_from_node of n poses on a noisy ring (node 0 at the origin) and exact edges: odometry k -> k+1
    and a loop closure every fifth node to the one five back."""
    rng = np.random.default_rng(seed)
    truth = [np.eye(4)]
    for _ in range(1, n):
        step = known_pose(rng)
        step[:3, 3] *= 0.5
        truth.append(truth[-1] @ step)
    edges = [(k, k + 1) for k in range(n - 1)] + [(k - 5, k) for k in range(5, n, 5)]
    measured = [(i, j, np.linalg.inv(truth[i]) @ truth[j], INFORMATION) for i, j in edges]
    return truth, measured


def _write_g2o(path, poses, edges) -> None:
    lines = []
    for k, pose in enumerate(poses):
        q = _quaternion_xyzw(pose[:3, :3])
        lines.append("VERTEX_SE3:QUAT %d %s" % (k, " ".join("%.17g" % v for v in [*pose[:3, 3], *q])))
    for i, j, i_from_j, information in edges:
        q = _quaternion_xyzw(i_from_j[:3, :3])
        upper = [information[r, c] for r in range(6) for c in range(r, 6)]
        values = [*i_from_j[:3, 3], *q, *upper]
        lines.append("EDGE_SE3:QUAT %d %d %s" % (i, j, " ".join("%.17g" % v for v in values)))
    path.write_text("\n".join(lines) + "\n")


def _perturbed(truth, seed: int):
    """The true poses, each but the first moved by up to ~0.1 rad and 0.1 m."""
    rng = np.random.default_rng(seed)
    out = [truth[0].copy()]
    for pose in truth[1:]:
        axis = rng.normal(size=3)
        angle = 0.1 * rng.uniform()
        k = axis / np.linalg.norm(axis)
        cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        nudge = np.eye(4)
        nudge[:3, :3] = np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
        nudge[:3, 3] = rng.uniform(-0.1, 0.1, 3)
        out.append(pose @ nudge)
    return out


def _assert_at(poses, truth, rotation_deg: float, translation_m: float) -> None:
    assert poses.shape == (len(truth), 4, 4) and poses.dtype == np.float64
    for k, pose in enumerate(truth):
        assert rotation_error_deg(poses[k], pose) < rotation_deg, k
        assert np.linalg.norm(poses[k][:3, 3] - pose[:3, 3]) < translation_m, k


def test_exact_edges_bring_a_perturbed_start_back_to_the_true_poses():
    truth, edges = _ring(30, seed=1)
    start = _perturbed(truth, seed=2)
    result = dpr_gpu.pose_graph(edges, poses=np.stack(start), init="file")
    _assert_at(result["world_from_node"], truth, 1e-4, 1e-8)
    assert result["given_error"] > 1.0 and result["final_error"] < 1e-12
    assert result["initial_error"] == result["given_error"] and result["iterations"] >= 1
    assert result["ids"] == list(range(30))
    np.testing.assert_array_equal(result["weights"], np.ones(len(edges)))
    # Without poses the start is chordal (every node at the identity before it): the same optimum.
    chordal = dpr_gpu.pose_graph(edges)
    _assert_at(chordal["world_from_node"], truth, 1e-4, 1e-8)
    assert (result["start"], chordal["start"], chordal["start_note"]) == ("file", "chordal", None)
    # Started at the optimum, a chordal start keeps the given poses (they start lower) and says why.
    again = dpr_gpu.pose_graph(edges, poses=result["world_from_node"], init="chordal")
    assert again["start"] == "file" and "start lower" in again["start_note"]


def test_a_g2o_file_gives_the_edges_result_and_what_the_command_line_writes(tmp_path):
    truth, edges = _ring(25, seed=3)
    rng = np.random.default_rng(4)
    noisy = []
    for i, j, t, w in edges:
        nudge = known_pose(rng)
        nudge[:3, :3] = np.eye(3)
        nudge[:3, 3] *= 0.01
        noisy.append((i, j, t @ nudge, w))
    start = _perturbed(truth, seed=5)
    graph = tmp_path / "ring.g2o"
    _write_g2o(graph, start, noisy)
    out = tmp_path / "python.g2o"
    from_file = dpr_gpu.pose_graph(graph, out=out)
    from_edges = dpr_gpu.pose_graph(noisy, poses=np.stack(start), init="chordal")
    np.testing.assert_allclose(from_file["world_from_node"], from_edges["world_from_node"], atol=1e-9)
    assert from_file["final_error"] == pytest.approx(from_edges["final_error"], rel=1e-9)
    assert 0 < from_file["final_error"] < from_file["given_error"]
    # Noisy edges: the optimum lies near, not at, the truth.
    _assert_at(from_file["world_from_node"], truth, 3.0, 0.1)
    # The file written holds the result's poses at full precision.
    written = [line.split() for line in out.read_text().splitlines() if line.startswith("VERTEX_SE3:QUAT")]
    positions = np.array([[float(v) for v in fields[2:5]] for fields in written])
    np.testing.assert_array_equal(positions, from_file["world_from_node"][:, :3, 3])
    binary = cli_binary()
    if binary is None:
        pytest.skip("no dpr-gpu binary: build it (cargo build) or set DPR_GPU_CLI")
    cli_out = tmp_path / "cli.g2o"
    subprocess.run([str(binary), "pose-graph", str(graph), "--out", str(cli_out)], check=True, capture_output=True)
    assert cli_out.read_bytes() == out.read_bytes()


def test_the_robust_kernel_prunes_wrong_loop_closures():
    truth, edges = _ring(40, seed=6)
    rng = np.random.default_rng(7)
    wrong = [(i, i + 17, known_pose(rng), INFORMATION) for i in (2, 9, 15)]
    plain = dpr_gpu.pose_graph(edges + wrong, poses=np.stack(truth), init="file")
    robust = dpr_gpu.pose_graph(edges + wrong, poses=np.stack(truth), robust="geman-mcclure")
    # Least squares bends the trajectory towards the wrong loops; the kernel switches them off.
    assert max(np.linalg.norm(p[:3, 3] - t[:3, 3]) for p, t in zip(plain["world_from_node"], truth)) > 0.05
    _assert_at(robust["world_from_node"], truth, 1e-4, 1e-5)
    np.testing.assert_array_equal(robust["weights"][len(edges) :], np.zeros(len(wrong)))
    assert np.all(robust["weights"][: len(edges)] > 0.99)


def test_bad_graphs_and_options_raise_clear_errors(tmp_path):
    truth, edges = _ring(8, seed=8)
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_XYZ 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad.g2o: line 2: unsupported element 'VERTEX_XYZ'"):
        dpr_gpu.pose_graph(bad)
    with pytest.raises(FileNotFoundError, match="missing.g2o"):
        dpr_gpu.pose_graph(tmp_path / "missing.g2o")
    good = tmp_path / "good.g2o"
    _write_g2o(good, truth, edges)
    before = good.read_bytes()
    with pytest.raises(ValueError, match="refusing to overwrite input"):
        dpr_gpu.pose_graph(good, out=good)
    assert good.read_bytes() == before
    with pytest.raises(ValueError, match="unknown initialisation 'x'"):
        dpr_gpu.pose_graph(edges, init="x")
    with pytest.raises(ValueError, match="unknown robust kernel"):
        dpr_gpu.pose_graph(edges, robust="huber")
    with pytest.raises(ValueError, match="needs the starting poses"):
        dpr_gpu.pose_graph(edges, init="file")
    with pytest.raises(ValueError, match=r"edges\[0\] i_from_j: expected a 4x4 array"):
        dpr_gpu.pose_graph([(0, 1, np.eye(3), INFORMATION)])
    with pytest.raises(ValueError, match=r"edges\[0\]: i = -1"):
        dpr_gpu.pose_graph([(-1, 1, np.eye(4), INFORMATION)])
    with pytest.raises(ValueError, match="poses, but the edges name node 7"):
        dpr_gpu.pose_graph(edges, poses=np.stack(truth[:5]), init="file")
