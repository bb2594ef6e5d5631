"""Multiway registration on a Ray cluster (or a laptop): the work of ``dpr_gpu.multiway``, spread over workers.

The stages are those of ``dpr_gpu.multiway`` and ``dpr-gpu multiway``, run by the same compiled code:

1. every scan is described once (``Registrar.describe_scan``), one Ray task per scan, on worker actors that each
   hold one ``Registrar`` (built from the same settings; one actor per GPU, or per CPU worker);
2. the candidate pairs are chosen on the driver (``select_pairs``, from the scans' pooled codewords);
3. the pairs are registered in batches (``Registrar.register_described``), one task per batch; a described scan
   travels as a Ray ``ObjectRef`` and is fetched once per actor, which keeps it for later batches;
4. the pair results are gathered on the driver and fed to the robust pose graph (``optimize_pairs``).

Every random choice depends on the seed and the scan or pair index only, never on which worker ran it, so the
result equals ``dpr_gpu.multiway`` with the same scans and settings (on the same kind of backend).

On a cluster, connect first, then run; on a laptop, ``run`` starts a local Ray itself::

    import ray
    from dpr_gpu import distributed

    ray.init(address="auto")          # or "ray://head:10001"; ray.init() (or nothing) runs locally
    outcome = distributed.run(scans, pairs="all", keypoints=1000, seed=0)
    outcome.result.write("run")       # run/trajectory.log and run/edges.json, as `dpr-gpu multiway` writes them

The command line, ``python -m dpr_gpu.distributed INPUT --out DIR --address auto``, reads a folder or list of
scans as ``dpr-gpu multiway`` does and writes the same files. Ray is an optional dependency:
``pip install './python[distributed]'`` (or ``pip install ray``).
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Literal, Optional, Sequence, Tuple, Union, cast

import numpy as np

from ._dpr_gpu import (
    DescribedScan,
    MultiwayResult,
    PairResult,
    Registrar,
    _library_defaults,
    choose_radius,
    multiway_origin,
    optimize_pairs,
    read_cloud,
    scan_size,
    select_pairs,
)

__all__ = ["RAY_MISSING", "DistributedRun", "multiway", "run", "scan_paths", "main"]

RAY_MISSING = (
    "dpr_gpu.distributed needs Ray, which is not installed: pip install 'dpr-gpu[distributed]' "
    "(from a checkout: pip install './python[distributed]'), or pip install 'ray>=2.40'"
)

_PAIRS = ("all", "consecutive+retrieval")
_CLOUD_EXTENSIONS = ("ply", "pcd", "xyz", "pts")

Scan = Union[Any, str, "os.PathLike[str]"]


def _import_ray() -> Any:
    """The ``ray`` module, or an ImportError that says how to install it."""
    try:
        import ray
    except ImportError as e:
        raise ImportError(RAY_MISSING) from e
    return ray


class _Worker:
    """The body of a worker actor: one ``Registrar`` and the described scans it has seen, by index (least
    recently used dropped beyond ``cache_scans``)."""

    def __init__(self, settings: Dict[str, Any], cache_scans: int) -> None:
        import ray

        # Ray reserves GPUs by setting CUDA_VISIBLE_DEVICES, which Vulkan and the other wgpu APIs ignore: name
        # this actor's GPU to the library by position instead (unless the user chose an adapter already), so
        # actors on one machine with several identical GPUs each take their own.
        gpu_ids = ray.get_gpu_ids()
        chosen = any(os.environ.get(v) for v in ("DPR_GPU_ADAPTER_INDEX", "WGPU_ADAPTER_NAME"))
        if gpu_ids and not chosen and str(gpu_ids[0]).isdigit():
            os.environ["DPR_GPU_ADAPTER_INDEX"] = str(gpu_ids[0])
        self._settings = dict(settings)
        self._registrar = Registrar(**settings)
        self._cache: "collections.OrderedDict[int, DescribedScan]" = collections.OrderedDict()
        self._cache_scans = max(1, cache_scans)
        self._fetched = 0
        context = ray.get_runtime_context()
        self._id = context.get_actor_id() or f"pid-{os.getpid()}"
        self._node = context.get_node_id()

    def info(self) -> Dict[str, Any]:
        """Who this worker is and what its registrar resolved."""
        import ray

        return {
            "worker": self._id,
            "node": self._node,
            "pid": os.getpid(),
            "backend": self._registrar.backend,
            "inlier_threshold": self._registrar.inlier_threshold,
            "fetched_scans": self._fetched,
            "gpu_ids": [str(g) for g in ray.get_gpu_ids()],
        }

    def size(self, scan: Any, origin: Tuple[int, int, int], drop_zero_points: Optional[bool]) -> float:
        """The size of one scan (an array, or a file read here) as ``Registrar.multiway`` measures it to choose
        the patch radius (``scan_size``)."""
        if isinstance(scan, (str, os.PathLike)):
            scan, _ = read_cloud(scan, drop_zero_points=drop_zero_points)
        return scan_size(scan, origin=origin, drop_zero_points=drop_zero_points)

    def set_radius(self, radius: float) -> None:
        """Rebuilds this worker's registrar at the patch radius chosen from every scan (before any describe)."""
        self._settings["radius"] = radius
        self._registrar = Registrar(**self._settings)

    def _keep(self, scan: DescribedScan) -> None:
        self._cache[scan.index] = scan
        self._cache.move_to_end(scan.index)

    def _trim(self) -> None:
        while len(self._cache) > self._cache_scans:
            self._cache.popitem(last=False)

    def describe(
        self, scan: Any, normals: Any, index: int, origin: Tuple[int, int, int], drop_zero_points: Optional[bool]
    ) -> Tuple[DescribedScan, Tuple[Any, str, float]]:
        """Describes scan ``index`` (an array, or a file read here); returns the described scan (kept in the
        object store for the pair tasks) and (pooled codeword, worker id, seconds) for the driver."""
        started = time.perf_counter()
        if isinstance(scan, (str, os.PathLike)):
            scan, normals = read_cloud(scan, drop_zero_points=drop_zero_points)
        described = self._registrar.describe_scan(scan, normals, index=index, origin=origin)
        self._keep(described)
        self._trim()
        return described, (described.pooled_codeword, self._id, time.perf_counter() - started)

    def register(
        self, pairs: List[Tuple[int, int]], scans: Dict[int, Any], information_distance: Optional[float]
    ) -> Tuple[List[PairResult], str, float]:
        """Registers a batch of pairs; ``scans`` maps scan index to the ObjectRef of its DescribedScan (fetched
        only when this worker does not hold the scan yet)."""
        import ray

        started = time.perf_counter()
        missing = sorted({k for pair in pairs for k in pair} - set(self._cache))
        if missing:
            for scan in ray.get([scans[k] for k in missing]):
                self._keep(scan)
            self._fetched += len(missing)
        results = []
        for i, j in pairs:
            self._cache.move_to_end(i)
            self._cache.move_to_end(j)
            results.append(
                self._registrar.register_described(
                    self._cache[i], self._cache[j], information_distance=information_distance
                )
            )
        self._trim()
        return results, self._id, time.perf_counter() - started


