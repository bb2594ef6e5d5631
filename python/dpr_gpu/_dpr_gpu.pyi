"""Type stubs of the compiled module ``dpr_gpu._dpr_gpu`` (re-exported by ``dpr_gpu``)."""

from __future__ import annotations

import os
from typing import Any, Literal, Optional, Sequence, Tuple, TypedDict, Union, final

import numpy as np
import numpy.typing as npt

__all__ = [
    "__version__",
    "DescribedScan",
    "Features",
    "MultiwayResult",
    "PairResult",
    "PoseEstimate",
    "RegistrationResult",
    "Registrar",
    "multiway_origin",
    "scan_size",
    "choose_radius",
    "optimize_pairs",
    "pose_graph",
    "read_cloud",
    "select_pairs",
    "_described_scan_from_state",
    "_library_defaults",
    "_pair_result_from_state",
]
__version__: str

_Points = npt.ArrayLike
_PathLike = Union[str, "os.PathLike[str]"]

class _Settings(TypedDict, total=False):
    """The keyword arguments of ``Registrar`` (defaults there), which ``register`` and ``multiway`` pass on."""

    weights: Optional[_PathLike]
    radius: Optional[float]
    voxel: Optional[float]
    keypoints: int
    first_keypoints: Optional[int]
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
    drop_zero_points: Optional[bool]
    seed: int
    backend: Literal["auto", "cpu", "gpu"]
    min_inliers: int
    min_inlier_ratio: float
    min_spread_over_threshold: float
    free_space_check: bool
    context_radii: Sequence[tuple[float, float]]
    context_when: Literal["untrusted", "always"]
    pose_candidates: int

@final
class DescribedScan:
    """One described scan (``Registrar.describe`` or ``Registrar.describe_scan``); picklable, bit for bit."""

    @property
    def index(self) -> int:
        """The scan's index in the collection (and its random stream)."""
    @property
    def stream(self) -> int:
        """The random stream the scan was described with (its index)."""
    @property
    def empty_patches(self) -> int:
        """Keypoints dropped because no other point lay within the patch radius."""
    @property
    def origin(self) -> Tuple[int, int, int]:
        """The whole-unit origin subtracted from the scan's coordinates."""
    @property
    def keypoints(self) -> npt.NDArray[np.float64]:
        """Keypoint positions (scan frame, origin added back), shape (K, 3)."""
    @property
    def keypoint_normals(self) -> npt.NDArray[np.float64]:
        """Unit normals at the keypoints, shape (K, 3)."""
    @property
    def points(self) -> int:
        """Points left after preprocessing."""
    @property
    def pooled_codeword(self) -> npt.NDArray[np.float32]:
        """Unit-length mean of the keypoints' unit codewords, shape (D,): what retrieval compares."""
    @property
    def timings(self) -> dict[str, float]:
        """Wall time per description stage in seconds."""
    def __len__(self) -> int: ...
    def __reduce__(self) -> Tuple[Any, Tuple[bytes]]: ...

# The name ``Registrar.describe``'s scans had before they became ``DescribedScan``s.
Features = DescribedScan

@final
class PairResult:
    """The registration of scan ``j`` (source) onto scan ``i`` (target), i < j; picklable, bit for bit."""

    @property
    def i(self) -> int: ...
    @property
    def j(self) -> int: ...
    @property
    def i_from_j(self) -> npt.NDArray[np.float64]:
        """4x4 estimate x_i = T x_j (the collection's shifted frame)."""
    @property
    def correspondences(self) -> int: ...
    @property
    def inliers(self) -> int: ...
    @property
    def fitness(self) -> float: ...
    @property
    def inlier_rmse(self) -> float: ...
    @property
    def trusted(self) -> bool: ...
    @property
    def reason(self) -> Optional[str]: ...
    @property
    def information(self) -> npt.NDArray[np.float64]:
        """6x6 edge information matrix (translation first)."""
    @property
    def seconds(self) -> float:
        """Seconds spent registering the pair."""
    def __reduce__(self) -> Tuple[Any, Tuple[bytes]]: ...

