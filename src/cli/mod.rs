//! The `dpr-gpu` command line. Each subcommand lives in its own module with an `Args` struct and `run`.

use clap::{Parser, Subcommand};

pub mod bench;
pub mod eval;
pub mod register;
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
}

/// Runs the CLI; returns the process exit code. Errors are printed as one line.
pub fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let outcome = match cli.command {
        Command::Register(args) => register::run(args),
        Command::Bench(args) => bench::run(args),
        Command::InitWeights(args) => weights::run_init(args),
        Command::Info(args) => weights::run_info(args),
        Command::Synth(args) => synth::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Train(args) => train::run(args),
    };
    match outcome {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line.
pub fn one_line(e: &anyhow::Error) -> String {
    e.chain().map(|c| c.to_string()).collect::<Vec<_>>().join(": ")
}
