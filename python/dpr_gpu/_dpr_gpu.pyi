"""Type stubs of the compiled module ``dpr_gpu._dpr_gpu`` (re-exported by ``dpr_gpu``)."""

from __future__ import annotations

import os
from typing import Any, Literal, Optional, Sequence, Tuple, TypedDict, Union, final

import numpy as np
import numpy.typing as npt

__all__ = ["__version__", "Features", "PoseEstimate", "RegistrationResult", "Registrar", "read_cloud", "_library_defaults"]
__version__: str

_Points = npt.ArrayLike
_PathLike = Union[str, "os.PathLike[str]"]

class _Settings(TypedDict, total=False):
    """The keyword arguments of ``Registrar`` (defaults there), which ``register`` and ``multiway`` pass on."""

    weights: Optional[_PathLike]
    radius: Optional[float]
    voxel: Optional[float]
    keypoints: int
    keypoint_mode: Literal["random", "uniform"]
    normal_neighbors: int
    viewpoint: Sequence[float]
    matching: Literal["mutual", "closest"]
    mutual_k: int
    estimator: Literal["relativenet", "ransac"]
    inlier_threshold: Optional[float]
    ransac_iterations: int
    ransac_confidence: float
    icp: bool
    icp_max_correspondence_distance: Optional[float]
    icp_max_iterations: int
    drop_zero_points: bool
    seed: int
    backend: Literal["auto", "cpu", "gpu"]
    min_inliers: int
    min_inlier_ratio: float
    min_spread_over_threshold: float

@final
class Features:
    """One described scan: keypoints, their normals and their learned descriptors (kept opaque)."""

    @property
    def keypoints(self) -> npt.NDArray[np.float64]:
        """Keypoint positions (scan frame), shape (K, 3)."""
    @property
    def keypoint_normals(self) -> npt.NDArray[np.float64]:
        """Unit normals at the keypoints (scan frame), shape (K, 3)."""
    @property
    def empty_patches(self) -> int:
        """Keypoints dropped because no other point lay within the patch radius."""
    @property
    def stream(self) -> int:
        """The random stream the scan was described with."""
    @property
    def timings(self) -> dict[str, float]:
        """Wall time per description stage in seconds."""
    def __len__(self) -> int: ...

@final
class PoseEstimate:
    """A pose estimated from correspondences (``Registrar.estimate``)."""

    @property
    def target_from_source(self) -> npt.NDArray[np.float64]:
        """4x4 rigid transform mapping source points into the target frame."""
    @property
    def fitness(self) -> float: ...
    @property
    def inlier_rmse(self) -> float: ...
    @property
    def inliers(self) -> int: ...
    @property
    def hypotheses_scored(self) -> int: ...

@final
class RegistrationResult:
    """The outcome of registering a source scan onto a target scan."""

    @property
    def target_from_source(self) -> npt.NDArray[np.float64]:
        """4x4 rigid transform (float64) mapping source points into the target frame."""
    @property
    def fitness(self) -> float:
        """Inliers / correspondences under the final pose."""
    @property
    def inlier_rmse(self) -> float:
        """RMS residual of the inlier correspondences (cloud units)."""
    @property
    def inliers(self) -> int:
        """Correspondences within the inlier threshold under the final pose."""
    @property
    def hypotheses_scored(self) -> int:
        """Pose hypotheses scored by the estimator."""
    @property
    def correspondences(self) -> npt.NDArray[np.int64]:
        """(K, 2) keypoint indices: column 0 into ``source_keypoints``, column 1 into ``target_keypoints``."""
    @property
    def feature_distances(self) -> npt.NDArray[np.float32]:
        """(K,) codeword distance of each correspondence."""
    @property
    def source_keypoints(self) -> npt.NDArray[np.float64]:
        """Source keypoints (source frame), shape (Ns, 3)."""
    @property
    def target_keypoints(self) -> npt.NDArray[np.float64]:
        """Target keypoints (target frame), shape (Nt, 3)."""
    @property
    def empty_patches(self) -> int:
        """Keypoints dropped (both scans) because their patch was empty."""
    @property
    def dropped_points(self) -> int:
        """Input rows dropped (both scans): non-finite values, or zeros with ``drop_zero_points``."""
    @property
    def timings(self) -> dict[str, float]:
        """Wall time per pipeline stage in seconds, in pipeline order."""
    @property
    def backend(self) -> str:
        """The backend (and adapter) that ran the learned stages."""
    @property
    def success(self) -> bool:
        """Whether the pose can be trusted (judged from its own support)."""
    @property
    def reason(self) -> Optional[str]:
        """Why the pose cannot be trusted; None on success."""
    def snapshot(self, path: _PathLike, *, inliers: bool = True) -> None:
        """Write a PNG of both scans before (top row) and after (bottom row) registration."""

@final
class Registrar:
    """The registration pipeline with weights, model and backend loaded once."""

    def __new__(
        cls,
        *,
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
    ) -> Registrar: ...
    @property
    def settings(self) -> dict[str, object]:
        """The settings in effect, keyed by the keyword argument names."""
    @property
    def backend(self) -> str:
        """The backend (and adapter) that runs the learned stages."""
    @property
    def radius(self) -> float:
        """The patch radius in use (cloud units)."""
    @property
    def inlier_threshold(self) -> float:
        """The inlier threshold in use (cloud units)."""
    def describe(self, points: _Points, normals: Optional[_Points] = None, *, stream: int = 0) -> Features:
        """Describes one scan: normals, keypoints and their learned descriptors."""
    def correspond(self, source: Features, target: Features) -> npt.NDArray[np.int64]:
        """Correspondences between two described scans as (K, 2) keypoint indices."""
    def estimate(
        self,
        source: Features,
        target: Features,
        correspondences: npt.ArrayLike,
        *,
        estimator: Optional[Literal["relativenet", "ransac"]] = None,
    ) -> PoseEstimate:
        """Estimates target_from_source from (K, 2) correspondences (then ICP when enabled)."""
    def register(
        self,
        source: _Points,
        target: _Points,
        *,
        source_normals: Optional[_Points] = None,
        target_normals: Optional[_Points] = None,
    ) -> RegistrationResult:
        """Registers ``source`` onto ``target`` (the whole pipeline)."""
    def multiway(
        self,
        scans: Sequence[_Points],
        normals: Optional[Sequence[_Points]] = None,
        *,
        pairs: Literal["all", "consecutive+retrieval"] = "consecutive+retrieval",
        retrieval_k: int = 5,
        max_pairs: Optional[int] = None,
        information_distance: Optional[float] = None,
        loop_preference: float = 1.0,
    ) -> dict[str, Any]:
        """Registers many scans into one trajectory (robust pose graph): ``world_from_scan``, ``edges``..."""

def read_cloud(
    path: _PathLike,
    *,
    drop_zero_points: bool = False,
    xyz_columns: Optional[str] = None,
) -> Tuple[npt.NDArray[np.float64], Optional[npt.NDArray[np.float64]]]:
    """Reads a .ply, .pcd or .xyz/.txt/.pts file: (points, normals or None) as (N, 3) float64 arrays."""

def _library_defaults() -> dict[str, object]: ...
