//! RelativeNet on the CPU reference path: a 4-layer MLP on [source pose feature | target pose feature]
//! (pose feature = PC codeword - PPF codeword) that regresses target_from_source as a unit quaternion.

use super::foldnet::{Slice, apply, apply_concat};
use super::linear::Linear;
use super::params::relative_layers;
use super::weights::Weights;
use crate::error::Result;

/// RelativeNet's layers.
#[derive(Clone, Debug)]
pub struct RelativeNet {
    /// Hidden layers (ReLU) and the final 4-wide layer (linear).
    pub layers: Vec<Linear>,
}

/// Below this norm a raw quaternion is treated as degenerate and mapped to the identity.
pub const MIN_QUATERNION_NORM: f32 = 1e-12;

/// Normalises a raw network output `[w, x, y, z]` to a unit quaternion (identity when degenerate).
pub fn normalize_quaternion(q: [f32; 4]) -> [f32; 4] {
    let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    if n.is_nan() || n <= MIN_QUATERNION_NORM {
        return [1.0, 0.0, 0.0, 0.0];
    }
    q.map(|v| v / n)
}

impl RelativeNet {
    /// Builds the network from checked weights.
    pub fn from_weights(weights: &Weights) -> Result<RelativeNet> {
        let layers =
            relative_layers(&weights.config).iter().map(|s| Linear::from_weights(weights, s)).collect::<Result<_>>()?;
        Ok(RelativeNet { layers })
    }

    /// Raw (unnormalised) outputs for `rows` pairs; `source` and `target` are `rows x feature` row-major.
    pub fn forward_raw(&self, source: &[f32], target: &[f32], rows: usize) -> Vec<f32> {
        if rows == 0 {
            return Vec::new();
        }
        let f = self.layers[0].in_dim / 2;
        // [source | target]: source as the first segment carrying the bias, target accumulated.
        let segs: [Slice<'_>; 2] = [(source, f, 0), (target, f, f)];
        let zero_group = vec![0.0; 0];
        let mut h = apply_concat(&self.layers[0], (&zero_group, 0, 0), &segs, rows, rows, self.layers.len() > 1);
        for (i, layer) in self.layers.iter().enumerate().skip(1) {
            h = apply(layer, &h, rows, i + 1 < self.layers.len());
        }
        h
    }

    /// Unit quaternions `[w, x, y, z]` (target_from_source) for `rows` pairs.
    pub fn predict(&self, source: &[f32], target: &[f32], rows: usize) -> Vec<[f32; 4]> {
        self.forward_raw(source, target, rows)
            .chunks_exact(4)
            .map(|q| normalize_quaternion([q[0], q[1], q[2], q[3]]))
            .collect()
    }
}
