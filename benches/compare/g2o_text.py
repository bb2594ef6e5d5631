"""Writes pose graphs as g2o text (VERTEX_SE3:QUAT / EDGE_SE3:QUAT at 17 significant digits), for the generators
in this folder. A pose is given as its 7 numbers x y z qx qy qz qw."""

#: The information matrix of every generated edge: diag(100, 100, 100, 400, 400, 400), upper triangle row by row.
INFORMATION = "100 0 0 0 0 0 100 0 0 0 0 100 0 0 0 400 0 0 400 0 400"


def pose_text(xyz_quaternion):
    """The 7 numbers of a pose at full precision."""
    return " ".join(f"{float(v):.17g}" for v in xyz_quaternion)


def write_g2o(path, vertices, edges):
    """`vertices`: one pose per id 0, 1, ...; `edges`: (i, j, pose of x_i^-1 x_j), all with INFORMATION."""
    with open(path, "w") as f:
        for k, p in enumerate(vertices):
            f.write(f"VERTEX_SE3:QUAT {k} {pose_text(p)}\n")
        for i, j, z in edges:
            f.write(f"EDGE_SE3:QUAT {i} {j} {pose_text(z)} {INFORMATION}\n")
