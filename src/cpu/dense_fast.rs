//! CPU twin of `shaders/dense_fast.wgsl`. The fast kernel computes exactly the function of
//! `shaders/dense.wgsl` in the same order for every output element (its start value, then the products added in
//! increasing k), only tiled differently, so its twin is the reference twin [`super::dense::dense`].

use super::dense::DenseShape;

/// The layer, as [`super::dense::dense`] computes it.
pub fn dense_fast(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    super::dense::dense(shape, x, w_t, group_term, out);
}