_REMOTE_WORKER: List[Any] = []


def _remote_worker() -> Any:
    """``_Worker`` as a Ray actor class (made on first use, so importing this module does not need Ray)."""
    if not _REMOTE_WORKER:
        _REMOTE_WORKER.append(_import_ray().remote(_Worker))
    return _REMOTE_WORKER[0]


@dataclass
class DistributedRun:
    """What ``run`` did: the multiway result and where the work ran."""

    #: The trajectory and edges (``MultiwayResult``; ``.to_dict()`` is what ``dpr_gpu.multiway`` returns).
    result: MultiwayResult
    #: One dict per worker actor: ``worker`` (Ray actor id), ``node``, ``pid``, ``backend``,
    #: ``inlier_threshold``, ``fetched_scans`` (described scans it pulled from the object store), ``gpu_ids``
    #: (the GPUs Ray reserved for it).
    workers: List[Dict[str, Any]]
    #: Per scan: the actor id that described it.
    described_by: List[str]
    #: Per scan: seconds its description took on its worker.
    describe_seconds: List[float]
    #: Per registered pair (i, j): the actor id that registered it.
    registered_by: Dict[Tuple[int, int], str]
    #: Per registered pair (i, j): seconds its registration took (``PairResult.seconds``).
    pair_seconds: Dict[Tuple[int, int], float]
    #: Wall seconds per stage on the driver: ``start``, ``describe``, ``pairs``, ``graph``.
    stage_seconds: Dict[str, float] = field(default_factory=dict)


