//! CPU twin of `shaders/rotation_head.wgsl`: RelativeNet's raw outputs to rotation matrices target_from_source
//! in the fragments' frames.
//!
//! Per correspondence: the raw output becomes a rotation `R_net` (a quaternion normalised, or 6 values made
//! orthonormal by Gram-Schmidt), which relates the two patches in the frames PC-FoldNet saw them in. With
//! fragment-frame patches that is already the answer; with normal-aligned patches (each patch rotated by its
//! keypoint's [`normal_frame`] `F`, so its normal is +z) the fragment-frame rotation is
//! `R = F_target^T R_net F_source`. Matrices are row-major `[f32; 9]`.
//!
//! The angle-bin output gives several rotations per correspondence ([`angle_candidates`]): rows of `candidates`
//! consecutive matrices, best bin first.

use crate::model::config::{PoseFrame, RotationOutput};

/// Norms not above this (or NaN) make a raw output degenerate: it becomes the identity.
pub const MIN_NORM: f32 = 1e-12;

/// A 6-D output is degenerate too when the part of its second column orthogonal to the first is not above this
/// share of the second column's length (the columns within 0.06 degrees of parallel): that part is then mostly
/// rounding, amplified up to 1 / share times, so it names no second axis and two backends that round
/// differently (FMA contraction, GPU division) would return unrelated rotations.
pub const MIN_ORTHOGONAL_SHARE: f32 = 1e-3;

/// The identity, row-major.
pub const IDENTITY: [f32; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

/// A rotation `F` (row-major; rows t1, t2, n) that maps the unit normal `n` to +z, with a tangent basis fixed by
/// `n` alone (Duff et al., "Building an orthonormal basis, revisited", JCGT 2017). The basis switches at
/// `n.z = 0`; the sign test `n.z >= 0` is the same on the CPU and the GPU (-0.0 counts as positive). A zero
/// or NaN normal gives the identity.
pub fn normal_frame(n: [f32; 3]) -> [f32; 9] {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if len.is_nan() || len <= MIN_NORM {
        return IDENTITY;
    }
    let [x, y, z] = [n[0] / len, n[1] / len, n[2] / len];
    let sign = if z >= 0.0 { 1.0f32 } else { -1.0 };
    let a = -1.0 / (sign + z);
    let b = x * y * a;
    [1.0 + sign * x * x * a, sign * b, -sign * x, b, sign + y * y * a, -y, x, y, z]
}

/// Rotation matrix of the raw quaternion `[w, x, y, z]` after normalisation (identity when degenerate).
pub fn quaternion_rotation(raw: [f32; 4]) -> [f32; 9] {
    let n = (raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2] + raw[3] * raw[3]).sqrt();
    if n.is_nan() || n <= MIN_NORM {
        return IDENTITY;
    }
    let [w, x, y, z] = raw.map(|v| v / n);
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Rotation whose first two columns are the raw `[a1 | a2]` made orthonormal (Gram-Schmidt), the third their
/// cross product. Identity when `a1` is degenerate or the part of `a2` orthogonal to it is not above
/// `MIN_NORM` and [`MIN_ORTHOGONAL_SHARE`] of `|a2|`.
pub fn six_d_rotation(raw: [f32; 6]) -> [f32; 9] {
    let a1 = [raw[0], raw[1], raw[2]];
    let a2 = [raw[3], raw[4], raw[5]];
    let n1 = dot(a1, a1).sqrt();
    if n1.is_nan() || n1 <= MIN_NORM {
        return IDENTITY;
    }
    let b1 = a1.map(|v| v / n1);
    let d = dot(b1, a2);
    let u2 = [a2[0] - d * b1[0], a2[1] - d * b1[1], a2[2] - d * b1[2]];
    let n2 = dot(u2, u2).sqrt();
    if n2.is_nan() || n2 <= MIN_NORM || n2 <= MIN_ORTHOGONAL_SHARE * dot(a2, a2).sqrt() {
        return IDENTITY;
    }
    let b2 = u2.map(|v| v / n2);
    let b3 = [b1[1] * b2[2] - b1[2] * b2[1], b1[2] * b2[0] - b1[0] * b2[2], b1[0] * b2[1] - b1[1] * b2[0]];
    [b1[0], b2[0], b3[0], b1[1], b2[1], b3[1], b1[2], b2[2], b3[2]]
}

/// `a * b` for row-major 3x3 matrices.
pub fn mat_mul(a: &[f32; 9], b: &[f32; 9]) -> [f32; 9] {
    let mut out = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[r * 3 + c] = a[r * 3] * b[c] + a[r * 3 + 1] * b[3 + c] + a[r * 3 + 2] * b[6 + c];
        }
    }
    out
}

/// `a^T * b` for row-major 3x3 matrices.
pub fn mat_t_mul(a: &[f32; 9], b: &[f32; 9]) -> [f32; 9] {
    let mut out = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[r * 3 + c] = a[r] * b[c] + a[3 + r] * b[3 + c] + a[6 + r] * b[6 + c];
        }
    }
    out
}

