//! `dpr-gpu prune`: removes the channels of PPF-FoldNet and PC-FoldNet that never fire on training patches
//! nor on random patches of the whole input domain (`crate::model::prune`), and checks that the pruned model
//! gives the same codewords on those patches.

use super::bench::encode_flops;
use super::weights::check_weights_path;
use crate::model::prune::{Firing, Kept, codeword_channels, domain_patches, prune};
use crate::model::{FoldNet, ModelConfig, Net, Weights};
use crate::train::data::{DataSettings, Sampler, discover_pairs};
use anyhow::{Context, bail};
use std::path::PathBuf;

/// Arguments of `dpr-gpu prune`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Calibration data (synthetic training scans; never the sets you evaluate on): dataset folders, scene
    /// folders, gt.log or pairs files, as `train --data` takes them.
    #[arg(long, required = true, num_args = 1..)]
    pub data: Vec<PathBuf>,
    /// The weights to prune (default: the built-in weights).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// The pruned weights file to write (*.safetensors).
    #[arg(long)]
    pub out: PathBuf,
    /// Training batches of patch pairs drawn per patch radius.
    #[arg(long, default_value_t = 40)]
    pub batches: usize,
    /// Patch pairs per batch.
    #[arg(long, default_value_t = 32)]
    pub batch: usize,
    /// Patch radii, as multiples of the model's training radius (inference uses about twice it).
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub radius_factors: Vec<f32>,
    /// Random patches per network over its whole input domain (every feature the geometry allows).
    #[arg(long, default_value_t = 4096)]
    pub domain_patches: usize,
    /// Each pruned layer keeps a multiple of this many channels (padding with dead ones), for the SIMD and GPU
    /// tiles.
    #[arg(long, default_value_t = 16)]
    pub align: usize,
    /// Seed of the drawn patches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Most calibration patches per network: bounds the memory of the calibration inputs.
const MAX_PATCHES: usize = 1 << 18;

/// Runs `dpr-gpu prune`.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_weights_path("--out", &args.out)?;
    let inputs: Vec<&std::path::Path> = args.weights.iter().map(PathBuf::as_path).collect();
    crate::io::check_outputs(&inputs, &[("--out", &args.out)])?;
    if args.align == 0 || args.radius_factors.iter().any(|f| !(f.is_finite() && *f > 0.0)) {
        bail!("--align must be positive and --radius-factors finite and positive");
    }
    let drawn = 2 * args.batches.saturating_mul(args.batch).saturating_mul(args.radius_factors.len());
    if drawn.saturating_add(args.domain_patches) > MAX_PATCHES {
        bail!("at most {MAX_PATCHES} calibration patches per network; lower --batches, --batch or --domain-patches");
    }
    let weights = match &args.weights {
        Some(path) => Weights::load(path)?,
        None => Weights::built_in()?,
    };
    let (ppf, pc, training_patches) = calibration_patches(&args, &weights.config)?;
    let view = weights.view();
    let points = weights.config.points_per_patch;
    let (mut kept, mut firings) = (Vec::new(), Vec::new());
    for (net, input) in [(Net::Ppf, &ppf), (Net::Pc, &pc)] {
        let patches = input.len() / (points * net.io_width());
        let firing = Firing::of(&FoldNet::from_weights(&view, net)?, &weights.config, input, patches, points);
        let k = Kept::of(&firing, args.align);
        let encoder = firing.encoder.iter().zip(&k.encoder).map(|layer| ("encoder", layer));
        for (name, (fired, keep)) in encoder.chain(firing.head.iter().zip(&k.head).map(|layer| ("head", layer))) {
            let count = fired.iter().filter(|&&x| x).count();
            println!("{} {name}: {} channels, {count} fired, {} kept", net.prefix(), fired.len(), keep.len());
        }
        let codeword = firing.head.last().map_or(0, |f| f.iter().filter(|&&x| x).count());
        println!("{} codeword: {} channels, {codeword} fired", net.prefix(), weights.config.codeword());
        kept.push(k);
        firings.push(firing);
    }
    let codeword = codeword_channels(&[&firings[0], &firings[1]], args.align);
    let either = codeword_channels(&[&firings[0], &firings[1]], 1).len();
    println!("codeword: {either} channels fired in either network, {} kept", codeword.len());
    let mut pruned = prune(&weights, [&kept[0], &kept[1]], &codeword)?;
    for (net, input) in [(Net::Ppf, &ppf), (Net::Pc, &pc)] {
        compare(&weights, &pruned, net, input, &codeword)?;
    }
    let origin = args.weights.as_ref().map_or("built-in default weights".to_string(), |p| p.display().to_string());
    let data: Vec<String> = args.data.iter().map(|p| p.display().to_string()).collect();
    let note = serde_json::json!({
        "from": origin,
        "data": data,
        "training_patches": training_patches,
        "radius_factors": args.radius_factors,
        "domain_patches": args.domain_patches,
        "align": args.align,
        "seed": args.seed,
    });
    pruned.notes.insert("dpr_gpu.pruned".into(), note.to_string());
    pruned.save(&args.out)?;
    println!("wrote {} ({} -> {} parameters)", args.out.display(), weights.parameter_count(), pruned.parameter_count());
    Ok(())
}

