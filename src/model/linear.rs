//! A linear layer's parameters in the layout the CPU twin wants (transposed weight).

use super::params::LayerSpec;
use super::weights::WeightsView;
use crate::cpu::gemm_bf16::{Bf16Unit, pack_weight};
use crate::cpu::gemm_int8::{Int8Weight, quantize_weight};
use crate::error::Result;
use std::sync::OnceLock;

/// Weight stored transposed (`in_dim x out_dim`) so the CPU dense kernel streams rows of it.
#[derive(Clone, Debug)]
pub struct Linear {
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// `weight_t[k * out_dim + o] = weight[o][k]`.
    pub weight_t: Vec<f32>,
    /// Bias, `out_dim`.
    pub bias: Vec<f32>,
    /// `weight_t` packed for the bf16 layer, built on first use ([`Linear::packed_bf16`]). A `Linear` is not
    /// changed after it is built (training builds new ones from its parameters).
    packed_bf16: OnceLock<Vec<u32>>,
    /// Rows `0..in_dim` of `weight_t` (or the fewer rows the first int8 use asked for) quantized for the
    /// int8 layer, built on first use ([`Linear::quantized_int8`]).
    quantized_int8: OnceLock<Int8Weight>,
    /// The unit its bf16 multiplies run on: AMX tiles where the CPU has them (inference and training; 2.5-3x
    /// the encoders' speed on the vector unit, docs/speed.md), else the vector unit
    /// ([`crate::model::Model::with_bf16_unit`] picks one).
    bf16_unit: Bf16Unit,
}

impl Linear {
    /// Reads `{spec.name}.weight` and `.bias` from `weights`.
    pub fn from_weights(weights: &WeightsView<'_>, spec: &LayerSpec) -> Result<Linear> {
        let w = weights.get(&format!("{}.weight", spec.name))?;
        let b = weights.get(&format!("{}.bias", spec.name))?;
        let (i_n, o_n) = (spec.in_dim, spec.out_dim);
        let weight_t = crate::cpu::transpose::transpose(w, o_n, i_n);
        let packed_bf16 = OnceLock::new();
        Ok(Linear {
            in_dim: i_n,
            out_dim: o_n,
            weight_t,
            bias: b.to_vec(),
            packed_bf16,
            quantized_int8: OnceLock::new(),
            bf16_unit: Bf16Unit::Tiles,
        })
    }

    /// The transposed weight as bf16 pairs of rows (`crate::cpu::gemm_bf16::pack_weight`), packed once.
    pub fn packed_bf16(&self) -> &[u32] {
        self.packed_bf16.get_or_init(|| pack_weight(&self.weight_t, self.in_dim, self.out_dim))
    }

    /// Rows `0..rows` of the transposed weight quantized for the int8 layer (a scale per output column over
    /// those rows), built once; `None` when it was built for another row count (the caller then takes bf16).
    pub fn quantized_int8(&self, rows: usize) -> Option<&Int8Weight> {
        let q =
            self.quantized_int8.get_or_init(|| quantize_weight(&self.weight_t, rows.min(self.in_dim), self.out_dim));
        (q.k == rows).then_some(q)
    }

    /// The unit its bf16 multiplies run on.
    pub fn bf16_unit(&self) -> Bf16Unit {
        self.bf16_unit
    }

    /// Runs its bf16 multiplies on `unit`.
    pub fn set_bf16_unit(&mut self, unit: Bf16Unit) {
        self.bf16_unit = unit;
    }

    /// Rows `from..from + count` of the transposed weight: the block that multiplies one slice of a
    /// concatenated input.
    pub fn weight_t_rows(&self, from: usize, count: usize) -> &[f32] {
        &self.weight_t[from * self.out_dim..(from + count) * self.out_dim]
    }
}
