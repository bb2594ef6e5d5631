//! RelativeNet on the CPU reference path: a 4-layer MLP on [source pose feature | target pose feature]
//! (pose feature = PC codeword - PPF codeword, [`super::pose_feature`]) whose raw output `rotation_head` turns
//! into the rotation target_from_source.

use super::config::ModelConfig;
use super::foldnet::{Slice, apply, apply_concat};
use super::linear::Linear;
use super::params::relative_layers;
use super::weights::WeightsView;
use crate::cpu::rotation_head::rotation_head;
use crate::error::Result;

/// RelativeNet's layers.
#[derive(Clone, Debug)]
pub struct RelativeNet {
    /// Hidden layers (ReLU) and the final linear layer (4 or 6 wide, the rotation output).
    pub layers: Vec<Linear>,
}

impl RelativeNet {
    /// Builds the network from checked weights.
    pub fn from_weights(weights: &WeightsView<'_>) -> Result<RelativeNet> {
        let layers =
            relative_layers(&weights.config).iter().map(|s| Linear::from_weights(weights, s)).collect::<Result<_>>()?;
        Ok(RelativeNet { layers })
    }

    /// The forward pass, the one definition inference and training share: every layer's output for `rows`
    /// pairs (`source` and `target` are `rows x feature` row-major); the last is the raw rotation output.
    pub fn forward_tape(&self, source: &[f32], target: &[f32], rows: usize) -> Vec<Vec<f32>> {
        if rows == 0 {
            return Vec::new();
        }
        let f = self.layers[0].in_dim / 2;
        // [source | target]: source as the first segment carrying the bias, target accumulated.
        let segs: [Slice<'_>; 2] = [(source, f, 0), (target, f, f)];
        let n = self.layers.len();
        let mut outs: Vec<Vec<f32>> = Vec::with_capacity(n);
        outs.push(apply_concat(&self.layers[0], (&[], 0, 0), &segs, rows, rows, n > 1));
        for (i, layer) in self.layers.iter().enumerate().skip(1) {
            let h = apply(layer, outs.last().expect("one relative output"), rows, i + 1 < n);
            outs.push(h);
        }
        outs
    }

    /// Raw outputs (`rows x 4` or `rows x 6`).
    pub fn forward_raw(&self, source: &[f32], target: &[f32], rows: usize) -> Vec<f32> {
        self.forward_tape(source, target, rows).pop().unwrap_or_default()
    }

    /// Rotations target_from_source (row-major, fragment frames) for `rows` correspondences, given the pose
    /// features and the keypoint normals of each correspondence's patches.
    pub fn predict(
        &self,
        config: &ModelConfig,
        source: &[f32],
        target: &[f32],
        source_normals: &[[f32; 3]],
        target_normals: &[[f32; 3]],
        rows: usize,
    ) -> Vec<[f32; 9]> {
        let raw = self.forward_raw(source, target, rows);
        rotation_head(&raw, config.rotation_output, config.pose_frame, source_normals, target_normals)
    }
}
