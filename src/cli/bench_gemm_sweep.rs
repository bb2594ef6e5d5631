//! `dpr-gpu bench --gemm-sweep`: times every GEMM the adapter can run (`portable`, `fast` at each tile shape of
//! [`FastTile::ALL`], `coop_f16` at each of [`CoopTile::ALL`] its workgroup memory holds) on the dense layer
//! shapes the encoders run (rows x 704 -> 512 and rows x 512 -> 512, bias and ReLU), prints a table (or with
//! `--json` one document whose `gemm_sweep` array has one entry per variant, tile and shape), and records the
//! fastest variant and tile for this adapter in the choice file ([`gemm_choice`]), which
//! [`crate::gpu::gemm::select`] then takes for the adapter when `DPR_GPU_GEMM` is not set. Each candidate is
//! first checked against its CPU twin on one small ragged layer ([`check_against_twin`]); one that disagrees is
//! listed as unavailable and never timed or recorded. Times are the fastest of `--repeat` runs after a warm-up,
//! on GPU timestamps where the adapter has them; the choice is the smallest total time over the shapes.

use super::bench::{Args, GemmTiming, gflops, gpu_timing, measure};
use crate::cpu::dense::DenseShape;
use crate::gpu::dense::Dense;
use crate::gpu::dense_coop_f16::{CoopTile, DenseCoopF16};
use crate::gpu::dense_fast::{DenseFast, FastTile};
use crate::gpu::gemm::{GemmChoice, GemmVariant, gemm_choice};
use crate::gpu::kernel::GpuKernel;
use crate::gpu::{Gpu, buffer::GpuBuffer, dense as gpu_dense, recorder::Recorder};
use crate::rng::Rng;
use anyhow::{Context, bail};
use serde::Serialize;

/// The `schema` field of the `--json` document.
pub const SCHEMA: &str = "dpr-gpu-gemm-sweep/1";
/// The dense layer shapes timed: (input width, output width) of the encoders' 512-wide layers.
pub const SHAPES: [(usize, usize); 2] = [(704, 512), (512, 512)];
/// Rows of each layer by default (a batch of the encoders' points).
pub const DEFAULT_ROWS: usize = 32_768;
/// Rows on a software adapter unless `--full-sizes` or `--gemm-rows`.
pub const SOFTWARE_ROWS: usize = 512;
/// Most rows `--gemm-rows` takes.
pub const MAX_ROWS: usize = 1 << 20;

/// One timed (variant, tile, shape).
#[derive(Clone, Debug, Serialize)]
pub struct SweepEntry {
    /// `portable`, `fast` or `coop_f16`.
    pub variant: &'static str,
    /// Output tile of one workgroup, `ROWSxCOLS`.
    pub tile: String,
    /// Outputs one invocation computes, `ROWSxCOLS` (`null` for the cooperative-matrix kernel, whose
    /// subgroups share their tiles: its tile names its subgroups, `128x128/8sg`).
    pub per_invocation: Option<String>,
    /// The layer and its time (the fields of a `bench` GEMM row).
    #[serde(flatten)]
    pub timing: GemmTiming,
}

/// A variant (or one tile of it) the adapter cannot run, or that gave wrong results.
#[derive(Clone, Debug, Serialize)]
pub struct SweepUnavailable {
    /// The variant.
    pub variant: &'static str,
    /// The tile shape, when only it is unavailable.
    pub tile: Option<String>,
    /// Why.
    pub reason: String,
}

/// The fastest candidate.
#[derive(Clone, Debug, Serialize)]
pub struct SweepBest {
    /// The variant.
    pub variant: &'static str,
    /// Its tile.
    pub tile: String,
    /// Its time summed over the shapes (ms).
    pub total_ms: f64,
    /// All the shapes' flops over `total_ms`.
    pub gflops: f64,
}

