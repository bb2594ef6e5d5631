//! Pruning dead channels: the per-point channels of a trained FoldNet that never fire (a ReLU output that stays
//! 0 on every calibration patch) are removed with the weight rows and columns that touch them. A channel that
//! is 0 contributes nothing to the next layer, the skip concatenation or the max-pool, so on every patch where
//! the removed channels stay dead the pruned network computes the same codewords as the whole one with less
//! arithmetic. ReLU training leaves many such channels: the shipped PPF-FoldNet fires 132 of its 512 head
//! channels on real and synthetic scans alike (docs/experiments/dead-channels.md).
//!
//! Every encoder and head layer is pruned. The codeword is shared: PC-FoldNet's minus PPF-FoldNet's is
//! RelativeNet's input, and both feed their folding decoders, so a codeword channel goes only when it is dead in
//! both networks, with its columns in RelativeNet's first layer and in the decoders' first layers (the shipped
//! PPF-FoldNet's codewords use 84 of their 512 channels, PC-FoldNet's 193). `dpr-gpu prune` runs this on
//! training patches and random patches of the whole input domain.

use super::config::NetWidths;
use super::foldnet::{EncodeTape, FoldNet};
use super::params::{Net, concat_width, encoder_widths, foldnet_layers, head_widths, relative_layers};
use super::weights::Weights;
use crate::error::{Error, Result};
use crate::rng::Rng;
use rayon::prelude::*;

/// Which per-point channels of one FoldNet fired on the calibration patches: one flag per channel of each
/// encoder layer, then of each head layer (the last one's are the codeword's channels).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Firing {
    /// `encoder[i][c]`: channel `c` of encoder layer `i` was positive on some point.
    pub encoder: Vec<Vec<bool>>,
    /// `head[j][c]` for every head layer.
    pub head: Vec<Vec<bool>>,
}

impl Firing {
    /// No channel fired yet, for `net`'s widths.
    pub fn none(config: &super::ModelConfig, net: Net) -> Firing {
        Firing {
            encoder: encoder_widths(config, net).iter().map(|&w| vec![false; w]).collect(),
            head: head_widths(config, net).iter().map(|&w| vec![false; w]).collect(),
        }
    }

    /// Marks the channels `tape` saw positive.
    pub fn record(&mut self, tape: &EncodeTape) {
        let layers = self.encoder.iter_mut().zip(&tape.encoder).chain(self.head.iter_mut().zip(&tape.head));
        for (flags, out) in layers {
            for row in out.chunks_exact(flags.len().max(1)) {
                for (f, &v) in flags.iter_mut().zip(row) {
                    *f |= v > 0.0;
                }
            }
        }
    }

    /// The union of two records.
    pub fn merge(mut self, other: &Firing) -> Firing {
        let pairs = self.encoder.iter_mut().zip(&other.encoder).chain(self.head.iter_mut().zip(&other.head));
        for (a, b) in pairs {
            a.iter_mut().zip(b).for_each(|(x, &y)| *x |= y);
        }
        self
    }

    /// The channels fired over `patches` patches of `points` points (`input`: `patches x points x io_width`),
    /// in f32, in parallel chunks.
    pub fn of(f: &FoldNet, config: &super::ModelConfig, input: &[f32], patches: usize, points: usize) -> Firing {
        let per_chunk = 32;
        let row = points * f.net.io_width();
        let input = &input[..(patches * row).min(input.len())];
        input
            .par_chunks(per_chunk * row)
            .map(|chunk| {
                let mut firing = Firing::none(config, f.net);
                firing.record(&f.encode_tape(chunk, chunk.len() / row, points));
                firing
            })
            .reduce(|| Firing::none(config, f.net), |a, b| a.merge(&b))
    }
}

/// The channels kept of one layer: every channel that fired, then the dead channels of lowest index until
/// the count is a multiple of `align` (or the whole layer), in index order. A layer where nothing fired
/// keeps `align` channels (at least one), so that no layer is empty.
pub fn kept_channels(fired: &[bool], align: usize) -> Vec<usize> {
    let align = align.max(1);
    let alive = fired.iter().filter(|&&f| f).count().max(1);
    let count = alive.next_multiple_of(align).min(fired.len());
    let mut keep: Vec<usize> = (0..fired.len()).filter(|&c| fired[c]).collect();
    keep.extend((0..fired.len()).filter(|&c| !fired[c]).take(count.saturating_sub(keep.len())));
    keep.sort_unstable();
    keep
}

/// The channels kept per layer of one network ([`kept_channels`] of each layer of `firing`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Kept {
    /// Per encoder layer.
    pub encoder: Vec<Vec<usize>>,
    /// Per head layer before the codeword.
    pub head: Vec<Vec<usize>>,
}

