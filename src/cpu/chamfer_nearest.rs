//! CPU twin of `shaders/chamfer_nearest.wgsl`, and what the trainer runs (in f64, as the loss): the first half
//! of the reconstruction loss ([`crate::train::loss::chamfer`]), each point's nearest point of the other set,
//! patch by patch.

/// For each of `patches` patch pairs, `x` (`patches * n x dim`, the input points) and `y` (`patches * m x dim`,
/// the reconstruction): the nearest `y` of every `x` row, then the nearest `x` of every `y` row, by brute force
/// in f64 (ties to the lowest index). Returns `patches * (n + m)` indices, local to the patch (`0..m` for the
/// first `n` rows of a patch, `0..n` for the next `m`), and the Euclidean distances to them.
pub fn chamfer_nearest(x: &[f32], y: &[f32], dim: usize, (n, m): (usize, usize)) -> (Vec<u32>, Vec<f64>) {
    let patches = if dim == 0 || n == 0 || m == 0 { 0 } else { (x.len() / (n * dim)).min(y.len() / (m * dim)) };
    let mut nearest = Vec::with_capacity(patches * (n + m));
    let mut distance = Vec::with_capacity(patches * (n + m));
    for p in 0..patches {
        let (xs, ys) = (&x[p * n * dim..][..n * dim], &y[p * m * dim..][..m * dim]);
        let d2 = |i: usize, j: usize| {
            let (a, b) = (&xs[i * dim..][..dim], &ys[j * dim..][..dim]);
            a.iter().zip(b).map(|(&u, &v)| (u as f64 - v as f64).powi(2)).sum::<f64>()
        };
        // For each x its nearest y, for each y its nearest x (squared distances, in one pass over all pairs).
        let mut near_y = vec![(f64::INFINITY, 0u32); n];
        let mut near_x = vec![(f64::INFINITY, 0u32); m];
        for (i, ny) in near_y.iter_mut().enumerate() {
            for (j, nx) in near_x.iter_mut().enumerate() {
                let d = d2(i, j);
                if d < ny.0 {
                    *ny = (d, j as u32);
                }
                if d < nx.0 {
                    *nx = (d, i as u32);
                }
            }
        }
        for &(d, k) in near_y.iter().chain(&near_x) {
            nearest.push(k);
            distance.push(d.sqrt());
        }
    }
    (nearest, distance)
}