/// The `--json` document.
#[derive(Clone, Debug, Serialize)]
pub struct SweepReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The adapter, in words.
    pub adapter: String,
    /// The choice file's key for it (name, backend, driver).
    pub adapter_key: String,
    /// Rows of each layer.
    pub rows: usize,
    /// Timed repetitions (the fastest is kept).
    pub repeat: usize,
    /// Whether the rows or repetitions were cut for a software adapter.
    pub sizes_cut: bool,
    /// `--peak-tflops`.
    pub peak_tflops: Option<f64>,
    /// What the device ran before the sweep (`DPR_GPU_GEMM`, an earlier record, or the fixed order).
    pub selected_before: String,
    /// One entry per variant, tile and shape.
    pub gemm_sweep: Vec<SweepEntry>,
    /// Variants the adapter cannot run.
    pub unavailable: Vec<SweepUnavailable>,
    /// The fastest variant and tile (`null` when nothing ran).
    pub best: Option<SweepBest>,
    /// The choice file (`null`: no cache directory in the environment).
    pub choice_file: Option<String>,
    /// Whether `best` was recorded there.
    pub recorded: bool,
    /// Why it was not, when it was not.
    pub record_error: Option<String>,
}

/// Every (variant, tile) the adapter can run, and the variants and tiles it cannot with the reason.
fn candidates(g: &Gpu) -> (Vec<GemmChoice>, Vec<SweepUnavailable>) {
    let (mut run, mut unavailable) = (Vec::new(), Vec::new());
    for variant in GemmVariant::ALL {
        if let Some(reason) = variant.unavailable_reason(&g.context) {
            unavailable.push(SweepUnavailable { variant: variant.name(), tile: None, reason });
            continue;
        }
        let choices: Vec<GemmChoice> = match variant {
            GemmVariant::Fast => FastTile::ALL.into_iter().map(GemmChoice::fast).collect(),
            GemmVariant::CoopF16 => CoopTile::ALL.into_iter().map(GemmChoice::coop).collect(),
            GemmVariant::Portable => vec![GemmChoice::of(variant)],
        };
        for choice in choices {
            match choice.unavailable_reason(&g.context) {
                Some(reason) => unavailable.push(unavailable_tile(choice, reason)),
                None => run.push(choice),
            }
        }
    }
    (run, unavailable)
}

/// `choice`'s tile, unavailable for `reason`.
fn unavailable_tile(choice: GemmChoice, reason: String) -> SweepUnavailable {
    SweepUnavailable { variant: choice.variant.name(), tile: Some(choice.tile_name()), reason }
}

/// The tile and outputs per invocation of `choice`, as reported.
fn tile_names(choice: GemmChoice) -> (String, Option<String>) {
    let per = match choice.variant {
        GemmVariant::Fast => {
            let (m, n) = choice.tile.per_invocation();
            Some(format!("{m}x{n}"))
        }
        GemmVariant::Portable => {
            let (m, n) = choice.variant.tile();
            Some(format!("{}x{}", m / 16, n / 16))
        }
        GemmVariant::CoopF16 => None,
    };
    (choice.tile_name(), per)
}

/// The layer [`check_against_twin`] runs: ragged against every tile (rows and columns not multiples of 16 or
/// 64, the input width not a multiple of 4 or of a k-tile), with a group term and ReLU.
pub const CHECK_SHAPE: DenseShape =
    DenseShape { rows: 131, in_dim: 70, out_dim: 133, rows_per_group: 40, accumulate: true, relu: true };

/// Runs `choice` once on [`CHECK_SHAPE`] and compares it with the variant's CPU twin within the parity tests'
/// bound (the f32 kernels' summation bound, the cooperative kernel's f16 bound); `Err` says how many outputs
/// differ and the worst.
pub fn check_against_twin(g: &Gpu, choice: GemmChoice, seed: u64) -> anyhow::Result<()> {
    use crate::gpu::parity::inference::f32_gemm_tolerance;
    let s = CHECK_SHAPE;
    let mut rng = Rng::new(seed ^ 0xC4EC);
    let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
    let (x, w, init) = (v(s.rows * s.in_dim), v(s.in_dim * s.out_dim), v(s.rows * s.out_dim));
    let group = v(s.rows.div_ceil(s.rows_per_group) * s.out_dim);
    let twin = match choice.variant {
        GemmVariant::Portable => Dense::CPU_TWIN,
        GemmVariant::Fast => DenseFast::CPU_TWIN,
        GemmVariant::CoopF16 => DenseCoopF16::CPU_TWIN,
    };
    let mut want = init.clone();
    twin(&s, &x, &w, &group, &mut want);
    let mut got = init.clone();
    crate::block_on(gpu_dense::run_choice(g, choice, &s, &x, &w, &group, &mut got))?;
    let tol = match choice.variant {
        GemmVariant::CoopF16 => crate::cpu::dense_coop_f16::parity_tolerance(&s, &x, &w, &group, &init),
        _ => f32_gemm_tolerance(&s, &x, &w, &group, &init),
    };
    // NaN is never within the bound.
    let within = |i: usize| (got[i] - want[i]).abs() <= tol[i];
    let bad: Vec<(usize, f32)> = (0..got.len()).filter(|&i| !within(i)).map(|i| (i, got[i] - want[i])).collect();
    if let Some(&(i, d)) = bad.iter().max_by(|a, b| a.1.abs().total_cmp(&b.1.abs())) {
        bail!(
            "wrong results on {}x{} -> {}: {} of {} outputs off the CPU twin by more than the bound (worst: output {i}, \
             off by {d}, bound {})",
            s.rows,
            s.in_dim,
            s.out_dim,
            bad.len(),
            got.len(),
            tol[i]
        );
    }
    Ok(())
}