impl Kept {
    /// The kept channels of each layer of `firing` before the codeword, each a multiple of `align` where the
    /// layer allows.
    pub fn of(firing: &Firing, align: usize) -> Kept {
        let before_codeword = &firing.head[..firing.head.len().saturating_sub(1)];
        Kept {
            encoder: firing.encoder.iter().map(|f| kept_channels(f, align)).collect(),
            head: before_codeword.iter().map(|f| kept_channels(f, align)).collect(),
        }
    }
}

/// The codeword channels kept: those that fired in either network ([`kept_channels`] of their union).
pub fn codeword_channels(firings: &[&Firing], align: usize) -> Vec<usize> {
    let width = firings.iter().filter_map(|f| f.head.last()).map(Vec::len).max().unwrap_or(0);
    let mut fired = vec![false; width];
    for flags in firings.iter().filter_map(|f| f.head.last()) {
        fired.iter_mut().zip(flags).for_each(|(a, &b)| *a |= b);
    }
    kept_channels(&fired, align)
}

/// Rows `rows` and columns `cols` of a row-major `[out, in]` weight with `in_dim` columns.
fn select(weight: &[f32], in_dim: usize, rows: &[usize], cols: &[usize]) -> Vec<f32> {
    rows.iter().flat_map(|&r| cols.iter().map(move |&c| weight[r * in_dim + c])).collect()
}

/// `weights` with each network's channels cut to `kept` (PPF-FoldNet's, then PC-FoldNet's) and the codeword to
/// `codeword`: the pruned layers' rows, the next layers' columns (the skip concatenation's slices and its global
/// slice too, the decoders' and RelativeNet's codeword columns) and the config's widths.
pub fn prune(weights: &Weights, kept: [&Kept; 2], codeword: &[usize]) -> Result<Weights> {
    let config = &weights.config;
    let width = config.codeword();
    if codeword.is_empty() || codeword.windows(2).any(|p| p[0] >= p[1]) || codeword.iter().any(|&c| c >= width) {
        return Err(Error::invalid("prune: the kept codeword channels do not fit the codeword"));
    }
    let mut out = weights.clone();
    let mut widths = Vec::new();
    for (net, kept) in [Net::Ppf, Net::Pc].into_iter().zip(kept) {
        widths.push(prune_net(&mut out, weights, net, kept, codeword)?);
    }
    // RelativeNet reads [source | target] pose features, each a codeword wide.
    let relative = &relative_layers(config)[0];
    let columns: Vec<usize> = codeword.iter().copied().chain(codeword.iter().map(|&c| width + c)).collect();
    cut(&mut out, weights, relative, &(0..relative.out_dim).collect::<Vec<_>>(), &columns)?;
    let pc = widths.pop().expect("two networks");
    let ppf = widths.pop().expect("two networks");
    out.config.encoder_widths = ppf.encoder.clone();
    out.config.head_widths = ppf.head.clone();
    out.config.pc_widths = (pc != ppf).then_some(pc);
    out.config.validate()?;
    Ok(out)
}

/// Cuts one network's layers in `out` (from `weights`) to `kept` and its codeword to `codeword`; its widths.
fn prune_net(out: &mut Weights, weights: &Weights, net: Net, kept: &Kept, codeword: &[usize]) -> Result<NetWidths> {
    let config = &weights.config;
    let (enc, head) = (encoder_widths(config, net), head_widths(config, net));
    let valid = |k: &[Vec<usize>], w: &[usize]| {
        k.len() == w.len()
            && k.iter()
                .zip(w)
                .all(|(k, &w)| !k.is_empty() && k.windows(2).all(|p| p[0] < p[1]) && k.iter().all(|&c| c < w))
    };
    if !valid(&kept.encoder, enc) || !valid(&kept.head, &head[..head.len() - 1]) {
        return Err(Error::invalid(format!("prune: kept channels do not fit {}'s widths", net.prefix())));
    }
    let layers = foldnet_layers(config, net);
    let all = |n: usize| (0..n).collect::<Vec<usize>>();
    let mut previous = all(net.io_width());
    for (i, spec) in layers.iter().take(enc.len()).enumerate() {
        cut(out, weights, spec, &kept.encoder[i], &previous)?;
        previous.clone_from(&kept.encoder[i]);
    }
    // The skip concatenation [enc_0 | enc_1 | ... | global]: each slice keeps its layer's channels.
    let mut concat = Vec::new();
    let mut offset = 0;
    for (k, &w) in kept.encoder.iter().zip(enc) {
        concat.extend(k.iter().map(|&c| offset + c));
        offset += w;
    }
    concat.extend(kept.encoder.last().map_or(&[][..], Vec::as_slice).iter().map(|&c| offset + c));
    debug_assert_eq!(offset + enc.last().copied().unwrap_or(0), concat_width(config, net));
    previous = concat;
    for (j, spec) in layers.iter().skip(enc.len()).take(head.len()).enumerate() {
        let rows = kept.head.get(j).map_or(codeword, Vec::as_slice).to_vec();
        cut(out, weights, spec, &rows, &previous)?;
        previous = rows;
    }
    // Each folding MLP's first layer reads [codeword | grid or first fold's output].
    let folds = config.fold_widths.len() + 1;
    for spec in [&layers[enc.len() + head.len()], &layers[enc.len() + head.len() + folds]] {
        let columns: Vec<usize> = codeword.iter().copied().chain(config.codeword()..spec.in_dim).collect();
        cut(out, weights, spec, &all(spec.out_dim), &columns)?;
    }
    Ok(NetWidths {
        encoder: kept.encoder.iter().map(Vec::len).collect(),
        head: kept.head.iter().map(Vec::len).chain([codeword.len()]).collect(),
    })
}

