//! The networks: configuration, parameter table, weights files, and the CPU reference forward passes.

pub mod config;
pub mod foldnet;
pub mod linear;
pub mod params;
pub mod prune;
pub mod relativenet;
pub mod weights;

pub use config::ModelConfig;
pub use foldnet::FoldNet;
pub use params::Net;
pub use relativenet::RelativeNet;
pub use weights::{Weights, WeightsView};

use crate::error::Result;

/// Both auto-encoders and RelativeNet, ready for the CPU forward pass.
#[derive(Clone, Debug)]
pub struct Model {
    /// The sizes.
    pub config: ModelConfig,
    /// PPF-FoldNet (rotation-invariant codewords).
    pub ppf: FoldNet,
    /// PC-FoldNet (pose-variant codewords).
    pub pc: FoldNet,
    /// The relative-pose regressor.
    pub relative: RelativeNet,
}

/// The pose-variant feature RelativeNet reads (paper, section 3.2): PC codeword minus PPF codeword, row by row.
pub fn pose_feature(pc_codewords: &[f32], ppf_codewords: &[f32]) -> Vec<f32> {
    pc_codewords.iter().zip(ppf_codewords).map(|(pc, ppf)| pc - ppf).collect()
}

impl Model {
    /// Builds the model from checked weights.
    pub fn from_weights(weights: &Weights) -> Result<Model> {
        Model::from_view(&weights.view())
    }

    /// [`Model::from_weights`] from a view of checked weights (the built-in weights read in place,
    /// [`Weights::built_in_view`]).
    pub fn from_view(weights: &WeightsView<'_>) -> Result<Model> {
        Ok(Model {
            config: weights.config.clone(),
            ppf: FoldNet::from_weights(weights, Net::Ppf)?,
            pc: FoldNet::from_weights(weights, Net::Pc)?,
            relative: RelativeNet::from_weights(weights)?,
        })
    }

    /// The model with every layer's bf16 multiplies on `unit` (built on AMX tiles, which fall back to the vector
    /// unit where the CPU has none). Changes nothing in f32.
    pub fn with_bf16_unit(mut self, unit: crate::cpu::gemm_bf16::Bf16Unit) -> Model {
        let nets = [&mut self.ppf, &mut self.pc];
        let fold_layers = nets.into_iter().flat_map(|f| [&mut f.encoder, &mut f.head, &mut f.fold1, &mut f.fold2]);
        for layers in fold_layers.chain([&mut self.relative.layers]) {
            layers.iter_mut().for_each(|l| l.set_bf16_unit(unit));
        }
        self
    }
}
