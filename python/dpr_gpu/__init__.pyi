"""Type stubs of ``dpr_gpu``."""

from __future__ import annotations

from typing import Any, Literal, Optional, Sequence

import numpy.typing as npt

from ._dpr_gpu import Features as Features
from ._dpr_gpu import PoseEstimate as PoseEstimate
from ._dpr_gpu import Registrar as Registrar
from ._dpr_gpu import RegistrationResult as RegistrationResult
from ._dpr_gpu import __version__ as __version__
from ._dpr_gpu import _PathLike
from ._dpr_gpu import read_cloud as read_cloud

__all__ = [
    "Features",
    "PoseEstimate",
    "Registrar",
    "RegistrationResult",
    "__version__",
    "multiway",
    "read_cloud",
    "register",
]

def register(
    source: npt.ArrayLike,
    target: npt.ArrayLike,
    *,
    source_normals: Optional[npt.ArrayLike] = None,
    target_normals: Optional[npt.ArrayLike] = None,
    weights: Optional[_PathLike] = None,
    radius: Optional[float] = None,
    voxel: Optional[float] = None,
    keypoints: int = 2500,
    keypoint_mode: Literal["random", "uniform"] = "random",
    normal_neighbors: int = 30,
    viewpoint: Sequence[float] = (0.0, 0.0, 0.0),
    matching: Literal["mutual", "closest"] = "mutual",
    mutual_k: int = 1,
    estimator: Literal["relativenet", "ransac"] = "relativenet",
    inlier_threshold: Optional[float] = None,
    ransac_iterations: int = 100_000,
    ransac_confidence: float = 0.999,
    icp: bool = False,
    icp_max_correspondence_distance: Optional[float] = None,
    icp_max_iterations: int = 30,
    drop_zero_points: bool = False,
    seed: int = 0,
    backend: Literal["auto", "cpu", "gpu"] = "auto",
    min_inliers: int = 12,
    min_inlier_ratio: float = 0.055,
    min_spread_over_threshold: float = 2.0,
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
    weights: Optional[_PathLike] = None,
    radius: Optional[float] = None,
    voxel: Optional[float] = None,
    keypoints: int = 2500,
    keypoint_mode: Literal["random", "uniform"] = "random",
    normal_neighbors: int = 30,
    viewpoint: Sequence[float] = (0.0, 0.0, 0.0),
    matching: Literal["mutual", "closest"] = "mutual",
    mutual_k: int = 1,
    estimator: Literal["relativenet", "ransac"] = "relativenet",
    inlier_threshold: Optional[float] = None,
    ransac_iterations: int = 100_000,
    ransac_confidence: float = 0.999,
    icp: bool = False,
    icp_max_correspondence_distance: Optional[float] = None,
    icp_max_iterations: int = 30,
    drop_zero_points: bool = False,
    seed: int = 0,
    backend: Literal["auto", "cpu", "gpu"] = "auto",
    min_inliers: int = 12,
    min_inlier_ratio: float = 0.055,
    min_spread_over_threshold: float = 2.0,
) -> dict[str, Any]:
    """Registers many scans into one trajectory (robust pose graph): ``world_from_scan``, ``edges``..."""