/// Replaces `spec`'s weight and bias in `out` by rows `rows` and columns `cols` of `from`'s.
fn cut(
    out: &mut Weights,
    from: &Weights,
    spec: &super::params::LayerSpec,
    rows: &[usize],
    cols: &[usize],
) -> Result<()> {
    let weight = from.get(&format!("{}.weight", spec.name))?;
    let bias = from.get(&format!("{}.bias", spec.name))?;
    out.tensors.insert(format!("{}.weight", spec.name), select(weight, spec.in_dim, rows, cols));
    out.tensors.insert(format!("{}.bias", spec.name), rows.iter().map(|&r| bias[r]).collect());
    Ok(())
}

/// `patches` random patches of `points` points each over `net`'s whole input domain, from `seed`: for
/// PPF-FoldNet the features of three independent uniform unit vectors (keypoint normal, neighbour normal,
/// offset direction) and a uniform distance in [0, 1] radius, every combination the geometry allows; for
/// PC-FoldNet points uniform in the unit ball.
pub fn domain_patches(net: Net, patches: usize, points: usize, seed: u64) -> Vec<f32> {
    let mut rng = Rng::new(seed);
    let unit = |rng: &mut Rng| loop {
        let v = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)].map(|x| x as f32);
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 1e-3 && n <= 1.0 {
            break (v.map(|x| x / n), n);
        }
    };
    let mut out = Vec::with_capacity(patches * points * net.io_width());
    for _ in 0..patches * points {
        match net {
            Net::Ppf => {
                let ((normal_r, _), (normal_i, _), (d, _)) = (unit(&mut rng), unit(&mut rng), unit(&mut rng));
                let distance = rng.uniform(0.0, 1.0) as f32;
                let p_i = [-d[0] * distance, -d[1] * distance, -d[2] * distance];
                let (ppf, _) = crate::cpu::patch_features::point_features([0.0; 3], normal_r, p_i, normal_i, 1.0);
                out.extend(ppf);
            }
            Net::Pc => {
                let (d, _) = unit(&mut rng);
                let r = (rng.uniform(0.0, 1.0) as f32).cbrt();
                out.extend(d.map(|x| x * r));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kept_channels_are_the_fired_ones_padded_with_the_first_dead_ones_to_the_alignment() {
        let fired = [false, true, false, false, true, true, false, false, false, true];
        assert_eq!(kept_channels(&fired, 1), vec![1, 4, 5, 9]);
        assert_eq!(kept_channels(&fired, 3), vec![0, 1, 2, 4, 5, 9]);
        assert_eq!(kept_channels(&fired, 8), (0..8).filter(|&c| c != 7).chain([9]).collect::<Vec<_>>());
        assert_eq!(kept_channels(&fired, 16), (0..10).collect::<Vec<_>>());
        assert_eq!(kept_channels(&[false; 5], 1), vec![0]);
    }

    #[test]
    fn domain_patches_lie_in_each_networks_input_domain() {
        let ppf = domain_patches(Net::Ppf, 3, 50, 1);
        assert_eq!(ppf.len(), 3 * 50 * 4);
        for f in ppf.chunks_exact(4) {
            assert!(f.iter().all(|v| (0.0..=1.0).contains(v)), "{f:?}");
            // Three angles between three unit vectors obey the spherical triangle inequality.
            assert!(f[2] <= f[0] + f[1] + 1e-5 && f[0] <= f[1] + f[2] + 1e-5 && f[1] <= f[0] + f[2] + 1e-5, "{f:?}");
        }
        let pc = domain_patches(Net::Pc, 2, 50, 1);
        assert!(pc.chunks_exact(3).all(|p| p.iter().map(|v| v * v).sum::<f32>() <= 1.0 + 1e-5));
        assert_eq!(domain_patches(Net::Pc, 2, 50, 1), pc, "seeded");
        assert_ne!(domain_patches(Net::Pc, 2, 50, 2), pc);
    }
}
