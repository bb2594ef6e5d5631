//! CPU twin of `shaders/relu_backward.wgsl`, and what the trainer runs: ReLU's derivative applied to a
//! gradient.

/// `d_out` masked by ReLU's derivative: passes where the layer's (post-ReLU) output is positive. At exactly
/// zero the derivative is taken as 0 (the output there is clamped).
pub fn relu_backward(out: &[f32], d_out: &[f32]) -> Vec<f32> {
    out.iter().zip(d_out).map(|(&y, &g)| if y > 0.0 { g } else { 0.0 }).collect()
}