/// The calibration inputs of PPF-FoldNet and PC-FoldNet: training patches at each radius factor, then the
/// random domain patches; and how many training patches were drawn.
fn calibration_patches(args: &Args, config: &ModelConfig) -> anyhow::Result<(Vec<f32>, Vec<f32>, usize)> {
    let points = config.points_per_patch;
    let (mut ppf, mut pc) = (Vec::new(), Vec::new());
    let pairs = discover_pairs(&args.data)?;
    for &factor in &args.radius_factors {
        let radius_config = ModelConfig { radius: config.radius * factor, ..config.clone() };
        let mut sampler = Sampler::new(pairs.clone(), DataSettings::default(), &radius_config)
            .with_context(|| format!("calibration data at {factor} x the model radius"))?;
        for step in 0..args.batches as u64 {
            for sample in sampler.batch(args.seed, step, args.batch)? {
                ppf.extend(sample.ppf);
                pc.extend(sample.pc);
            }
        }
    }
    let drawn = ppf.len() / (points * Net::Ppf.io_width());
    ppf.extend(domain_patches(Net::Ppf, args.domain_patches, points, args.seed));
    pc.extend(domain_patches(Net::Pc, args.domain_patches, points, args.seed ^ 1));
    Ok((ppf, pc, drawn))
}

/// Prints how the pruned network's codewords compare with the whole one's on `input` (the removed codeword
/// channels must be 0 there, the kept ones equal), and its FLOPs.
fn compare(whole: &Weights, pruned: &Weights, net: Net, input: &[f32], codeword: &[usize]) -> anyhow::Result<()> {
    let points = whole.config.points_per_patch;
    let (a, b) = (FoldNet::from_weights(&whole.view(), net)?, FoldNet::from_weights(&pruned.view(), net)?);
    let patches = input.len() / (points * net.io_width());
    let (x, y) = (a.encode(input, patches, points), b.encode(input, patches, points));
    let width = whole.config.codeword();
    let mut expanded = vec![0f32; x.len()];
    for (row, cut) in expanded.chunks_exact_mut(width).zip(y.chunks_exact(codeword.len())) {
        codeword.iter().zip(cut).for_each(|(&c, &v)| row[c] = v);
    }
    let differ = x.iter().zip(&expanded).filter(|(p, q)| p != q).count();
    let max = x.iter().zip(&expanded).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
    println!(
        "{}: {} -> {} MFLOP per patch; codewords on the {patches} calibration patches: {differ} values differ, \
         largest difference {max:e}",
        net.prefix(),
        encode_flops(&a, 1, points) / 1e6,
        encode_flops(&b, 1, points) / 1e6
    );
    Ok(())
}
