//! CPU twin of `shaders/adam_step.wgsl`, and what the trainer runs ([`crate::train::adam::Adam::step`]): one
//! AdamW update of one tensor, element by element. The twin computes each element in f64 (the moments are
//! stored in f32); the shader has no f64 and computes in f32 (its parity test allows for that).

/// The scalars of one update step, the same for every tensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamStep {
    /// Learning rate of this step.
    pub lr: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator guard.
    pub eps: f64,
    /// Decoupled weight decay of tensors that take it (per unit learning rate).
    pub weight_decay: f64,
    /// First-moment bias correction `1 - beta1^t`.
    pub c1: f64,
    /// Second-moment bias correction `1 - beta2^t`.
    pub c2: f64,
}

/// Updates `value` in place from `grad`, with the moments `m` and `v` (all of one length):
/// `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`, `x -= lr (m / c1 / (sqrt(v / c2) + eps) + wd x)`, `wd`
/// the weight decay when `decay` and 0 otherwise.
pub fn adam_step(step: &AdamStep, decay: bool, value: &mut [f32], grad: &[f32], m: &mut [f32], v: &mut [f32]) {
    let s = step;
    let wd = if decay { s.weight_decay } else { 0.0 };
    for (((x, &g), mi), vi) in value.iter_mut().zip(grad).zip(m.iter_mut()).zip(v.iter_mut()) {
        let g = g as f64;
        let m_new = s.beta1 * *mi as f64 + (1.0 - s.beta1) * g;
        let v_new = s.beta2 * *vi as f64 + (1.0 - s.beta2) * g * g;
        *mi = m_new as f32;
        *vi = v_new as f32;
        let update = (m_new / s.c1) / ((v_new / s.c2).sqrt() + s.eps) + wd * *x as f64;
        *x = (*x as f64 - s.lr * update) as f32;
    }
}
