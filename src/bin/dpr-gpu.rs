//! The `dpr-gpu` binary; all logic is in `dpr_gpu::cli`.

fn main() -> std::process::ExitCode {
    dpr_gpu::cli::main()
}
