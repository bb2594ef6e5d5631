"""Issue 36 case 4, third candidate (a probe): on a registered pair's final correspondences, how many the best
rotation explains against the best reflection (3-point RANSAC on the keypoints, 20,000 draws, seed 0, the run's
inlier threshold), for each SOURCE,TARGET given as it is and with the source mirrored (x -> -x).
(docs/experiments/mirrored-scans.md)

    python benches/compare/mirrored_handedness.py SOURCE,TARGET [SOURCE,TARGET ...]   (needs dpr_gpu, numpy)
"""
import sys
import numpy as np
import dpr_gpu

def fit(S, T, reflect):
    ms, mt = S.mean(0), T.mean(0)
    H = (S - ms).T @ (T - mt)
    U, _, Vt = np.linalg.svd(H)
    d = np.linalg.det(Vt.T @ U.T)
    want = -1.0 if reflect else 1.0
    D = np.diag([1, 1, d * want])
    R = Vt.T @ D @ U.T
    return R, mt - R @ ms

def ransac(S, T, tau, reflect, iters=20000, seed=0):
    rng = np.random.default_rng(seed)
    best = 0
    n = len(S)
    for _ in range(iters):
        idx = rng.choice(n, 3, replace=False)
        R, t = fit(S[idx], T[idx], reflect)
        inl = np.linalg.norm(S @ R.T + t - T, axis=1) < tau
        c = int(inl.sum())
        if c > best:
            best = c
    return best

for src, tgt in [a.split(",") for a in sys.argv[1:]]:
    p, n = dpr_gpu.read_cloud(src); q, m = dpr_gpu.read_cloud(tgt)
    for kind, pts, nrm in (("real", p, n), ("mirrored", p * [-1, 1, 1], None if n is None else n * [-1, 1, 1])):
        r = dpr_gpu.register(pts, q, source_normals=nrm, target_normals=m, backend="cpu")
        c = r.correspondences
        S = r.source_keypoints[c[:, 0]]; T = r.target_keypoints[c[:, 1]]
        tau = r.scale["inlier_threshold"]
        rot = ransac(S, T, tau, False); ref = ransac(S, T, tau, True)
        print(f"{src.split('/')[-1]}->{tgt.split('/')[-1]} {kind}: trusted={r.success} corr={len(c)} rotation inliers={rot} reflection inliers={ref}", flush=True)