def _dispatch(
    ray: Any, actors: Sequence[Any], jobs: Sequence[Any], submit: Callable[[Any, Any], Any], depth: int = 2
) -> List[Any]:
    """Runs ``jobs`` on ``actors`` with at most ``depth`` calls queued per actor, each new job going to the actor
    that finished first (load balancing); returns ``submit``'s handles in job order. ``submit(actor, job)``
    returns either an ObjectRef or a list of ObjectRefs whose last one signals completion."""
    handles: List[Any] = [None] * len(jobs)
    free = [a for _ in range(depth) for a in actors]
    pending: Dict[Any, Tuple[int, Any]] = {}
    next_job = 0
    while next_job < len(jobs) or pending:
        while free and next_job < len(jobs):
            actor = free.pop(0)
            handle = submit(actor, jobs[next_job])
            signal = handle[-1] if isinstance(handle, list) else handle
            pending[signal] = (next_job, actor)
            handles[next_job] = handle
            next_job += 1
        done, _ = ray.wait(list(pending), num_returns=1)
        for ref in done:
            _, actor = pending.pop(ref)
            free.append(actor)
    return handles


def _worker_count(ray: Any, workers: Optional[int], gpus_per_worker: float, cpus_per_worker: float) -> int:
    if workers is not None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        return workers
    resources = ray.cluster_resources()
    if gpus_per_worker > 0:
        return max(1, int(resources.get("GPU", 0) // gpus_per_worker))
    return max(1, int(resources.get("CPU", 1) // max(cpus_per_worker, 1e-9)))


def run(
    scans: Sequence[Scan],
    *,
    normals: Optional[Sequence[Any]] = None,
    pairs: Literal["all", "consecutive+retrieval"] = "consecutive+retrieval",
    retrieval_k: int = 5,
    max_pairs: Optional[int] = None,
    information_distance: Optional[float] = None,
    loop_preference: float = 1.0,
    workers: Optional[int] = None,
    gpus_per_worker: Optional[float] = None,
    cpus_per_worker: float = 1,
    batch_size: int = 8,
    cache_scans: int = 128,
    **settings: Any,
) -> DistributedRun:
    """Registers a collection of scans into one trajectory on Ray and returns a ``DistributedRun``.

    ``scans`` are (N, 3) arrays (shipped once each through Ray's object store) or paths of cloud files (read by
    the worker that describes them: on a cluster, a path every node can read). ``normals``, ``pairs``,
    ``retrieval_k``, ``max_pairs``, ``information_distance``, ``loop_preference`` and ``settings`` (the keyword
    arguments of ``Registrar``) are those of ``dpr_gpu.multiway``, with the same meaning and result.

    Uses the Ray connection of this process (``ray.init(address=...)`` for a cluster) or starts a local Ray with
    ``ray.init()`` (which also honours ``RAY_ADDRESS``). ``workers`` actors are started (default: one per GPU of
    the cluster when ``gpus_per_worker`` > 0, which is the default when the cluster has GPUs; else one per
    ``cpus_per_worker`` CPUs), each reserving ``gpus_per_worker`` GPUs and ``cpus_per_worker`` CPUs, and stopped
    at the end. Pairs go to workers in batches of ``batch_size``; each worker keeps up to ``cache_scans``
    described scans. Raises ``ImportError`` without Ray, ``ValueError`` for bad input (as ``dpr_gpu.multiway``).
    """
    n = len(scans)
    if n < 2:
        raise ValueError(f"multiway registration needs at least 2 scans, got {n}")
    if normals is not None and len(normals) != n:
        raise ValueError(f"{len(normals)} normal arrays for {n} scans")
    if pairs not in _PAIRS:
        raise ValueError(f"unknown pairs '{pairs}' (expected 'all' or 'consecutive+retrieval')")
    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    # The options are checked here, before any worker starts (the same checks run again where they are used).
    select_pairs(2, [np.zeros(1, np.float32)] * 2, pairs=pairs, retrieval_k=retrieval_k, max_pairs=max_pairs)
    if information_distance is not None and not information_distance > 0:
        raise ValueError(f"information_distance must be positive, got {information_distance}")
    if not loop_preference > 0:
        raise ValueError(f"loop closure preference must be positive, got {loop_preference}")
    settings_check = Registrar(**{**settings, "backend": "cpu"})  # bad settings fail here, not on a worker
    drop_zero_points = cast(Optional[bool], settings_check.settings["drop_zero_points"])
    del settings_check

    ray = _import_ray()
    clock = time.perf_counter()
    if not ray.is_initialized():
        ray.init()
    first = scans[0]
    if isinstance(first, (str, os.PathLike)):
        first = read_cloud(first, drop_zero_points=drop_zero_points)[0]
    origin = multiway_origin(first)

    if gpus_per_worker is None:
        gpus_per_worker = 1.0 if ray.cluster_resources().get("GPU", 0) >= 1 else 0.0
    count = _worker_count(ray, workers, gpus_per_worker, cpus_per_worker)
    options: Dict[str, Any] = {"num_cpus": cpus_per_worker, "num_gpus": gpus_per_worker}
    threads = max(1, int(cpus_per_worker))
    options["runtime_env"] = {"env_vars": {"RAYON_NUM_THREADS": str(threads)}}
    worker_class = _remote_worker()
    actors = [worker_class.options(**options).remote(dict(settings), cache_scans) for _ in range(count)]
    stages: Dict[str, float] = {}
    try:
        infos = ray.get([a.info.remote() for a in actors])
        stages["start"] = time.perf_counter() - clock

        clock = time.perf_counter()
        scan_refs = [s if isinstance(s, (str, os.PathLike)) else ray.put(s) for s in scans]
        normal_refs = [None if normals is None or normals[k] is None else ray.put(normals[k]) for k in range(n)]
        if settings.get("radius") is None:
            # One radius for every scan, chosen from all of them as Registrar.multiway chooses it.
            sizes = ray.get(
                _dispatch(
                    ray,
                    actors,
                    list(range(n)),
                    lambda actor, k: actor.size.remote(scan_refs[k], origin, drop_zero_points),
                )
            )
            radius = choose_radius(sizes)
            ray.get([a.set_radius.remote(radius) for a in actors])
            stages["scale"] = time.perf_counter() - clock
            clock = time.perf_counter()

        def describe(actor: Any, k: int) -> Any:
            method = actor.describe.options(num_returns=2)
            return method.remote(scan_refs[k], normal_refs[k], k, origin, drop_zero_points)

        described = _dispatch(ray, actors, list(range(n)), describe)
        described_refs = [d[0] for d in described]
        scan_info = ray.get([d[1] for d in described])
        del scan_refs, normal_refs
        stages["describe"] = time.perf_counter() - clock

        clock = time.perf_counter()
        pooled = [info[0] for info in scan_info] if pairs == "consecutive+retrieval" else None
        selected = select_pairs(n, pooled, pairs=pairs, retrieval_k=retrieval_k, max_pairs=max_pairs)
        batches = [selected[b : b + batch_size] for b in range(0, len(selected), batch_size)]

        def register(actor: Any, batch: List[Tuple[int, int]]) -> Any:
            needed = {k: described_refs[k] for pair in batch for k in pair}
            return actor.register.remote(batch, needed, information_distance)

        gathered = ray.get(_dispatch(ray, actors, batches, register))
        results: List[PairResult] = [r for batch_results, _, _ in gathered for r in batch_results]
        registered_by = {
            (r.i, r.j): worker for batch_results, worker, _ in gathered for r in batch_results
        }
        stages["pairs"] = time.perf_counter() - clock
        infos = ray.get([a.info.remote() for a in actors])
    finally:
        for a in actors:
            ray.kill(a)

    clock = time.perf_counter()
    distance = information_distance if information_distance is not None else float(infos[0]["inlier_threshold"])
    graph = optimize_pairs(n, results, information_distance=distance, loop_preference=loop_preference, origin=origin)
    stages["graph"] = time.perf_counter() - clock
    return DistributedRun(
        result=graph,
        workers=infos,
        described_by=[info[1] for info in scan_info],
        describe_seconds=[float(info[2]) for info in scan_info],
        registered_by=registered_by,
        pair_seconds={(r.i, r.j): r.seconds for r in results},
        stage_seconds=stages,
    )


def multiway(
    scans: Sequence[Scan],
    *,
    normals: Optional[Sequence[Any]] = None,
    pairs: Literal["all", "consecutive+retrieval"] = "consecutive+retrieval",
    retrieval_k: int = 5,
    max_pairs: Optional[int] = None,
    information_distance: Optional[float] = None,
    loop_preference: float = 1.0,
    **options: Any,
) -> Dict[str, Any]:
    """``dpr_gpu.multiway`` on Ray: the same arguments and the same dict (``world_from_scan``, ``edges``,
    ``connected``, ``line_process_weight``). ``options`` are the settings of ``Registrar`` plus the scheduling
    options of ``run`` (``workers``, ``gpus_per_worker``, ``cpus_per_worker``, ``batch_size``,
    ``cache_scans``)."""
    outcome = run(
        scans,
        normals=normals,
        pairs=pairs,
        retrieval_k=retrieval_k,
        max_pairs=max_pairs,
        information_distance=information_distance,
        loop_preference=loop_preference,
        **options,
    )
    return outcome.result.to_dict()


def _natural_cmp(a: str, b: str) -> int:
    """Orders names with digit runs compared as numbers (``cloud_bin_2`` < ``cloud_bin_10``), as the command
    line orders a folder's scans."""
    ra, rb = re.findall(r"[0-9]+|[^0-9]+", a), re.findall(r"[0-9]+|[^0-9]+", b)
    for sa, sb in zip(ra, rb):
        if sa[0].isascii() and sa[0].isdigit() and sb[0].isascii() and sb[0].isdigit():
            ta, tb = sa.lstrip("0"), sb.lstrip("0")
            if (len(ta), ta) != (len(tb), tb):
                return -1 if (len(ta), ta) < (len(tb), tb) else 1
        elif sa != sb:
            return -1 if sa < sb else 1
    if len(ra) != len(rb):
        return -1 if len(ra) < len(rb) else 1
    return (a > b) - (a < b)


def scan_paths(input: Union[str, "os.PathLike[str]"]) -> List[Path]:
    """The scans of ``dpr-gpu multiway INPUT``: a folder's .ply, .pcd, .xyz and .pts files in natural name
    order, or the lines of a list file (paths relative to its folder; blank lines and ``#`` comments skipped).
    Raises ``ValueError`` when fewer than 2 scans are found, ``OSError`` when INPUT cannot be read."""
    path = Path(input)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such folder or scan list")
    if path.is_dir():
        found = [
            p for p in path.iterdir() if p.is_file() and p.suffix[1:].lower() in _CLOUD_EXTENSIONS
        ]
        found.sort(key=functools.cmp_to_key(lambda x, y: _natural_cmp(str(x), str(y))))
    else:
        lines = path.read_text().splitlines()
        found = [path.parent / line.strip() for line in lines if line.strip() and not line.strip().startswith("#")]
    if len(found) < 2:
        raise ValueError(f"{path}: multiway registration needs at least 2 scans, found {len(found)}")
    return found


def _arguments() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m dpr_gpu.distributed",
        description="dpr-gpu multiway on a Ray cluster: describe every scan once and register the candidate "
        "pairs on worker actors, then optimise the robust pose graph; writes DIR/trajectory.log, "
        "DIR/edges.json and DIR/scans.txt as `dpr-gpu multiway` does.",
    )
    p.add_argument("input", help="a folder of scans (.ply/.pcd/.xyz/.pts, natural order) or a list file")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    ray_group = p.add_argument_group("Ray")
    ray_group.add_argument(
        "--address", default=None, help="Ray cluster: 'auto', 'ray://HOST:10001' or HOST:PORT (default: local Ray)"
    )
    ray_group.add_argument("--workers", type=int, default=None, help="worker actors (default: one per GPU or CPU)")
    ray_group.add_argument("--gpus-per-worker", type=float, default=None, help="GPUs per worker (default: 1 if any)")
    ray_group.add_argument("--cpus-per-worker", type=float, default=1, help="CPUs per worker (default 1)")
    ray_group.add_argument("--batch-size", type=int, default=8, help="pairs per task (default 8)")
    ray_group.add_argument(
        "--read-on-workers",
        action="store_true",
        help="workers read the scan files themselves (every node must see the same paths)",
    )
    mw = p.add_argument_group("multiway (as dpr-gpu multiway)")
    mw.add_argument("--pairs", default="consecutive+retrieval", choices=_PAIRS)
    mw.add_argument("--retrieval-k", type=int, default=5)
    mw.add_argument("--max-pairs", type=int, default=None)
    mw.add_argument("--information-distance", type=float, default=None)
    mw.add_argument("--loop-preference", type=float, default=1.0)
    reg = p.add_argument_group("registration (as dpr-gpu multiway)")
    reg.add_argument("--weights", default=None)
    reg.add_argument("--keypoints", type=int, default=2500)
    reg.add_argument("--keypoint-mode", default="random", choices=("random", "uniform"))
    reg.add_argument("--radius", type=float, default=None)
    reg.add_argument("--voxel", type=float, default=None)
    reg.add_argument("--normal-k", type=int, default=30)
    reg.add_argument("--estimator", default="relativenet", choices=("relativenet", "ransac"))
    reg.add_argument("--mutual", type=int, default=1)
    reg.add_argument("--inlier-threshold", type=float, default=None)
    reg.add_argument("--ransac-iterations", type=int, default=100_000)
    reg.add_argument("--seed", type=int, default=0)
    reg.add_argument("--no-icp", action="store_true", help="skip the ICP refinement (on by default)")
    reg.add_argument("--icp", action="store_true", help="ICP refinement (the default)")
    reg.add_argument("--icp-distance", type=float, default=None)
    reg.add_argument("--icp-iterations", type=int, default=None)
    zero = reg.add_mutually_exclusive_group()
    zero.add_argument("--drop-zero", action="store_true")
    zero.add_argument("--keep-zero", action="store_true")
    reg.add_argument("--backend", default="auto", choices=("auto", "cpu", "gpu"))
    reg.add_argument("--min-inliers", type=int, default=12)
    reg.add_argument("--min-inlier-ratio", type=float, default=0.055)
    reg.add_argument("--min-inlier-spread", type=float, default=2.0)
    reg.add_argument("--no-free-space-check", action="store_true", help="skip the verdict's free-space check")
    reg.add_argument(
        "--context-radius",
        action="append",
        default=None,
        metavar="FACTOR:WEIGHT",
        help="context radius, repeatable, or 'off' (default 2:1)",
    )
    reg.add_argument("--context-when", default="untrusted", choices=("untrusted", "always"))
    reg.add_argument(
        "--pose-candidates",
        type=int,
        default=None,
        help="how many of the estimator's best distinct poses compete (default: the library's)",
    )
    return p


def _context_radii(values: Optional[Sequence[str]]) -> Sequence[Tuple[float, float]]:
    """The `context_radii` of `--context-radius` values (None: the library's default, 2:1; 'off' alone: none)."""
    if values is None:
        return cast(List[Tuple[float, float]], _library_defaults()["context_radii"])
    if "off" in (v.strip() for v in values):
        if len(values) > 1:
            raise ValueError("--context-radius off cannot be combined with other context radii")
        return []
    radii: List[Tuple[float, float]] = []
    for v in values:
        factor, _, weight = v.partition(":")  # no ':' leaves weight empty, which float() refuses
        try:
            radii.append((float(factor), float(weight)))
        except ValueError:
            raise ValueError(f"--context-radius expects FACTOR:WEIGHT (e.g. 2:1) or off, got '{v}'") from None
    return radii


def _settings_of(a: argparse.Namespace) -> Dict[str, Any]:
    """The Registrar keyword arguments of the command-line flags (named as `dpr-gpu multiway` names them)."""
    if a.no_icp and (a.icp or a.icp_distance is not None or a.icp_iterations is not None):
        raise SystemExit("--no-icp cannot be combined with --icp, --icp-distance or --icp-iterations")
    icp = not a.no_icp
    return {
        "weights": a.weights,
        "keypoints": a.keypoints,
        "keypoint_mode": a.keypoint_mode,
        "radius": a.radius,
        "voxel": a.voxel,
        "normal_neighbors": a.normal_k,
        "estimator": a.estimator,
        "matching": "mutual",
        "mutual_k": a.mutual,
        "inlier_threshold": a.inlier_threshold,
        "ransac_iterations": a.ransac_iterations,
        "seed": a.seed,
        "icp": icp,
        "icp_max_correspondence_distance": a.icp_distance,
        "icp_max_iterations": 30 if a.icp_iterations is None else a.icp_iterations,
        "drop_zero_points": True if a.drop_zero else False if a.keep_zero else None,
        "backend": a.backend,
        "min_inliers": a.min_inliers,
        "min_inlier_ratio": a.min_inlier_ratio,
        "min_spread_over_threshold": a.min_inlier_spread,
        "free_space_check": not a.no_free_space_check,
        "context_radii": _context_radii(a.context_radius),
        "context_when": a.context_when,
        **({} if a.pose_candidates is None else {"pose_candidates": a.pose_candidates}),
    }


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The command line; returns the exit status."""
    a = _arguments().parse_args(argv)
    try:
        paths = scan_paths(a.input)
        out = Path(a.out)
        if out.is_file():
            raise ValueError(f"--out {out} is a file; it must be a folder")
        if Path(a.input).is_dir() and out.exists() and Path(a.input).resolve() == out.resolve():
            raise ValueError(f"--out {out} is the input folder; write the results to a folder of their own")
        settings = _settings_of(a)
        scans: List[Any]
        normals: Optional[List[Any]] = None
        if a.read_on_workers:
            scans = [str(p) for p in paths]
        else:
            loaded = [read_cloud(p, drop_zero_points=settings["drop_zero_points"]) for p in paths]
            scans = [points for points, _ in loaded]
            normals = [n for _, n in loaded] if all(n is not None for _, n in loaded) else None
        ray = _import_ray()
        if a.address is not None:
            ray.init(address=a.address)
        started = time.perf_counter()
        outcome = run(
            scans,
            normals=normals,
            pairs=cast(Literal["all", "consecutive+retrieval"], a.pairs),
            retrieval_k=a.retrieval_k,
            max_pairs=a.max_pairs,
            information_distance=a.information_distance,
            loop_preference=a.loop_preference,
            workers=a.workers,
            gpus_per_worker=a.gpus_per_worker,
            cpus_per_worker=a.cpus_per_worker,
            batch_size=a.batch_size,
            **settings,
        )
        outcome.result.write(out, [str(p) for p in paths])
    except (ValueError, OSError, ImportError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    edges = outcome.result.edges
    loops = [e for e in edges if e["kind"] == "loop"]
    backends = ", ".join(sorted({w["backend"] for w in outcome.workers}))
    odometry_trusted = sum(e["kind"] == "odometry" and e["trusted"] for e in edges)
    print(f"scans: {len(paths)} on {len(outcome.workers)} workers ({backends})")
    print(f"pairs registered: {len(edges)} ({odometry_trusted} odometry trusted of {len(paths) - 1})")
    print(
        f"loop closures: {len(loops)} candidates, {sum(e['in_graph'] for e in loops)} trusted, "
        f"{sum(e['survived'] for e in loops)} kept after the line processes"
    )
    unplaced = [k for k, c in enumerate(outcome.result.connected) if not c]
    if unplaced:
        print(
            f"warning: scans {unplaced} are not connected to scan 0 by any surviving edge; their poses are guesses",
            file=sys.stderr,
        )
    s = outcome.stage_seconds
    print(
        f"time: {time.perf_counter() - started:.1f} s (start {s['start']:.1f}, describe {s['describe']:.1f}, "
        f"pairs {s['pairs']:.1f}, graph {s['graph']:.2f})"
    )
    print(f"wrote {out / 'trajectory.log'}, {out / 'edges.json'}, {out / 'scans.txt'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
