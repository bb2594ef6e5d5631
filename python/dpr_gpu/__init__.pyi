"""Type stubs of ``dpr_gpu``."""

from __future__ import annotations

from typing import Any, Literal, Optional, Sequence

from typing_extensions import Unpack

import numpy.typing as npt

from ._dpr_gpu import DescribedScan as DescribedScan
from ._dpr_gpu import Features as Features
from ._dpr_gpu import MultiwayResult as MultiwayResult
from ._dpr_gpu import PairResult as PairResult
from ._dpr_gpu import PoseEstimate as PoseEstimate
from ._dpr_gpu import Registrar as Registrar
from ._dpr_gpu import RegistrationResult as RegistrationResult
from ._dpr_gpu import __version__ as __version__
from ._dpr_gpu import _Settings
from ._dpr_gpu import choose_radius as choose_radius
from ._dpr_gpu import multiway_origin as multiway_origin
from ._dpr_gpu import optimize_pairs as optimize_pairs
from ._dpr_gpu import pose_graph as pose_graph
from ._dpr_gpu import read_cloud as read_cloud
from ._dpr_gpu import scan_size as scan_size
from ._dpr_gpu import select_pairs as select_pairs

__all__ = [
    "DescribedScan",
    "Features",
    "MultiwayResult",
    "PairResult",
    "PoseEstimate",
    "Registrar",
    "RegistrationResult",
    "__version__",
    "multiway",
    "choose_radius",
    "multiway_origin",
    "optimize_pairs",
    "pose_graph",
    "read_cloud",
    "register",
    "scan_size",
    "select_pairs",
]

def register(
    source: npt.ArrayLike,
    target: npt.ArrayLike,
    *,
    source_normals: Optional[npt.ArrayLike] = None,
    target_normals: Optional[npt.ArrayLike] = None,
    **settings: Unpack[_Settings],
) -> RegistrationResult:
    """Registers ``source`` onto ``target``; ``target_from_source`` maps source points into the target frame."""

def multiway(
    scans: Sequence[npt.ArrayLike],
    *,
    normals: Optional[Sequence[npt.ArrayLike]] = None,
    pairs: Literal["all", "consecutive+retrieval"] = "consecutive+retrieval",
    retrieval_k: int = 5,
    max_pairs: Optional[int] = None,
    information_distance: Optional[float] = None,
    loop_preference: float = 1.0,
    **settings: Unpack[_Settings],
) -> dict[str, Any]:
    """Registers many scans into one trajectory (robust pose graph): ``world_from_scan``, ``edges``..."""
