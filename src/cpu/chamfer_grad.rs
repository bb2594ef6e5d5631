//! CPU twin of `shaders/chamfer_grad.wgsl`, and what the trainer runs (in f64, as the loss): the second half of
//! the reconstruction loss ([`crate::train::loss::chamfer`]), the paper's Chamfer distance of each patch and its
//! gradient w.r.t. the reconstruction, from the nearest points of [`super::chamfer_nearest`].

/// Below this norm the gradient of `|y - x|` is scaled towards zero instead of dividing by zero
/// (`crate::train::loss::NORM_EPS`).
pub const NORM_EPS: f64 = 1e-12;

/// Per patch `d = max(a, b)`, `a = mean_x |x - nearest y|`, `b = mean_y |y - nearest x|` (from `distance`, in
/// row order), and `scale` times its gradient w.r.t. `y` (`patches * m x dim`): when `a >= b`, each `y` row
/// gathers `(y - x) / |y - x| / n` over the `x` rows whose nearest it is, in row order; else each `y` row gets
/// `(y - x) / |y - x| / m` for its own nearest `x`. Each term is formed in f64 and added in f32 in that order,
/// then multiplied by `scale`. `nearest` and `distance` are [`super::chamfer_nearest::chamfer_nearest`]'s.
pub fn chamfer_grad(
    x: &[f32],
    y: &[f32],
    dim: usize,
    (n, m): (usize, usize),
    (nearest, distance): (&[u32], &[f64]),
    scale: f32,
) -> (Vec<f64>, Vec<f32>) {
    let mut grad = vec![0.0f32; y.len()];
    let patches = nearest.len() / (n + m).max(1);
    let mut losses = Vec::with_capacity(patches);
    for p in 0..patches {
        let (xs, ys) = (&x[p * n * dim..][..n * dim], &y[p * m * dim..][..m * dim]);
        let g = &mut grad[p * m * dim..][..m * dim];
        let (near, dist) = (&nearest[p * (n + m)..][..n + m], &distance[p * (n + m)..][..n + m]);
        let a = dist[..n].iter().sum::<f64>() / n as f64;
        let b = dist[n..].iter().sum::<f64>() / m as f64;
        // d|y - x| / dy = (y - x) / |y - x|, guarded at 0.
        let mut push = |i: usize, j: usize, weight: f64| {
            let diff: Vec<f64> = (0..dim).map(|c| ys[j * dim + c] as f64 - xs[i * dim + c] as f64).collect();
            let len = diff.iter().map(|v| v * v).sum::<f64>().sqrt().max(NORM_EPS);
            for (c, dv) in diff.iter().enumerate() {
                g[j * dim + c] += (weight * dv / len) as f32;
            }
        };
        if a >= b {
            for (i, &j) in near[..n].iter().enumerate() {
                push(i, j as usize, 1.0 / n as f64);
            }
        } else {
            for (j, &i) in near[n..].iter().enumerate() {
                push(i as usize, j, 1.0 / m as f64);
            }
        }
        losses.push(a.max(b));
        g.iter_mut().for_each(|v| *v *= scale);
    }
    (losses, grad)
}
