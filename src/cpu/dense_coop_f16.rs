//! CPU twin of `shaders/dense_coop_f16.wgsl`: the dense layer with the tensor-core precision model, f16 inputs
//! and f32 accumulation,
//!
//! `out[r, o] = act( ((accumulate ? out[r, o] : 0) + group_term[r / rows_per_group, o]) + P[r, o] )`,
//! `P[r, o] = sum_k f16(x[r, k]) * f16(w_t[k, o])`, summed in f32 from zero in increasing k,
//!
//! where `f16(v)` rounds to the nearest f16 (ties to even; beyond the f16 range, +-inf). The products of two
//! f16 values are exact in f32, so the only roundings are the input conversions and the f32 additions.
//!
//! Error model ([`error_bounds`]): with unit roundoff `u16 = 2^-11`, a conversion to nearest gives
//! `|f16(a) - a| <= u16 |a| + 2^-25` (relative in the normal range, half the subnormal quantum below it), so each
//! product is off by at most `(2 u16 + u16^2) |a||b| + (1 + u16) 2^-25 (|a| + |b|) + 2^-50`; the f32 sum of the
//! `n = k + 2` terms (start value, group term, products) adds at most `gamma_n * sum |terms|`
//! ([`super::dense::gamma_f32`]). A GPU's conversion need only be faithful (WGSL lets `f16(v)` round either
//! way), which doubles both conversion terms, and a tensor core may align and truncate instead of rounding while
//! it accumulates, which at most doubles the summation term: [`Conversion::Gpu`].

use super::dense::{DenseShape, gamma_f32};

/// Unit roundoff of f16: half the distance from 1 to the next f16.
pub const F16_UNIT_ROUNDOFF: f64 = 1.0 / 2048.0;

/// Half the spacing of f16 subnormals (2^-24): the largest absolute error of rounding a value below the normal
/// range to nearest.
pub const F16_SUBNORMAL_HALF_QUANTUM: f64 = 1.0 / 33_554_432.0;

/// The largest finite f16.
pub const F16_MAX: f32 = 65504.0;

/// `v` rounded to the nearest f16 value (ties to even), returned as the f32 that holds it exactly: the f16 grid
/// has 11 significant bits down to 2^-14 and the fixed spacing 2^-24 below; values from 65520 up round to
/// infinity. NaN and infinities pass through.
pub fn round_to_f16(v: f32) -> f32 {
    if !v.is_finite() {
        return v;
    }
    let a = v.abs();
    if a >= 65520.0 {
        return f32::INFINITY.copysign(v);
    }
    // Exponent of the f16 spacing: 2^(e - 10) for a in [2^e, 2^(e+1)), e >= -14; 2^-24 below 2^-14.
    let e = if a < 2f32.powi(-14) { -14 } else { ((a.to_bits() >> 23) & 0xff) as i32 - 127 };
    let quantum = f32::from_bits(((e - 10 + 127) as u32) << 23);
    // a / quantum and the product below are exact (power-of-two scaling within the f32 range).
    ((a / quantum).round_ties_even() * quantum).copysign(v)
}

/// Runs the layer with the precision model above. Shapes as [`super::dense::dense`].
pub fn dense_coop_f16(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    let DenseShape { rows, in_dim, out_dim, rows_per_group, accumulate, relu } = *shape;
    debug_assert_eq!(x.len(), rows * in_dim);
    debug_assert_eq!(w_t.len(), in_dim * out_dim);
    debug_assert_eq!(out.len(), rows * out_dim);
    let x16: Vec<f32> = x.iter().copied().map(round_to_f16).collect();
    let w16: Vec<f32> = w_t.iter().copied().map(round_to_f16).collect();
    let mut products = vec![0f32; out_dim];
    for r in 0..rows {
        products.fill(0.0);
        for k in 0..in_dim {
            let xv = x16[r * in_dim + k];
            for (p, &wv) in products.iter_mut().zip(&w16[k * out_dim..(k + 1) * out_dim]) {
                *p += xv * wv;
            }
        }
        for (o, &p) in products.iter().enumerate() {
            let i = r * out_dim + o;
            let mut v = if accumulate { out[i] } else { 0.0 };
            if !group_term.is_empty() {
                v += group_term[(r / rows_per_group.max(1)) * out_dim + o];
            }
            v += p;
            out[i] = if relu { v.max(0.0) } else { v };
        }
    }
}

/// Who rounded: the twin (conversions to nearest, sequential f32 sums) or a GPU (conversions only faithful,
/// tensor-core accumulation that may truncate).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Conversion {
    /// [`dense_coop_f16`] itself.
    Twin,
    /// `shaders/dense_coop_f16.wgsl` on a GPU.
    Gpu,
}