/// Times `choice` on one layer shape.
fn time_layer(
    g: &Gpu,
    args: &Args,
    choice: GemmChoice,
    rows: usize,
    (in_dim, out_dim): (usize, usize),
) -> anyhow::Result<SweepEntry> {
    let mut rng = Rng::new(args.seed ^ 0x5EE9 ^ in_dim as u64);
    let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
    let (x, w, b) = (v(rows * in_dim), v(in_dim * out_dim), v(out_dim));
    let ctx = &g.context;
    let xb = GpuBuffer::from_slice(ctx, "x", &x)?;
    let wb = GpuBuffer::from_slice(ctx, "w", &w)?;
    let bb = GpuBuffer::from_slice(ctx, "b", &b)?;
    let ob = GpuBuffer::from_slice(ctx, "out", &vec![0.0f32; rows * out_dim])?;
    let shape = DenseShape { rows, in_dim, out_dim, rows_per_group: rows, accumulate: false, relu: true };
    let params = gpu_dense::DenseParams::new(&shape, 0, true)?;
    let m = measure(args.repeat, Some(g), || {
        let mut rec = Recorder::new(g, "gemm sweep");
        gpu_dense::record_choice(&mut rec, g, choice, &params, [xb.raw(), wb.raw()], Some(bb.raw()), ob.raw())?;
        crate::block_on(rec.finish())?;
        Ok(())
    })
    .with_context(|| format!("timing GEMM {} on {rows} x {in_dim} -> {out_dim}", choice.name()))?;
    let flops = 2.0 * (rows * in_dim * out_dim) as f64;
    let t = gpu_timing(m, Some(flops), args.peak_tflops);
    let (tile, per_invocation) = tile_names(choice);
    Ok(SweepEntry {
        variant: choice.variant.name(),
        tile,
        per_invocation,
        timing: GemmTiming::new((rows, in_dim, out_dim), t.device_ms, t.clock, args.peak_tflops),
    })
}

/// Rows and repetitions: the arguments, the defaults cut on a software adapter unless `--full-sizes`; and
/// whether they were cut.
fn sizes(args: &Args, g: &Gpu) -> anyhow::Result<(usize, usize, bool)> {
    let software = g.context.info.device_type == wgpu::DeviceType::Cpu && !args.full_sizes;
    let (rows, rows_cut) = match args.gemm_rows {
        Some(r) if (1..=MAX_ROWS).contains(&r) => (r, false),
        Some(r) => bail!("--gemm-rows must be 1..={MAX_ROWS}, got {r}"),
        None if software => (SOFTWARE_ROWS, true),
        None => (DEFAULT_ROWS, false),
    };
    let repeat_cut = software && args.repeat == super::bench::DEFAULT_REPEAT;
    let repeat = if repeat_cut { 1 } else { args.repeat.max(1) };
    Ok((rows, repeat, rows_cut || repeat_cut))
}

