"""dpr-gpu: learned pairwise registration of 3D scans (RelativeNet / PPF-FoldNet), numpy in and out.

Transforms are named by their frames: ``target_from_source`` maps source points into the target frame,
``p_target = T @ p_source``. Distances are in the clouds' units (metres by default).

Quick start::

    import numpy as np
    import dpr_gpu

    source, _ = dpr_gpu.read_cloud("source.ply")
    target, _ = dpr_gpu.read_cloud("target.ply")
    result = dpr_gpu.register(source, target, backend="cpu", seed=0)
    print(result.target_from_source, result.success, result.reason)

``register`` builds a ``Registrar`` (weights, model and backend) for one pair; keep a ``Registrar`` to register
many pairs, or to run the steps (``describe``, ``correspond``, ``estimate``) one at a time.

``multiway`` registers a collection of scans into one trajectory in this process; its stages are also separate
calls (``multiway_origin``, ``Registrar.describe_scan``, ``select_pairs``, ``Registrar.register_described``,
``optimize_pairs``) with picklable values, which ``dpr_gpu.distributed`` schedules on a Ray cluster.
"""

from __future__ import annotations

import os as _os
from typing import Any, Optional, Sequence

# Without a desktop session (no XDG_RUNTIME_DIR: servers, containers, ssh), Mesa's Vulkan device-select layer
# prints "error: XDG_RUNTIME_DIR is invalid or not set" while the backend looks for an adapter; it only reorders
# adapters, so it is switched off there (NODEVICE_SELECT=1, its manifest's switch) as the command line does.
if not _os.path.isdir(_os.environ.get("XDG_RUNTIME_DIR") or "/nonexistent") and "NODEVICE_SELECT" not in _os.environ:
    _os.environ["NODEVICE_SELECT"] = "1"

from ._dpr_gpu import (
    DescribedScan,
    Features,
    MultiwayResult,
    PairResult,
    PoseEstimate,
    Registrar,
    RegistrationResult,
    __version__,
    choose_radius,
    multiway_origin,
    optimize_pairs,
    pose_graph,
    read_cloud,
    scan_size,
    select_pairs,
)

__all__ = [
    "DescribedScan",
    "Features",
    "MultiwayResult",
    "PairResult",
    "PoseEstimate",
    "Registrar",
    "RegistrationResult",
    "__version__",
    "choose_radius",
    "multiway",
    "multiway_origin",
    "optimize_pairs",
    "pose_graph",
    "read_cloud",
    "register",
    "scan_size",
    "select_pairs",
]


def register(
    source: Any,
    target: Any,
    *,
    source_normals: Optional[Any] = None,
    target_normals: Optional[Any] = None,
    **settings: Any,
) -> RegistrationResult:
    """Registers ``source`` onto ``target`` and returns a ``RegistrationResult``.

    ``source`` and ``target`` are (N, 3) float32 or float64 arrays (C- or F-ordered, strided views too); the
    optional normals have the same shape. Rows with a NaN or infinite value are dropped, as the command line
    drops them from files. ``settings`` are the keyword arguments of ``Registrar`` (``radius``, ``keypoints``,
    ``estimator``, ``backend``, ``seed``, ``icp``, ``weights``...), with the library's defaults; the computation
    runs without the GIL.

    Raises ``ValueError`` for bad arrays or settings, ``OSError`` when a weights file cannot be read and
    ``RuntimeError`` when the GPU backend fails.
    """
    registrar = Registrar(**settings)
    return registrar.register(source, target, source_normals=source_normals, target_normals=target_normals)


def multiway(
    scans: Sequence[Any],
    *,
    normals: Optional[Sequence[Any]] = None,
    pairs: str = "consecutive+retrieval",
    retrieval_k: int = 5,
    max_pairs: Optional[int] = None,
    information_distance: Optional[float] = None,
    loop_preference: float = 1.0,
    **settings: Any,
) -> dict[str, Any]:
    """Registers a collection of scans into one trajectory and returns a dict with ``world_from_scan``
    ((N, 4, 4) float64, world = the first scan's frame), ``edges`` (one dict per registered pair, with whether it
    survived the robust pose graph), ``connected`` and ``line_process_weight``.

    Every scan is described once; ``pairs`` chooses the candidate pairs (``"all"``, or ``"consecutive+retrieval"``:
    consecutive scans plus each scan's ``retrieval_k`` most similar scans by pooled codewords), ``max_pairs`` caps
    them. Wrong loop closures are switched off by line processes (Choi et al. 2015); see
    ``Registrar.multiway``. ``settings`` are the keyword arguments of ``Registrar``.

    Raises ``ValueError`` for fewer than 2 scans or bad arrays or settings, ``OSError`` when a weights file
    cannot be read and ``RuntimeError`` when the GPU backend fails.
    """
    registrar = Registrar(**settings)
    return registrar.multiway(
        scans,
        normals,
        pairs=pairs,
        retrieval_k=retrieval_k,
        max_pairs=max_pairs,
        information_distance=information_distance,
        loop_preference=loop_preference,
    )