/// Per output element, a bound on `|computed - exact|` where `exact` is the layer in real arithmetic on the f32
/// inputs (before the ReLU, which only shrinks differences), for the rounding of `who` (module docs). `init` is
/// the output's initial contents (read when accumulating). Valid while every input is within the f16 range.
pub fn error_bounds(
    shape: &DenseShape,
    x: &[f32],
    w_t: &[f32],
    group_term: &[f32],
    init: &[f32],
    who: Conversion,
) -> Vec<f64> {
    let (rho, eta, sum_factor) = match who {
        Conversion::Twin => (F16_UNIT_ROUNDOFF, F16_SUBNORMAL_HALF_QUANTUM, 1.0),
        Conversion::Gpu => (2.0 * F16_UNIT_ROUNDOFF, 2.0 * F16_SUBNORMAL_HALF_QUANTUM, 2.0),
    };
    let gamma = sum_factor * gamma_f32(shape.in_dim + 2);
    (0..shape.rows * shape.out_dim)
        .map(|i| {
            let (r, o) = (i / shape.out_dim, i % shape.out_dim);
            let mut conversion = 0.0;
            let mut terms = if shape.accumulate { f64::from(init[i].abs()) } else { 0.0 };
            if !group_term.is_empty() {
                terms += f64::from(group_term[(r / shape.rows_per_group.max(1)) * shape.out_dim + o].abs());
            }
            for k in 0..shape.in_dim {
                let a = f64::from(x[r * shape.in_dim + k].abs());
                let b = f64::from(w_t[k * shape.out_dim + o].abs());
                let e = (2.0 * rho + rho * rho) * a * b + (1.0 + rho) * eta * (a + b) + eta * eta;
                conversion += e;
                terms += a * b + e;
            }
            conversion + gamma * terms
        })
        .collect()
}