/// The rotation about +z by `angle` radians.
pub fn rotation_about_z(angle: f32) -> [f32; 9] {
    let (s, c) = (angle.sin(), angle.cos());
    [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]
}

/// Logit ordering for the candidate search: NaN counts as below everything.
fn above(a: f32, b: f32) -> bool {
    !a.is_nan() && (b.is_nan() || a > b)
}

/// The `candidates` best angles (radians, in [-pi, pi)) of one row of `bins` angle logits, best first: bins by
/// decreasing logit (ties to the lower bin), each refined by the vertex of the parabola through its own and its
/// two neighbours' logits (wrapped), clamped to half a bin.
pub fn angle_candidates(logits: &[f32], candidates: usize) -> Vec<f32> {
    let k_bins = logits.len();
    let mut chosen = vec![false; k_bins];
    let mut out = Vec::with_capacity(candidates);
    for _ in 0..candidates.min(k_bins) {
        let mut best = usize::MAX;
        for k in 0..k_bins {
            if !chosen[k] && (best == usize::MAX || above(logits[k], logits[best])) {
                best = k;
            }
        }
        chosen[best] = true;
        let l0 = logits[(best + k_bins - 1) % k_bins];
        let l1 = logits[best];
        let l2 = logits[(best + 1) % k_bins];
        let den = l0 - 2.0 * l1 + l2;
        let offset = if den < 0.0 { (0.5 * (l0 - l2) / den).clamp(-0.5, 0.5) } else { 0.0 };
        let mut angle = std::f32::consts::TAU * (best as f32 + offset) / k_bins as f32;
        if angle >= std::f32::consts::PI {
            angle -= std::f32::consts::TAU;
        }
        out.push(angle);
    }
    out
}

/// The rotations of one raw output, in the network's (patch) frames: one, or one per angle candidate.
pub fn network_rotations(raw: &[f32], output: RotationOutput) -> Vec<[f32; 9]> {
    match output {
        RotationOutput::Quaternion => vec![quaternion_rotation([raw[0], raw[1], raw[2], raw[3]])],
        RotationOutput::SixD => vec![six_d_rotation([raw[0], raw[1], raw[2], raw[3], raw[4], raw[5]])],
        RotationOutput::AngleBins { .. } => {
            angle_candidates(raw, output.candidates()).into_iter().map(rotation_about_z).collect()
        }
    }
}

