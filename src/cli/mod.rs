//! The `dpr-gpu` command line. Each subcommand lives in its own module with an `Args` struct and `run`.

use clap::{Parser, Subcommand};

pub mod bench;
pub mod bench_gemm_sweep;
pub mod bench_pose_graph;
pub mod eval;
pub mod eval_trajectory;
pub mod multiway;
pub mod pose_graph;
pub mod prune;
pub mod register;
pub mod synopsis;
pub mod synth;
pub mod train;
pub mod weights;

/// dpr-gpu: learned pairwise registration of 3D scans on any GPU (and the CPU).
#[derive(Parser, Debug)]
#[command(name = "dpr-gpu", version, about)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Register SOURCE onto TARGET and print target_from_source.
    Register(register::Args),
    /// Time every stage and the GEMM throughput on the current adapter (or the CPU).
    Bench(bench::Args),
    /// Write a seeded random initialisation of the model.
    InitWeights(weights::InitArgs),
    /// Print a weights file's config and parameter counts.
    Info(weights::InfoArgs),
    /// Generate synthetic indoor scans in the 3DMatch layout.
    Synth(synth::Args),
    /// Train the model (PPF-FoldNet, PC-FoldNet and RelativeNet) on 3DMatch-format data.
    Train(train::Args),
    /// Evaluate registration on a dataset (3DMatch protocol) or score a result log.
    Eval(eval::Args),
    /// Register a collection of scans into one trajectory (robust pose graph); resumable.
    Multiway(multiway::Args),
    /// Compare a trajectory with ground truth: ATE, rotation errors, loop closures kept.
    EvalTrajectory(eval_trajectory::Args),
    /// Remove the encoder channels that never fire (the same codewords, less arithmetic).
    Prune(prune::Args),
    /// Optimise a g2o pose graph (sparse Levenberg-Marquardt, chordal start, optional robust kernel).
    PoseGraph(pose_graph::Args),
}

/// Runs the CLI; returns the process exit code. Errors are printed as one line.
pub fn main() -> std::process::ExitCode {
    default_sigpipe();
    quiet_device_select();
    let cli = Cli::parse();
    cap_thread_pool();
    let mut untrusted = false;
    let outcome = match cli.command {
        Command::Register(args) => register::run(args).map(|trusted| untrusted = !trusted),
        Command::Bench(args) if args.gemm_sweep => bench_gemm_sweep::run(&args),
        Command::Bench(args) => bench::run(args),
        Command::InitWeights(args) => weights::run_init(args),
        Command::Info(args) => weights::run_info(args),
        Command::Synth(args) => synth::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Train(args) => train::run(args),
        Command::Multiway(args) => multiway::run(args).map(|placed| untrusted = !placed),
        Command::EvalTrajectory(args) => eval_trajectory::run(args),
        Command::PoseGraph(args) => pose_graph::run(args),
        Command::Prune(args) => prune::run(args),
    };
    match outcome {
        Ok(()) if untrusted => std::process::ExitCode::from(register::EXIT_UNTRUSTED),
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line.
/// A cause whose text already ends the line (an I/O error that its wrapper prints) is not repeated.
pub fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain().map(|c| c.to_string()) {
        if line.ends_with(&cause) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&cause);
    }
    line
}

/// Most threads of the global pool, whatever `RAYON_NUM_THREADS` asks for.
pub const MAX_THREADS: usize = 256;

/// Restores SIGPIPE's default action (Rust ignores it), so that output into a closed pipe (`dpr-gpu info w |
/// head -1`) ends the process quietly as it ends other Unix tools, not with a panic in `println!`.
fn default_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first in `main`, before any other thread exists; SIG_DFL is a valid action for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Turns Mesa's Vulkan device-select layer off (`NODEVICE_SELECT=1`, the switch its manifest names) where
/// there is no desktop session (`XDG_RUNTIME_DIR` unset or not a folder: servers, containers, ssh): while the
/// loader enumerates adapters it asks the Wayland display for the default GPU and, without a session, prints
/// "error: XDG_RUNTIME_DIR is invalid or not set" twice, on every run. The layer only reorders the adapters,
/// which the adapter policy ranks itself. A value the user set is kept.
fn quiet_device_select() {
    let session = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir());
    if !session && std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called first in `main`, before any other thread exists (nothing reads the environment
        // concurrently).
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

/// Sizes rayon's global pool: `RAYON_NUM_THREADS` when set, capped at the cores this process may use (and at
/// [`MAX_THREADS`]), so a value such as 5000 cannot make every parallel stage spawn and schedule thousands of
/// threads. Call once, before any parallel work; later calls do nothing.
pub fn cap_thread_pool() {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let wanted = std::env::var("RAYON_NUM_THREADS").ok().and_then(|v| v.trim().parse::<usize>().ok()).unwrap_or(0);
    let threads = if wanted == 0 { cores } else { wanted.min(cores) }.clamp(1, MAX_THREADS);
    let _ = rayon::ThreadPoolBuilder::new().num_threads(threads).build_global();
}
