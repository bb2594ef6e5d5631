//! CPU twin of `shaders/patch_features.wgsl`: per patch point, the 4-D point pair feature and the centred,
//! scaled PC coordinate.
//!
//! For reference point p_r (the keypoint, normal n_r) and neighbour p_i (normal n_i), with d = p_r - p_i:
//! `ppf = (angle(n_r, d) / pi, angle(n_i, d) / pi, angle(n_r, n_i) / pi, |d| / r)` and `pc = (p_i - p_r) / r`,
//! where `angle(a, b) = atan2(|a x b|, a . b)` is in [0, pi] and is 0 when a or b is zero (coincident points,
//! zero normals), so degenerate geometry gives finite features. With [`PoseFrame::Normal`] the PC coordinate is
//! rotated into the keypoint's normal frame, `pc = F(n_r) (p_i - p_r) / r` (`rotation_head::normal_frame`), so
//! every patch's normal is +z.

use super::rotation_head::normal_frame;
use crate::model::config::PoseFrame;
use rayon::prelude::*;

/// Angle between two vectors in [0, pi]; 0 when either is zero.
pub fn angle(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (s, c) = sine_cosine_terms(a, b);
    angle_of(s, c)
}

/// `(|a x b|, a . b)` in f32: the two arguments of [`angle`]'s atan2.
fn sine_cosine_terms(a: [f32; 3], b: [f32; 3]) -> (f32, f32) {
    let cross = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let s = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
    (s, a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
}

/// The angle whose [`sine_cosine_terms`] are `(s, c)`: 0 when both are 0 (a zero vector).
fn angle_of(s: f32, c: f32) -> f32 {
    if s == 0.0 && c == 0.0 { 0.0 } else { atan2_upper(s, c) }
}

/// `out[i] = angle_of(s[i], c[i])` for every i, four at a time on AVX2 where the CPU has it (the same
/// arithmetic lane by lane, so the same bits), the rest one by one.
fn angles_of(s: &[f32], c: &[f32], out: &mut [f32]) {
    assert!(s.len() == out.len() && c.len() == out.len());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX2 (checked first).
    let done = if std::arch::is_x86_feature_detected!("avx2") { unsafe { x86::angles_of(s, c, out) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for ((o, &s), &c) in out.iter_mut().zip(s).zip(c).skip(done) {
        *o = angle_of(s, c);
    }
}

/// Coefficients of `(atan(u) - u) / u^3` as a polynomial in `u^2` on `|u| <= tan(pi / 8)`, fitted on
/// Chebyshev nodes: `atan` to 1.1e-13 relative there.
const ATAN_COEFFICIENTS: [f64; 8] = [
    -0.3333333333327346,
    0.1999999995223682,
    -0.14285708298906494,
    0.11110825795390192,
    -0.09084198251785919,
    0.07605596694090146,
    -0.060306034170028736,
    0.03301067519459196,
];

/// `y.atan2(x)` for `y >= 0` (an angle in [0, pi]), evaluated in f64 to about 1e-13 and rounded once to
/// f32: the correctly rounded angle but where it lies within 1e-13 of a rounding boundary, and several times
/// faster than the C library's `atan2f` (the patch features take three per point). For finite `x` and `y`;
/// NaN stays NaN.
pub fn atan2_upper(y: f32, x: f32) -> f32 {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI, SQRT_2};
    // No branches (the three conditions are as good as random from point to point, and a mispredicted
    // branch costs more than the whole polynomial): each condition is a sign bit, 0.0 or 1.0, and enters
    // the arithmetic as a factor whose products are exact (0 or the value itself), so the result is the
    // one of the plain `if`s.
    if y.is_nan() || x.is_nan() {
        // (Never taken on features of finite points, so always predicted.)
        return f32::NAN;
    }
    let sign_bit = |v: f64| (v.to_bits() >> 63) as f64;
    let (y, ax) = (f64::from(y), f64::from(x).abs());
    // t = num / den in [0, 1], the angle's distance from the nearer axis; `swap` when that axis is y.
    let (num, den) = (y.min(ax), y.max(ax));
    let swap = sign_bit(ax - y);
    // Above tan(pi / 8), t is reduced by atan(t) = pi / 4 + atan((t - 1) / (t + 1)), so |u| <= tan(pi / 8).
    let reduce = sign_bit((SQRT_2 - 1.0) * den - num);
    let u = (num - reduce * den) / (den + reduce * num);
    let v = u * u;
    let poly = ATAN_COEFFICIENTS.iter().rev().fold(0.0, |acc, &c| acc * v + c);
    let r = u + u * v * poly + reduce * FRAC_PI_4;
    let r = swap * FRAC_PI_2 + (1.0 - 2.0 * swap) * r;
    // x < 0 (or -0.0, where r is pi / 2 or the angle is atan2's pi for y = 0): pi - r.
    let left = sign_bit(f64::from(x));
    (left * PI + (1.0 - 2.0 * left) * r) as f32
}

/// Features of one neighbour: (ppf, pc).
pub fn point_features(p_r: [f32; 3], n_r: [f32; 3], p_i: [f32; 3], n_i: [f32; 3], radius: f32) -> ([f32; 4], [f32; 3]) {
    let (terms, dist, pc) = point_terms(p_r, n_r, p_i, n_i, radius);
    let inv_pi = std::f32::consts::FRAC_1_PI;
    let [a, b, c] = terms.map(|(s, c)| angle_of(s, c) * inv_pi);
    ([a, b, c, dist], pc)
}

/// What [`point_features`] takes its features from: the [`sine_cosine_terms`] of its three angles (the
/// keypoint's normal and the offset, the neighbour's normal and the offset, the two normals), the distance over
/// `radius`, and the PC coordinates.
fn point_terms(
    p_r: [f32; 3],
    n_r: [f32; 3],
    p_i: [f32; 3],
    n_i: [f32; 3],
    radius: f32,
) -> ([(f32, f32); 3], f32, [f32; 3]) {
    let d = [p_r[0] - p_i[0], p_r[1] - p_i[1], p_r[2] - p_i[2]];
    let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let terms = [sine_cosine_terms(n_r, d), sine_cosine_terms(n_i, d), sine_cosine_terms(n_r, n_i)];
    (terms, dist / radius, [-d[0] / radius, -d[1] / radius, -d[2] / radius])
}

/// `frame * v` for a row-major 3x3 frame.
pub fn apply_frame(frame: &[f32; 9], v: [f32; 3]) -> [f32; 3] {
    [
        frame[0] * v[0] + frame[1] * v[1] + frame[2] * v[2],
        frame[3] * v[0] + frame[4] * v[1] + frame[5] * v[2],
        frame[6] * v[0] + frame[7] * v[1] + frame[8] * v[2],
    ]
}

/// Features of every patch. `centers`/`center_normals` have one entry per patch; `points`/`normals` have
/// `patches x points_per_patch` entries (gathered neighbours). Returns (`ppf`: P x N x 4, `pc`: P x N x 3), the
/// PC coordinates in `frame`.
pub fn patch_features(
    centers: &[[f32; 3]],
    center_normals: &[[f32; 3]],
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    points_per_patch: usize,
    radius: f32,
    frame: PoseFrame,
) -> (Vec<f32>, Vec<f32>) {
    // Patches in parallel; each patch's frame once (it depends on the keypoint's normal only).
    // Each row is `point_features` of its point (its `point_terms`); the patch's three angles per point are taken together
    // ([`angles_of`]).
    let n = points_per_patch.max(1);
    let mut ppf = vec![0.0; points.len() * 4];
    let mut pc = vec![0.0; points.len() * 3];
    let inv_pi = std::f32::consts::FRAC_1_PI;
    ppf.par_chunks_mut(n * 4).zip(pc.par_chunks_mut(n * 3)).enumerate().for_each_init(
        AngleScratch::default,
        |scratch, (patch, (ppf, pc))| {
            let (center, center_normal) = (centers[patch], center_normals[patch]);
            let rotation = match frame {
                PoseFrame::Fragment => None,
                PoseFrame::Normal => Some(normal_frame(center_normal)),
            };
            let rows = points[patch * n..].iter().zip(&normals[patch * n..]).take(ppf.len() / 4);
            scratch.clear();
            for ((f_out, c_out), (p, normal)) in ppf.chunks_exact_mut(4).zip(pc.chunks_exact_mut(3)).zip(rows) {
                let (terms, dist, c) = point_terms(center, center_normal, *p, *normal, radius);
                for (s, c) in terms {
                    scratch.sines.push(s);
                    scratch.cosines.push(c);
                }
                f_out[3] = dist;
                c_out.copy_from_slice(&rotation.map_or(c, |m| apply_frame(&m, c)));
            }
            scratch.angles.resize(scratch.sines.len(), 0.0);
            angles_of(&scratch.sines, &scratch.cosines, &mut scratch.angles);
            for (f_out, angles) in ppf.chunks_exact_mut(4).zip(scratch.angles.chunks_exact(3)) {
                for (f, &a) in f_out.iter_mut().zip(angles) {
                    *f = a * inv_pi;
                }
            }
        },
    );
    (ppf, pc)
}

/// One task's buffers for a patch's angle arguments and angles.
#[derive(Default)]
struct AngleScratch {
    sines: Vec<f32>,
    cosines: Vec<f32>,
    angles: Vec<f32>,
}

impl AngleScratch {
    fn clear(&mut self) {
        self.sines.clear();
        self.cosines.clear();
        self.angles.clear();
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{ATAN_COEFFICIENTS, angle_of};
    use std::arch::x86_64::*;
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI, SQRT_2};

    /// [`super::angles_of`] on the leading multiple of 4: [`super::atan2_upper`]'s operations four lanes at
    /// a time in f64 (separate multiplies and adds, exact selects where it multiplies by a 0-or-1 factor), a
    /// group holding a NaN one by one; returns how many it wrote.
    #[target_feature(enable = "avx2")]
    pub(super) fn angles_of(s: &[f32], c: &[f32], out: &mut [f32]) -> usize {
        let full = out.len() / 4 * 4;
        let pd = _mm256_set1_pd;
        for i in (0..full).step_by(4) {
            // SAFETY: `s`, `c` and `out` hold `full` values (asserted by the caller: equal lengths).
            unsafe {
                let s4 = _mm_loadu_ps(s.as_ptr().add(i));
                let c4 = _mm_loadu_ps(c.as_ptr().add(i));
                if _mm_movemask_ps(_mm_cmpunord_ps(s4, c4)) != 0 {
                    for j in i..i + 4 {
                        out[j] = angle_of(s[j], c[j]);
                    }
                    continue;
                }
                let (y, x) = (_mm256_cvtps_pd(s4), _mm256_cvtps_pd(c4));
                let ax = _mm256_andnot_pd(pd(-0.0), x);
                let (num, den) = (_mm256_min_pd(y, ax), _mm256_max_pd(y, ax));
                // Selects by sign bit: y > ax; num > (sqrt 2 - 1) den; x < 0 (or -0).
                let swap = _mm256_sub_pd(ax, y);
                let reduce = _mm256_sub_pd(_mm256_mul_pd(pd(SQRT_2 - 1.0), den), num);
                let top = _mm256_blendv_pd(num, _mm256_sub_pd(num, den), reduce);
                let bottom = _mm256_blendv_pd(den, _mm256_add_pd(den, num), reduce);
                let u = _mm256_div_pd(top, bottom);
                let v = _mm256_mul_pd(u, u);
                let mut poly = pd(0.0);
                for &k in ATAN_COEFFICIENTS.iter().rev() {
                    poly = _mm256_add_pd(_mm256_mul_pd(poly, v), pd(k));
                }
                let r = _mm256_add_pd(u, _mm256_mul_pd(_mm256_mul_pd(u, v), poly));
                let r = _mm256_add_pd(r, _mm256_blendv_pd(pd(0.0), pd(FRAC_PI_4), reduce));
                let r = _mm256_blendv_pd(r, _mm256_sub_pd(pd(FRAC_PI_2), r), swap);
                let r = _mm256_blendv_pd(r, _mm256_sub_pd(pd(PI), r), x);
                // Both terms zero (a zero vector): 0.
                let zero =
                    _mm256_and_pd(_mm256_cmp_pd::<_CMP_EQ_OQ>(y, pd(0.0)), _mm256_cmp_pd::<_CMP_EQ_OQ>(x, pd(0.0)));
                let r = _mm256_blendv_pd(r, pd(0.0), zero);
                _mm_storeu_ps(out.as_mut_ptr().add(i), _mm256_cvtpd_ps(r));
            }
        }
        full
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// [`atan2_upper`] written with plain `if`s: the selects its factors stand for.
    fn with_ifs(y: f32, x: f32) -> f32 {
        use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI, SQRT_2};
        let (y64, ax) = (f64::from(y), f64::from(x).abs());
        let swap = y64 > ax;
        let (num, den) = if swap { (ax, y64) } else { (y64, ax) };
        let reduce = num > (SQRT_2 - 1.0) * den;
        let u = if reduce { (num - den) / (num + den) } else { num / den };
        let v = u * u;
        let poly = ATAN_COEFFICIENTS.iter().rev().fold(0.0, |acc, &c| acc * v + c);
        let mut r = u + u * v * poly + if reduce { FRAC_PI_4 } else { 0.0 };
        if swap {
            r = FRAC_PI_2 - r;
        }
        (if x < 0.0 { PI - r } else { r }) as f32
    }

    /// Against the f64 library `atan2` rounded once to f32: within one f32 step everywhere, and equal but for
    /// a handful of values within rounding distance of a boundary; the axes, zeros and NaN as `atan2`.
    #[test]
    fn atan2_upper_is_the_rounded_angle() {
        let mut rng = Rng::new(12);
        let mut differ = 0;
        let n = 400_000;
        for i in 0..n {
            let scale = 10f64.powf(rng.uniform(-6.0, 3.0));
            // Half the cases near an axis or a diagonal, where the reduction switches branch.
            let (y, x) = match i % 4 {
                0 => (rng.uniform(0.0, 1.0) * scale, rng.uniform(-1.0, 1.0) * scale),
                1 => (scale, scale * (1.0 + rng.uniform(-1e-3, 1e-3)) * if i % 8 == 1 { 1.0 } else { -1.0 }),
                2 => (scale * rng.uniform(0.0, 1e-4), rng.uniform(-1.0, 1.0) * scale),
                _ => (scale * (std::f64::consts::FRAC_PI_8.tan() + rng.uniform(-1e-4, 1e-4)), scale),
            };
            let (y, x) = (y as f32, x as f32);
            let want = f64::from(y).atan2(f64::from(x)) as f32;
            let got = atan2_upper(y, x);
            assert_eq!(got.to_bits(), with_ifs(y, x).to_bits(), "{y} {x}");
            assert!((got - want).abs() <= f32::EPSILON * want.abs().max(f32::MIN_POSITIVE), "{y} {x}: {got} {want}");
            differ += usize::from(got != want);
        }
        assert!(differ * 10_000 < n, "{differ} of {n} differ");
        let pi = std::f32::consts::PI;
        for (y, x, want) in
            [(0.0, 1.0, 0.0), (0.0, -1.0, pi), (1.0, 0.0, pi / 2.0), (1.0, -0.0, pi / 2.0), (2.0, 2.0, pi / 4.0)]
        {
            assert_eq!(atan2_upper(y, x), want, "{y} {x}");
        }
        assert!(atan2_upper(f32::NAN, 1.0).is_nan() && atan2_upper(1.0, f32::NAN).is_nan());
    }

    /// The batch (four lanes at a time where the CPU has AVX2) gives every angle bit for bit as one at a time:
    /// random terms of both signs and all sizes, zero pairs, exact axes and NaN, at lengths that leave a tail.
    #[test]
    fn angles_in_a_batch_are_the_angles_one_by_one() {
        let mut rng = Rng::new(14);
        for len in [0, 3, 4, 7, 64, 1001] {
            let mut s: Vec<f32> =
                (0..len).map(|_| (rng.uniform(0.0, 1.0) * 10f64.powf(rng.uniform(-5.0, 2.0))) as f32).collect();
            let mut c: Vec<f32> =
                (0..len).map(|_| (rng.uniform(-1.0, 1.0) * 10f64.powf(rng.uniform(-5.0, 2.0))) as f32).collect();
            for (i, (s, c)) in s.iter_mut().zip(c.iter_mut()).enumerate() {
                match i % 11 {
                    0 => (*s, *c) = (0.0, 0.0),
                    1 => (*s, *c) = (0.0, -0.0),
                    2 => *s = 0.0,
                    3 => *c = 0.0,
                    4 => *c = -0.0,
                    5 => *c = *s,
                    6 if i % 3 == 0 => *s = f32::NAN,
                    _ => {}
                }
            }
            let mut batch = vec![0.0; len];
            angles_of(&s, &c, &mut batch);
            for i in 0..len {
                let one = angle_of(s[i], c[i]);
                assert!(batch[i].to_bits() == one.to_bits() || (batch[i].is_nan() && one.is_nan()), "{i}: {s:?}");
            }
        }
    }

    /// Every row is its point's own features, in its patch's frame (the oracle: [`point_features`] and
    /// [`apply_frame`] of [`normal_frame`] one point at a time), for whole and partial patches.
    #[test]
    fn each_row_is_its_points_features_in_its_patchs_frame() {
        let mut rng = Rng::new(3);
        let mut v = || [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32);
        for ((patches, n), frame) in
            [(4, 5), (3, 37)].into_iter().flat_map(|s| [(s, PoseFrame::Fragment), (s, PoseFrame::Normal)])
        {
            let centers: Vec<[f32; 3]> = (0..patches).map(|_| v()).collect();
            let center_normals: Vec<[f32; 3]> = (0..patches).map(|_| v()).collect();
            let rows = patches * n - 2;
            let mut points: Vec<[f32; 3]> = (0..rows).map(|_| v()).collect();
            let mut normals: Vec<[f32; 3]> = (0..rows).map(|_| v()).collect();
            // Degenerate rows: a point on its keypoint, a zero normal, a normal along the offset.
            points[1] = centers[0];
            normals[2] = [0.0; 3];
            normals[3] = [centers[0][0] - points[3][0], centers[0][1] - points[3][1], centers[0][2] - points[3][2]];
            let (ppf, pc) = patch_features(&centers, &center_normals, &points, &normals, n, 0.7, frame);
            assert_eq!((ppf.len(), pc.len()), (rows * 4, rows * 3));
            for i in 0..rows {
                let p = i / n;
                let (f, c) = point_features(centers[p], center_normals[p], points[i], normals[i], 0.7);
                let c = if frame == PoseFrame::Normal { apply_frame(&normal_frame(center_normals[p]), c) } else { c };
                assert_eq!(ppf[i * 4..][..4], f, "row {i}, {frame:?}");
                assert_eq!(pc[i * 3..][..3], c, "row {i}, {frame:?}");
            }
        }
    }
}
