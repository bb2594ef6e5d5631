//! The loss terms of the paper (RelativeNet, CVPR 2019, section 3.3) and their gradients.
//!
//! Every loss is evaluated in f64 from f32 inputs and returns f32 gradients.
//!
//! Euclidean norms are not differentiable at 0: the gradient of `|v|` is taken as `v / max(|v|, NORM_EPS)`,
//! which is the exact derivative `v / |v|` whenever `|v| >= NORM_EPS` and goes smoothly to 0 (a valid
//! subgradient) at `v = 0`, so a point that sits exactly on its reconstruction, or two identical codewords,
//! give a zero gradient instead of NaN. Values are never changed by the guard.

/// Below this norm, the gradient of a Euclidean norm is scaled down towards zero (see the module docs).
pub const NORM_EPS: f64 = crate::cpu::chamfer_grad::NORM_EPS;

use crate::cpu::chamfer_grad::chamfer_grad;
use crate::cpu::chamfer_nearest::chamfer_nearest;
use crate::model::config::RotationOutput;
use nalgebra::Matrix3;

/// Euclidean norm in f64.
fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Chamfer distance of the paper, `d(X, Y) = max(mean_x min_y |x - y|, mean_y min_x |x - y|)` (Euclidean, not
/// squared), between `x` (`n x dim`, the input patch) and `y` (`m x dim`, the reconstruction), and its
/// gradient w.r.t. `y`: the two kernels' twins, [`chamfer_nearest`] then [`chamfer_grad`], on one patch.
///
/// Nearest neighbours are found by brute force; ties go to the lowest index, and when both directions are
/// equal the gradient is that of the first (X to Y). Empty sets give 0 and a zero gradient.
pub fn chamfer(x: &[f32], y: &[f32], dim: usize) -> (f64, Vec<f32>) {
    let (n, m) = (x.len() / dim.max(1), y.len() / dim.max(1));
    if dim == 0 || n == 0 || m == 0 {
        return (0.0, vec![0.0f32; y.len()]);
    }
    let (nearest, distance) = chamfer_nearest(x, y, dim, (n, m));
    let (losses, grad) = chamfer_grad(x, y, dim, (n, m), (&nearest, &distance), 1.0);
    (losses[0], grad)
}

/// Below this norm a raw rotation output is degenerate: it maps to the identity with a zero gradient (the same
/// threshold as `crate::cpu::rotation_head`).
pub const MIN_QUATERNION_NORM: f64 = crate::cpu::rotation_head::MIN_NORM as f64;

/// `q = r / |r|` (the identity when `|r|` is below [`MIN_QUATERNION_NORM`]).
pub fn normalize_quaternion(r: [f32; 4]) -> [f64; 4] {
    let r = r.map(f64::from);
    let n = norm(&r);
    if n.is_nan() || n <= MIN_QUATERNION_NORM {
        return [1.0, 0.0, 0.0, 0.0];
    }
    r.map(|v| v / n)
}

/// Gradient of a loss w.r.t. the raw output `r`, given its gradient `d_q` w.r.t. `q = r / |r|`:
/// `(I - q q^T) d_q / |r|`. Zero for a degenerate `r`.
pub fn normalize_quaternion_backward(r: [f32; 4], d_q: [f64; 4]) -> [f64; 4] {
    let rr = r.map(f64::from);
    let n = norm(&rr);
    if n.is_nan() || n <= MIN_QUATERNION_NORM {
        return [0.0; 4];
    }
    let q = rr.map(|v| v / n);
    let dot: f64 = q.iter().zip(&d_q).map(|(a, b)| a * b).sum();
    [0, 1, 2, 3].map(|i| (d_q[i] - q[i] * dot) / n)
}

/// The pose loss `min(|q - q*|, |q + q*|)` (plain L2, as the paper's eq. 5) between a unit quaternion `q` and
/// the label `q*`, and its gradient w.r.t. `q`.
///
/// `q` and `-q` are the same rotation, and a label can be written with either sign. Comparing against the
/// nearer of `q*` and `-q*` makes the loss a function of the two rotations only, so the network is never
/// punished for choosing the other (equally correct) sign, and the target does not jump where a fixed sign
/// convention (say w >= 0) would flip it (rotations by about 180 degrees). On a tie (`q . q* = 0`) the
/// `q - q*` branch is used.
pub fn pose_loss(q: [f64; 4], label: [f64; 4]) -> (f64, [f64; 4]) {
    let minus = [0, 1, 2, 3].map(|i| q[i] - label[i]);
    let plus = [0, 1, 2, 3].map(|i| q[i] + label[i]);
    let (nm, np) = (norm(&minus), norm(&plus));
    let (diff, len) = if nm <= np { (minus, nm) } else { (plus, np) };
    let g = len.max(NORM_EPS);
    (len, diff.map(|d| d / g))
}

/// The feature-consistency loss of one corresponding pair, `|f_p - f_q|` (L2 of the difference of the two
/// PPF-FoldNet codewords), and its gradient w.r.t. `f_p` (the gradient w.r.t. `f_q` is its negation).
pub fn feat_loss(f_p: &[f32], f_q: &[f32]) -> (f64, Vec<f32>) {
    let diff: Vec<f64> = f_p.iter().zip(f_q).map(|(&a, &b)| a as f64 - b as f64).collect();
    let len = norm(&diff);
    let g = len.max(NORM_EPS);
    (len, diff.iter().map(|d| (d / g) as f32).collect())
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The 6-D output's rotation in f64 (as `crate::cpu::rotation_head::six_d_rotation`): columns
/// `b1 = a1 / |a1|`, `b2 = (a2 - (b1.a2) b1) / |..|`, `b3 = b1 x b2`; `None` when degenerate (the same rule).
fn gram_schmidt(raw: [f32; 6]) -> Option<([[f64; 3]; 3], f64, f64)> {
    let a1 = [raw[0], raw[1], raw[2]].map(f64::from);
    let a2 = [raw[3], raw[4], raw[5]].map(f64::from);
    let n1 = norm(&a1);
    if n1.is_nan() || n1 <= MIN_QUATERNION_NORM {
        return None;
    }
    let b1 = a1.map(|v| v / n1);
    let d = dot3(b1, a2);
    let u2 = [0, 1, 2].map(|i| a2[i] - d * b1[i]);
    let n2 = norm(&u2);
    let min_share = f64::from(crate::cpu::rotation_head::MIN_ORTHOGONAL_SHARE);
    if n2.is_nan() || n2 <= MIN_QUATERNION_NORM || n2 <= min_share * norm(&a2) {
        return None;
    }
    let b2 = u2.map(|v| v / n2);
    Some(([b1, b2, cross(b1, b2)], n1, n2))
}

/// The chordal pose loss of a 6-D output, `|R - R*|_F / 2` (R from Gram-Schmidt on the raw `[a1 | a2]`, R* the
/// row-major label), and its gradient w.r.t. the raw output. `|R - R*|_F / 2 = sqrt(2) sin(theta / 2)` for a
/// rotation error theta: the same shape as the quaternion loss `2 sin(theta / 4)`, but continuous over all of
/// SO(3). A degenerate output is scored as the identity with a zero gradient.
pub fn six_d_pose_loss(raw: [f32; 6], label: &[f64; 9]) -> (f64, [f64; 6]) {
    let Some(([b1, b2, b3], n1, n2)) = gram_schmidt(raw) else {
        let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let diff: Vec<f64> = identity.iter().zip(label).map(|(a, b)| a - b).collect();
        return (0.5 * norm(&diff), [0.0; 6]);
    };
    let cols = [b1, b2, b3];
    // diff[c][r] = R[r][c] - label[r][c].
    let diff = [0, 1, 2].map(|c| [0, 1, 2].map(|r| cols[c][r] - label[r * 3 + c]));
    let len = norm(&diff.concat());
    let g = 0.5 / len.max(NORM_EPS);
    let [mut g1, mut g2, g3] = diff.map(|col| col.map(|v| v * g));
    // b3 = b1 x b2.
    let (c1, c2) = (cross(b2, g3), cross(g3, b1));
    g1 = [0, 1, 2].map(|i| g1[i] + c1[i]);
    g2 = [0, 1, 2].map(|i| g2[i] + c2[i]);
    // b2 = u2 / |u2|.
    let k2 = dot3(b2, g2);
    let g_u2 = [0, 1, 2].map(|i| (g2[i] - b2[i] * k2) / n2);
    // u2 = a2 - (b1 . a2) b1.
    let a2 = [raw[3], raw[4], raw[5]].map(f64::from);
    let (d, k) = (dot3(b1, a2), dot3(b1, g_u2));
    let g_a2 = [0, 1, 2].map(|i| g_u2[i] - b1[i] * k);
    g1 = [0, 1, 2].map(|i| g1[i] - d * g_u2[i] - a2[i] * k);
    // b1 = a1 / |a1|.
    let k1 = dot3(b1, g1);
    let g_a1 = [0, 1, 2].map(|i| (g1[i] - b1[i] * k1) / n1);
    (0.5 * len, [g_a1[0], g_a1[1], g_a1[2], g_a2[0], g_a2[1], g_a2[2]])
}

/// Width (in bins) of the wrapped Gaussian the angle-bin target spreads over.
pub const ANGLE_TARGET_SIGMA_BINS: f64 = 1.0;

/// Below this z-z element the label does not keep the normal (the two viewpoints oriented the normals
/// oppositely): no angle about the normal describes it, and the angle-bin loss skips the sample.
pub const MIN_LABEL_NORMAL_COS: f64 = 0.5;

/// The angle-bin pose loss: cross-entropy of the softmax over `logits` against a wrapped Gaussian
/// (`ANGLE_TARGET_SIGMA_BINS`) centred on the label's angle about z, `atan2(R[1][0], R[0][0])`, and its gradient
/// `softmax - target` w.r.t. the logits. A label that flips the normal (`R[2][2] <` [`MIN_LABEL_NORMAL_COS`])
/// gives zero loss and gradient.
pub fn angle_bins_loss(logits: &[f32], label: &[f64; 9]) -> (f64, Vec<f64>) {
    let k = logits.len();
    if k == 0 || label[8] < MIN_LABEL_NORMAL_COS {
        return (0.0, vec![0.0; k]);
    }
    let angle = label[3].atan2(label[0]).rem_euclid(std::f64::consts::TAU);
    let position = angle / std::f64::consts::TAU * k as f64;
    let mut target: Vec<f64> = (0..k)
        .map(|b| {
            let d = (b as f64 - position).rem_euclid(k as f64);
            let d = d.min(k as f64 - d);
            (-0.5 * (d / ANGLE_TARGET_SIGMA_BINS).powi(2)).exp()
        })
        .collect();
    let total: f64 = target.iter().sum();
    target.iter_mut().for_each(|t| *t /= total);
    let z: Vec<f64> = logits.iter().map(|&v| f64::from(v)).collect();
    let max = z.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let sum: f64 = z.iter().map(|v| (v - max).exp()).sum();
    let log_sum = max + sum.ln();
    let loss = -z.iter().zip(&target).map(|(v, t)| t * (v - log_sum)).sum::<f64>();
    let grad = z.iter().zip(&target).map(|(v, t)| (v - log_sum).exp() - t).collect();
    (loss, grad)
}

/// The pose loss of a raw RelativeNet output of either encoding against the label rotation (row-major, in the
/// frames the network sees), and its gradient w.r.t. the raw output: the paper's quaternion L2 loss
/// ([`pose_loss`] after [`normalize_quaternion`]), the 6-D chordal loss ([`six_d_pose_loss`]) or the angle-bin
/// cross-entropy ([`angle_bins_loss`]).
pub fn rotation_loss(raw: &[f32], output: RotationOutput, label: &[f64; 9]) -> (f64, Vec<f32>) {
    match output {
        RotationOutput::Quaternion => {
            let r = [raw[0], raw[1], raw[2], raw[3]];
            let q_label = crate::pose::quaternion_from_matrix(&Matrix3::from_row_slice(label));
            let (loss, d_q) = pose_loss(normalize_quaternion(r), q_label);
            (loss, normalize_quaternion_backward(r, d_q).map(|v| v as f32).to_vec())
        }
        RotationOutput::SixD => {
            let (loss, d) = six_d_pose_loss([raw[0], raw[1], raw[2], raw[3], raw[4], raw[5]], label);
            (loss, d.map(|v| v as f32).to_vec())
        }
        RotationOutput::AngleBins { .. } => {
            let (loss, d) = angle_bins_loss(raw, label);
            (loss, d.into_iter().map(|v| v as f32).collect())
        }
    }
}