/// Runs the sweep on the environment's adapter and records the fastest choice (what `--gemm-sweep` prints).
pub fn measure_sweep(args: &Args) -> anyhow::Result<SweepReport> {
    if args.repeat > super::bench::MAX_REPEAT {
        bail!("--repeat must be at most {}, got {}", super::bench::MAX_REPEAT, args.repeat);
    }
    let g = Gpu::new().context("bench --gemm-sweep needs a GPU adapter")?;
    g.set_profiling(true);
    let (rows, repeat, sizes_cut) = sizes(args, &g)?;
    if sizes_cut {
        eprintln!(
            "bench --gemm-sweep: a software adapter: {rows} rows, {repeat} repetition (--full-sizes keeps {DEFAULT_ROWS} \
             rows and --repeat)"
        );
    }
    let timed = Args { repeat, ..args.clone() };
    let (run, mut unavailable) = candidates(&g);
    let mut entries = Vec::new();
    let mut best: Option<(GemmChoice, SweepBest)> = None;
    for &choice in &run {
        if let Err(e) = check_against_twin(&g, choice, args.seed) {
            eprintln!("warning: GEMM {} is not timed: {e:#}", choice.name());
            unavailable.push(unavailable_tile(choice, format!("{e:#}")));
            continue;
        }
        let layers: Vec<SweepEntry> =
            SHAPES.iter().map(|&s| time_layer(&g, &timed, choice, rows, s)).collect::<anyhow::Result<_>>()?;
        let total_ms: f64 = layers.iter().map(|e| e.timing.time_ms).sum();
        let flops: f64 = layers.iter().map(|e| e.timing.flops).sum();
        if best.as_ref().is_none_or(|(_, b)| total_ms < b.total_ms) {
            let (tile, _) = tile_names(choice);
            let b = SweepBest { variant: choice.variant.name(), tile, total_ms, gflops: gflops(flops, total_ms) };
            best = Some((choice, b));
        }
        entries.extend(layers);
    }
    let key = gemm_choice::adapter_key(&g.context.info);
    let path = gemm_choice::choice_file();
    let (mut recorded, mut record_error) = (false, None);
    match (&best, &path) {
        (Some((choice, b)), Some(p)) => match gemm_choice::record(p, &key, *choice, b.gflops) {
            Ok(()) => recorded = true,
            Err(e) => {
                eprintln!("warning: the GEMM choice was not recorded: {e}");
                record_error = Some(e.to_string());
            }
        },
        (_, None) => {
            record_error =
                Some(format!("no cache directory ({} or XDG_CACHE_HOME or HOME)", gemm_choice::CACHE_DIR_ENV));
        }
        (None, Some(_)) => record_error = Some("no variant ran".into()),
    }
    Ok(SweepReport {
        schema: SCHEMA,
        adapter: g.adapter_info(),
        adapter_key: key,
        rows,
        repeat,
        sizes_cut,
        peak_tflops: args.peak_tflops,
        selected_before: g.gemm_choice().name(),
        gemm_sweep: entries,
        unavailable,
        best: best.map(|(_, b)| b),
        choice_file: path.map(|p| p.display().to_string()),
        recorded,
        record_error,
    })
}

/// `dpr-gpu bench --gemm-sweep`: the table, or with `--json` the [`SweepReport`].
pub fn run(args: &Args) -> anyhow::Result<()> {
    let r = measure_sweep(args)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(());
    }
    println!("dpr-gpu bench --gemm-sweep: {} ({} rows, best of {})", r.adapter, r.rows, r.repeat);
    println!(
        "{:<10} {:>8} {:>9} {:>16} {:>10} {:>10} {:>8}",
        "variant", "tile", "per inv.", "shape", "ms", "GFLOP/s", "peak"
    );
    for e in &r.gemm_sweep {
        let peak = e.timing.peak_fraction.map_or("-".to_string(), |f| format!("{:.1}%", 100.0 * f));
        println!(
            "{:<10} {:>8} {:>9} {:>16} {:>10.3} {:>10.1} {:>8}",
            e.variant,
            e.tile,
            e.per_invocation.as_deref().unwrap_or("-"),
            format!("{}x{}->{}", e.timing.rows, e.timing.in_dim, e.timing.out_dim),
            e.timing.time_ms,
            e.timing.gflops,
            peak
        );
    }
    for u in &r.unavailable {
        println!("{:<10} {:>8} not available: {}", u.variant, u.tile.as_deref().unwrap_or(""), u.reason);
    }
    if let Some(b) = &r.best {
        println!("best: {} {} ({:.3} ms over the shapes, {:.1} GFLOP/s)", b.variant, b.tile, b.total_ms, b.gflops);
    }
    match (&r.choice_file, r.recorded, &r.record_error) {
        (Some(p), true, _) => {
            println!("recorded for this adapter in {p} (GEMM auto takes it; delete the file to forget it)")
        }
        (_, _, Some(e)) => println!("not recorded: {e}"),
        _ => {}
    }
    Ok(())
}