/// Fragment-frame rotations (target_from_source) of `rows` raw outputs (`rows x output.width()`), given the
/// keypoint normals of each correspondence's source and target patch (used by [`PoseFrame::Normal`]):
/// `rows x output.candidates()` matrices.
pub fn rotation_head(
    raw: &[f32],
    output: RotationOutput,
    frame: PoseFrame,
    source_normals: &[[f32; 3]],
    target_normals: &[[f32; 3]],
) -> Vec<[f32; 9]> {
    raw.chunks_exact(output.width())
        .enumerate()
        .flat_map(|(i, r)| {
            network_rotations(r, output).into_iter().map(move |net| match frame {
                PoseFrame::Fragment => net,
                PoseFrame::Normal => {
                    let fs = normal_frame(source_normals[i]);
                    let ft = normal_frame(target_normals[i]);
                    mat_mul(&mat_t_mul(&ft, &net), &fs)
                }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::matrix_from_quaternion;
    use crate::rng::Rng;
    use nalgebra::Matrix3;

    fn m(r: &[f32; 9]) -> Matrix3<f64> {
        Matrix3::from_row_slice(&r.map(f64::from))
    }

    fn assert_rotation(r: &[f32; 9]) {
        let r = m(r);
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-5, "not orthonormal: {r}");
        assert!((r.determinant() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn normal_frame_is_a_rotation_taking_the_normal_to_z() {
        let mut rng = Rng::new(5);
        let mut normals: Vec<[f32; 3]> = (0..200)
            .map(|_| {
                let q = rng.unit_quaternion();
                let r = matrix_from_quaternion(q);
                [r[(0, 2)] as f32, r[(1, 2)] as f32, r[(2, 2)] as f32]
            })
            .collect();
        normals.extend([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, -0.0], [0.0, 1.0, 0.0]]);
        for n in normals {
            let f = normal_frame(n);
            assert_rotation(&f);
            let z = m(&f) * nalgebra::Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
            assert!((z - nalgebra::Vector3::z()).norm() < 1e-5, "{n:?} -> {z}");
        }
        assert_eq!(normal_frame([0.0; 3]), IDENTITY);
        assert_eq!(normal_frame([f32::NAN; 3]), IDENTITY);
    }

    #[test]
    fn quaternion_and_six_d_outputs_give_the_rotation_they_encode() {
        let mut rng = Rng::new(9);
        for _ in 0..100 {
            let q = rng.unit_quaternion();
            let truth = matrix_from_quaternion(q);
            let scale = rng.uniform(0.1, 10.0);
            let raw_q = q.map(|v| (v * scale) as f32);
            let rq = quaternion_rotation(raw_q);
            assert!((m(&rq) - truth).norm() < 1e-5);
            // The first two columns, scaled and with a1 leaking into a2, still give the same rotation.
            let c = |j: usize| [truth[(0, j)], truth[(1, j)], truth[(2, j)]];
            let (c0, c1) = (c(0), c(1));
            let leak = rng.uniform(-2.0, 2.0);
            let raw6 = [
                (c0[0] * scale) as f32,
                (c0[1] * scale) as f32,
                (c0[2] * scale) as f32,
                (c1[0] + leak * c0[0]) as f32,
                (c1[1] + leak * c0[1]) as f32,
                (c1[2] + leak * c0[2]) as f32,
            ];
            let r6 = six_d_rotation(raw6);
            assert_rotation(&r6);
            assert!((m(&r6) - truth).norm() < 1e-5);
        }
        assert_eq!(quaternion_rotation([0.0; 4]), IDENTITY);
        assert_eq!(six_d_rotation([1.0, 0.0, 0.0, 2.0, 0.0, 0.0]), IDENTITY);
        assert_eq!(six_d_rotation([f32::NAN; 6]), IDENTITY);
        // Parallel columns whose orthogonal part is rounding, and one just under the share: the identity; just
        // over it, the rotation the columns name (second axis +y).
        assert_eq!(six_d_rotation([1.0, 2.0, 3.0, 2.0, 4.0, 6.0]), IDENTITY);
        assert_eq!(six_d_rotation([1.0, 0.0, 0.0, 1.0, 0.9 * MIN_ORTHOGONAL_SHARE, 0.0]), IDENTITY);
        let r = six_d_rotation([1.0, 0.0, 0.0, 1.0, 1.5 * MIN_ORTHOGONAL_SHARE, 0.0]);
        assert_rotation(&r);
        assert!((r[4] - 1.0).abs() < 1e-6, "{r:?}");
    }

    #[test]
    fn angle_candidates_are_ordered_refined_and_wrapped() {
        // A peak at bin 3 of 12 with a heavier right neighbour: best is bin 3, shifted right by the parabola's
        // vertex; the runner-up is the best remaining bin.
        let mut logits = vec![0.0f32; 12];
        logits[2] = 1.0;
        logits[3] = 3.0;
        logits[4] = 2.0;
        logits[9] = 2.5;
        let c = angle_candidates(&logits, 3);
        let bin = std::f32::consts::TAU / 12.0;
        let vertex = 0.5 * (1.0 - 2.0) / (1.0 - 6.0 + 2.0);
        assert!((c[0] - bin * (3.0 + vertex)).abs() < 1e-6);
        // Bin 9 (270 degrees) wraps to -90 degrees; its neighbours are equal, so no shift.
        assert!((c[1] - (bin * 9.0 - std::f32::consts::TAU)).abs() < 1e-6);
        // Bin 4's parabola peaks 1.5 bins to the left: clamped to half a bin.
        assert!((c[2] - bin * 3.5).abs() < 1e-6, "{c:?}");
        // Ties go to the lower bin, NaN ranks last, a flat row gives bin 0 unshifted.
        assert_eq!(
            angle_candidates(&[1.0, f32::NAN, 1.0, 0.5], 2),
            vec![0.0, std::f32::consts::PI - std::f32::consts::TAU]
        );
        assert_eq!(angle_candidates(&[f32::NAN, 0.0, 0.0, 0.0], 1), vec![std::f32::consts::FRAC_PI_2 * 1.0]);
        assert_eq!(angle_candidates(&[0.0; 4], 9).len(), 4);
        // A one-hot row at the true angle's bin gives that angle's rotation about z.
        let mut hot = vec![-10.0f32; 36];
        hot[7] = 10.0;
        let out = network_rotations(&hot, RotationOutput::AngleBins { bins: 36, candidates: 2 });
        assert_eq!(out.len(), 2);
        assert!((m(&out[0]) - m(&rotation_about_z(70f32.to_radians()))).norm() < 1e-5);
    }

    #[test]
    fn normal_frames_recover_the_fragment_rotation() {
        // A patch pair related by a known rotation R: source normal n_s, target normal n_t = R n_s. The network
        // sees the patches in their normal frames, related by F_t R F_s^T; the head must give back R.
        let mut rng = Rng::new(21);
        for _ in 0..100 {
            let r = matrix_from_quaternion(rng.unit_quaternion());
            let n_s = matrix_from_quaternion(rng.unit_quaternion()).column(0).into_owned();
            let n_t = r * n_s;
            let to32 = |v: nalgebra::Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
            let fs = m(&normal_frame(to32(n_s)));
            let ft = m(&normal_frame(to32(n_t)));
            let net = ft * r * fs.transpose();
            // The aligned rotation keeps +z: it is a rotation about the normal.
            assert!((net * nalgebra::Vector3::z() - nalgebra::Vector3::z()).norm() < 1e-5);
            let raw = [net[(0, 0)], net[(1, 0)], net[(2, 0)], net[(0, 1)], net[(1, 1)], net[(2, 1)]].map(|v| v as f32);
            let out = rotation_head(&raw, RotationOutput::SixD, PoseFrame::Normal, &[to32(n_s)], &[to32(n_t)]);
            assert!((m(&out[0]) - r).norm() < 1e-4);
        }
    }
}