/// The parity tolerance of the GPU kernel against the twin, per element: `|gpu - twin| <= |gpu - exact| +
/// |exact - twin|`, the sum of the [`Conversion::Gpu`] and [`Conversion::Twin`] bounds, as f32 (rounded up).
pub fn parity_tolerance(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], init: &[f32]) -> Vec<f32> {
    let gpu = error_bounds(shape, x, w_t, group_term, init, Conversion::Gpu);
    let twin = error_bounds(shape, x, w_t, group_term, init, Conversion::Twin);
    gpu.iter().zip(&twin).map(|(g, t)| ((g + t) * (1.0 + f64::from(f32::EPSILON))) as f32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Decodes f16 bits (the oracle for [`round_to_f16`]; written from the IEEE 754 binary16 layout).
    fn f16_value(bits: u16) -> f64 {
        let sign = if bits & 0x8000 != 0 { -1.0 } else { 1.0 };
        let exp = i32::from((bits >> 10) & 0x1f);
        let frac = f64::from(bits & 0x3ff);
        match exp {
            0 => sign * frac * 2f64.powi(-24),
            31 if frac == 0.0 => sign * f64::INFINITY,
            31 => f64::NAN,
            _ => sign * (1.0 + frac / 1024.0) * 2f64.powi(exp - 15),
        }
    }

    #[test]
    fn round_to_f16_is_round_to_nearest_even_on_every_f16_interval() {
        // Every finite positive f16 h (bits b) and its successor: h itself and the points around the midpoint.
        for b in 0u16..0x7bff {
            let (lo, hi) = (f16_value(b), f16_value(b + 1));
            assert_eq!(f64::from(round_to_f16(lo as f32)), lo, "f16 {b:#x} is exact");
            assert_eq!(f64::from(round_to_f16(-lo as f32)), -lo, "-f16 {b:#x} is exact");
            let mid = ((lo + hi) / 2.0) as f32;
            assert_eq!(f64::from(mid), (lo + hi) / 2.0, "midpoints are f32 values");
            let even = if b % 2 == 0 { lo } else { hi };
            assert_eq!(f64::from(round_to_f16(mid)), even, "tie at {mid:e} goes to the even neighbour");
            assert_eq!(f64::from(round_to_f16(f32::from_bits(mid.to_bits() - 1))), lo, "below the tie");
            assert_eq!(f64::from(round_to_f16(f32::from_bits(mid.to_bits() + 1))), hi, "above the tie");
        }
        assert_eq!(round_to_f16(F16_MAX), F16_MAX);
        assert_eq!(round_to_f16(65519.99), F16_MAX);
        assert_eq!(round_to_f16(65520.0), f32::INFINITY);
        assert_eq!(round_to_f16(-1e6), f32::NEG_INFINITY);
        assert_eq!(round_to_f16(1e-9), 0.0);
        assert!(round_to_f16(f32::NAN).is_nan());
    }

    /// The layer in f64 on the f32 inputs: the exact value up to f64 rounding (far below the bounds).
    fn exact(s: &DenseShape, x: &[f32], w: &[f32], g: &[f32], init: &[f32]) -> Vec<f64> {
        (0..s.rows * s.out_dim)
            .map(|i| {
                let (r, o) = (i / s.out_dim, i % s.out_dim);
                let mut v = if s.accumulate { f64::from(init[i]) } else { 0.0 };
                if !g.is_empty() {
                    v += f64::from(g[(r / s.rows_per_group) * s.out_dim + o]);
                }
                for k in 0..s.in_dim {
                    v += f64::from(x[r * s.in_dim + k]) * f64::from(w[k * s.out_dim + o]);
                }
                if s.relu { v.max(0.0) } else { v }
            })
            .collect()
    }

    #[test]
    fn twin_is_within_its_derived_bound_of_the_exact_layer_and_the_bound_is_tight_enough_to_matter() {
        let mut rng = Rng::new(17);
        let (mut worst_ratio, mut beyond_f32_bound) = (0.0f64, 0usize);
        for &(rows, in_dim, out_dim, rpg, accumulate, relu) in &[
            (7, 3, 5, 7, false, true),
            (13, 70, 130, 4, true, false),
            (33, 257, 17, 33, true, true),
            (1, 1, 1, 1, false, false),
            (5, 512, 9, 1, false, false),
        ] {
            let s = DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu };
            let mut v = |n: usize, scale: f64| (0..n).map(|_| (rng.normal() * scale) as f32).collect::<Vec<f32>>();
            // Inputs spanning the f16 subnormal range (1e-6) to large values (100), within the f16 range.
            let x: Vec<f32> =
                v(rows * in_dim, 1.0).iter().enumerate().map(|(i, a)| a * [1e-6, 1.0, 100.0][i % 3]).collect();
            let w = v(in_dim * out_dim, 0.5);
            let g = v(rows.div_ceil(rpg) * out_dim, 1.0);
            let init = v(rows * out_dim, 1.0);
            let mut got = init.clone();
            dense_coop_f16(&s, &x, &w, &g, &mut got);
            let want = exact(&s, &x, &w, &g, &init);
            let bound = error_bounds(&s, &x, &w, &g, &init, Conversion::Twin);
            let gamma = gamma_f32(in_dim + 2);
            for i in 0..got.len() {
                let err = (f64::from(got[i]) - want[i]).abs();
                assert!(
                    err <= bound[i],
                    "{s:?} element {i}: twin {} vs exact {} (error {err:e} > bound {:e})",
                    got[i],
                    want[i],
                    bound[i]
                );
                worst_ratio = worst_ratio.max(err / bound[i]);
                // The f32 reference's own bound: elements the f16 inputs put beyond it show the model is not f32.
                let (r, o) = (i / out_dim, i % out_dim);
                let f32_scale: f64 =
                    (0..in_dim).map(|k| f64::from((x[r * in_dim + k] * w[k * out_dim + o]).abs())).sum();
                if err > 2.0 * gamma * (f32_scale + 1.0) {
                    beyond_f32_bound += 1;
                }
            }
        }
        assert!(worst_ratio > 1e-3, "the bound is not vacuous: worst error / bound = {worst_ratio}");
        assert!(beyond_f32_bound > 100, "f16 rounding shows beyond the f32 bound ({beyond_f32_bound} elements)");
    }

    #[test]
    fn gpu_parity_tolerance_covers_any_faithful_conversion() {
        // A GPU that rounds every conversion the other way (the worst a faithful conversion may do) and sums in
        // f64 stays within the parity tolerance of the twin.
        let mut rng = Rng::new(29);
        let s = DenseShape { rows: 9, in_dim: 100, out_dim: 11, rows_per_group: 3, accumulate: true, relu: false };
        let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
        let (x, w, g, init) = (v(s.rows * s.in_dim), v(s.in_dim * s.out_dim), v(3 * s.out_dim), v(s.rows * s.out_dim));
        // The f16 neighbour of `a` on the other side from its nearest one (spacing of a's binade).
        let away = |a: f32| {
            let (a, n) = (f64::from(a), f64::from(round_to_f16(a)));
            let step = 2f64.powi((a.abs().max(2f64.powi(-14))).log2().floor() as i32 - 10);
            if n == a {
                n
            } else if n > a {
                n - step
            } else {
                n + step
            }
        };
        let mut twin = init.clone();
        dense_coop_f16(&s, &x, &w, &g, &mut twin);
        let tol = parity_tolerance(&s, &x, &w, &g, &init);
        for i in 0..twin.len() {
            let (r, o) = (i / s.out_dim, i % s.out_dim);
            let mut v = f64::from(init[i]) + f64::from(g[(r / 3) * s.out_dim + o]);
            for k in 0..s.in_dim {
                v += away(x[r * s.in_dim + k]) * away(w[k * s.out_dim + o]);
            }
            assert!((v - f64::from(twin[i])).abs() <= f64::from(tol[i]), "element {i}: {v} vs {}", twin[i]);
        }
    }
}