@final
class MultiwayResult:
    """A multiway registration's outcome (``optimize_pairs``)."""

    @property
    def world_from_scan(self) -> npt.NDArray[np.float64]:
        """world_from_scan per scan, shape (N, 4, 4) (world = the first scan's frame)."""
    @property
    def edges(self) -> list[dict[str, Any]]:
        """One dict per registered pair, with its fate in the pose graph."""
    @property
    def connected(self) -> list[bool]: ...
    @property
    def line_process_weight(self) -> float: ...
    def to_dict(self) -> dict[str, Any]:
        """The dict ``Registrar.multiway`` returns."""
    def write(self, out: _PathLike, scans: Optional[Sequence[_PathLike]] = None) -> None:
        """Writes out/trajectory.log, out/edges.json (and out/scans.txt) as ``dpr-gpu multiway`` does."""

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
    def scale(self) -> dict[str, Any]:
        """The patch radius, how it was chosen, and the voxel, inlier threshold and ICP distance."""
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
        """Input rows dropped (both scans): non-finite values, or points exactly at (0, 0, 0) as ``drop_zero_points``
        says (by default when a scan has two or more)."""
    @property
    def timings(self) -> dict[str, float]:
        """Wall time per pipeline stage in seconds, in pipeline order; stages repeated by the progressive
        keypoint rounds are summed."""
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
        first_keypoints: Optional[int] = 250,
        keypoint_mode: Literal["random", "uniform"] = "random",
        normal_neighbors: int = 30,
        viewpoint: Sequence[float] = (0.0, 0.0, 0.0),
        matching: Literal["mutual", "closest"] = "mutual",
        mutual_k: int = 1,
        estimator: Literal["relativenet", "ransac"] = "relativenet",
        inlier_threshold: Optional[float] = None,
        ransac_iterations: int = 100_000,
        ransac_confidence: float = 0.999,
        icp: bool = True,
        icp_max_correspondence_distance: Optional[float] = None,
        icp_max_iterations: int = 30,
        drop_zero_points: Optional[bool] = None,
        seed: int = 0,
        backend: Literal["auto", "cpu", "gpu"] = "auto",
        min_inliers: int = 12,
        min_inlier_ratio: float = 0.055,
        min_spread_over_threshold: float = 2.0,
        free_space_check: bool = True,
        context_radii: Sequence[tuple[float, float]] = [(2.0, 1.0)],
        context_when: Literal["untrusted", "always"] = "untrusted",
        pose_candidates: int = 16,
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
    def describe(self, points: _Points, normals: Optional[_Points] = None, *, stream: int = 0) -> DescribedScan:
        """Describes one scan: normals, keypoints and their learned descriptors."""
    def correspond(self, source: DescribedScan, target: DescribedScan) -> npt.NDArray[np.int64]:
        """Correspondences between two described scans as (K, 2) keypoint indices."""
    def estimate(
        self,
        source: DescribedScan,
        target: DescribedScan,
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
    def describe_scan(
        self,
        points: _Points,
        normals: Optional[_Points] = None,
        *,
        index: int,
        origin: Tuple[int, int, int] = (0, 0, 0),
    ) -> DescribedScan:
        """Describes scan ``index`` of a collection as ``multiway`` does (picklable result)."""
    def register_described(
        self,
        target: DescribedScan,
        source: DescribedScan,
        *,
        information_distance: Optional[float] = None,
    ) -> PairResult:
        """Registers described scan j (source) onto described scan i (target), i < j, as ``multiway`` does."""
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
    drop_zero_points: Optional[bool] = None,
    xyz_columns: Optional[str] = None,
) -> Tuple[npt.NDArray[np.float64], Optional[npt.NDArray[np.float64]]]:
    """Reads a .ply, .pcd or .xyz/.txt/.pts file: (points, normals or None) as (N, 3) float64 arrays."""

def multiway_origin(points: _Points) -> Tuple[int, int, int]:
    """The whole-unit origin ``multiway`` subtracts from every scan of a collection whose first scan is ``points``."""

def scan_size(points: _Points, *, origin: Tuple[int, int, int] = ..., drop_zero_points: Optional[bool] = None) -> float:
    """Median distance of the scan's points from its centre (coordinate-wise median), as ``multiway`` measures it."""

def choose_radius(sizes: Sequence[float]) -> float:
    """The patch radius chosen for scans of these sizes: 0.6 times their median."""

def select_pairs(
    n: int,
    pooled: Optional[Sequence[npt.NDArray[np.float32]]] = None,
    *,
    pairs: Literal["all", "consecutive+retrieval"] = "consecutive+retrieval",
    retrieval_k: int = 5,
    max_pairs: Optional[int] = None,
) -> list[Tuple[int, int]]:
    """The candidate pairs (i, j) of ``n`` scans in registration order, as ``multiway`` chooses them."""

def optimize_pairs(
    n: int,
    pair_results: Sequence[PairResult],
    *,
    information_distance: float,
    loop_preference: float = 1.0,
    origin: Tuple[int, int, int] = (0, 0, 0),
) -> MultiwayResult:
    """The robust pose graph of ``multiway`` over registered pairs."""

class _PoseGraphResult(TypedDict):
    world_from_node: npt.NDArray[np.float64]
    ids: list[int]
    weights: npt.NDArray[np.float64]
    given_error: float
    initial_error: float
    final_error: float
    iterations: int
    start: Literal["chordal", "file"]
    start_note: Optional[str]

def pose_graph(
    graph: Union[_PathLike, Sequence[Tuple[int, int, Any, Any]]],
    *,
    poses: Optional[Any] = None,
    robust: Literal["none", "geman-mcclure"] = "none",
    robust_scale: float = 1.0,
    prune_below: float = 0.25,
    init: Optional[Literal["chordal", "file"]] = None,
    out: Optional[_PathLike] = None,
) -> _PoseGraphResult:
    """Optimises a pose graph (a g2o file or ``(i, j, i_from_j, information)`` edges), node 0 fixed."""

def _described_scan_from_state(state: bytes) -> DescribedScan: ...
def _pair_result_from_state(state: bytes) -> PairResult: ...
def _library_defaults() -> dict[str, object]: ...
