//! The parameter table: every tensor's name and shape for a `ModelConfig`. The single source of truth for
//! loading, saving, initialising and training.
//!
//! Names: `{ppf,pc}.encoder.{i}`, `{ppf,pc}.head.{i}`, `{ppf,pc}.fold1.{i}`, `{ppf,pc}.fold2.{i}`,
//! `relative.{i}`, each with `.weight` (`[out, in]`, the PyTorch convention) and `.bias` (`[out]`).

use super::config::ModelConfig;

/// Which auto-encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Net {
    /// PPF-FoldNet: 4-D point pair features in and out, rotation invariant.
    Ppf,
    /// PC-FoldNet: centred 3-D points in and out, pose variant.
    Pc,
}

impl Net {
    /// Name prefix of this network's tensors.
    pub fn prefix(self) -> &'static str {
        match self {
            Net::Ppf => "ppf",
            Net::Pc => "pc",
        }
    }

    /// Per-point input (and reconstruction) width.
    pub fn io_width(self) -> usize {
        match self {
            Net::Ppf => 4,
            Net::Pc => 3,
        }
    }
}

/// One linear layer's name and sizes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LayerSpec {
    /// Name prefix, e.g. "ppf.head.0"; tensors are `{name}.weight` and `{name}.bias`.
    pub name: String,
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
}

fn chain(name: &str, in_dim: usize, widths: &[usize], out: &mut Vec<LayerSpec>) {
    let mut prev = in_dim;
    for (i, &w) in widths.iter().enumerate() {
        out.push(LayerSpec { name: format!("{name}.{i}"), in_dim: prev, out_dim: w });
        prev = w;
    }
}

/// `net`'s per-point widths before the first max-pool (`config.pc_widths` for PC-FoldNet where set).
pub fn encoder_widths(config: &ModelConfig, net: Net) -> &[usize] {
    match (net, &config.pc_widths) {
        (Net::Pc, Some(w)) => &w.encoder,
        _ => &config.encoder_widths,
    }
}

/// `net`'s per-point widths after the skip concatenation.
pub fn head_widths(config: &ModelConfig, net: Net) -> &[usize] {
    match (net, &config.pc_widths) {
        (Net::Pc, Some(w)) => &w.head,
        _ => &config.head_widths,
    }
}

/// Width of `net`'s skip concatenation [encoder outputs | global max-pool].
pub fn concat_width(config: &ModelConfig, net: Net) -> usize {
    let widths = encoder_widths(config, net);
    widths.iter().sum::<usize>() + widths.last().copied().unwrap_or(0)
}

/// The layers of one FoldNet (encoder, head, fold1, fold2) in forward order.
pub fn foldnet_layers(config: &ModelConfig, net: Net) -> Vec<LayerSpec> {
    let p = net.prefix();
    let d = net.io_width();
    let codeword = config.codeword();
    let mut out = Vec::new();
    chain(&format!("{p}.encoder"), d, encoder_widths(config, net), &mut out);
    chain(&format!("{p}.head"), concat_width(config, net), head_widths(config, net), &mut out);
    let fold: Vec<usize> = config.fold_widths.iter().copied().chain([d]).collect();
    chain(&format!("{p}.fold1"), codeword + 2, &fold, &mut out);
    chain(&format!("{p}.fold2"), codeword + d, &fold, &mut out);
    out
}

/// RelativeNet's layers: 2 x codeword -> relative_widths -> the rotation output (4 or 6).
pub fn relative_layers(config: &ModelConfig) -> Vec<LayerSpec> {
    let widths: Vec<usize> = config.relative_widths.iter().copied().chain([config.rotation_output.width()]).collect();
    let mut out = Vec::new();
    chain("relative", 2 * config.codeword(), &widths, &mut out);
    out
}

/// Every layer of the model.
pub fn all_layers(config: &ModelConfig) -> Vec<LayerSpec> {
    let mut out = foldnet_layers(config, Net::Ppf);
    out.extend(foldnet_layers(config, Net::Pc));
    out.extend(relative_layers(config));
    out
}

/// Every tensor `(name, shape)` in a stable order.
pub fn tensor_specs(config: &ModelConfig) -> Vec<(String, Vec<usize>)> {
    all_layers(config)
        .into_iter()
        .flat_map(|l| {
            [(format!("{}.weight", l.name), vec![l.out_dim, l.in_dim]), (format!("{}.bias", l.name), vec![l.out_dim])]
        })
        .collect()
}
