//! Device acquisition for GPU tests and benchmarks, with the missing-adapter policy in one place, and
//! [`run_tests`], a small test harness for GPU test binaries (`harness = false`) that reports tests run
//! without an adapter as SKIPPED, with a count, instead of as passed; a test whose adapter lacks a feature it
//! needs (cooperative matrices) calls [`skip_test`] and is reported SKIPPED with its reason the same way.
//!
//! Without a usable adapter: when `CI=true` or `DPR_GPU_REQUIRE_ADAPTER=1`, [`gpu_or_skip`] panics with
//! the reason (CI never skips silently); otherwise it prints a loud `SKIPPED (no GPU adapter)` line to the
//! real stderr (not captured by the test harness) and returns `None`, and the caller returns early.
//!
//! The backend is `DPR_GPU_BACKEND` / `WGPU_BACKEND` when set, else Vulkan only: without a Vulkan driver
//! wgpu would otherwise pick a GL adapter, which is not what CI means to test (lavapipe is Vulkan).

use super::Gpu;
use super::device::context::{self, GpuContext};
use std::io::Write;
use std::sync::{Arc, OnceLock};

/// Env var that turns a missing adapter into a failure (as does `CI=true`).
pub const REQUIRE_ENV: &str = "DPR_GPU_REQUIRE_ADAPTER";

/// Whether a missing adapter must fail (`CI=true|1` or `DPR_GPU_REQUIRE_ADAPTER=1|true|yes`).
pub fn adapter_required() -> bool {
    let set = |var: &str, yes: &[&str]| {
        std::env::var(var).is_ok_and(|v| yes.contains(&v.trim().to_ascii_lowercase().as_str()))
    };
    set("CI", &["true", "1"]) || set(REQUIRE_ENV, &["1", "true", "yes"])
}

/// The backends tests use: the environment's when `DPR_GPU_BACKEND` or `WGPU_BACKEND` is set, else Vulkan.
pub fn test_backends() -> crate::Result<wgpu::Backends> {
    if std::env::var(context::BACKEND_ENV).is_ok() || std::env::var("WGPU_BACKEND").is_ok() {
        context::backends_from_env()
    } else {
        Ok(wgpu::Backends::VULKAN)
    }
}

/// A new device on [`test_backends`] (for tests that change per-device settings such as the buffer cap).
pub fn new_test_gpu() -> crate::Result<Gpu> {
    Gpu::from_context(GpuContext::with_backends(test_backends()?)?)
}

/// Applies the missing-adapter policy to `reason`: panics when an adapter is required, else prints the
/// skip line and returns `None`.
pub fn skip_or_panic<T>(reason: &str) -> Option<T> {
    if adapter_required() {
        panic!("no usable GPU adapter, and CI=true or {REQUIRE_ENV}=1 requires one: {reason}");
    }
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "=== SKIPPED (no GPU adapter): {reason} (set {REQUIRE_ENV}=1 to fail instead) ===");
    None
}

/// The device shared by all tests of a process, or `None` after the skip line.
pub fn gpu_or_skip() -> Option<Arc<Gpu>> {
    static GPU: OnceLock<Result<Arc<Gpu>, String>> = OnceLock::new();
    match GPU.get_or_init(|| new_test_gpu().map(Arc::new).map_err(|e| e.to_string())) {
        Ok(g) => Some(Arc::clone(g)),
        Err(e) => skip_or_panic(e),
    }
}

/// A fresh device (see [`new_test_gpu`]), or `None` after the skip line.
pub fn new_gpu_or_skip() -> Option<Gpu> {
    match new_test_gpu() {
        Ok(g) => Some(g),
        Err(e) => skip_or_panic(&e.to_string()),
    }
}

/// Whether a GPU test can run: `Ok` with a usable adapter, else `Err(reason)`.
pub fn adapter_status() -> Result<(), String> {
    static STATUS: OnceLock<Result<(), String>> = OnceLock::new();
    STATUS.get_or_init(|| new_test_gpu().map(drop).map_err(|e| e.to_string())).clone()
}

/// One test of a GPU test binary: its name and body (a panic is a failure).
pub type GpuTest = (&'static str, fn());

thread_local! {
    /// Set by [`skip_test`] while a test body runs.
    static SKIP_REASON: std::cell::RefCell<Option<String>> = const { std::cell::RefCell::new(None) };
}

/// Marks the running test of [`run_tests`] as not run because the adapter lacks what it needs (a feature such
/// as cooperative matrices): the body should return right after. The harness reports the test `SKIPPED` with
/// `reason` and counts it as skipped, never as passed. (Outside [`run_tests`] it only prints the reason.)
pub fn skip_test(reason: impl Into<String>) {
    let reason = reason.into();
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "=== SKIPPED: {reason} ===");
    SKIP_REASON.with(|r| *r.borrow_mut() = Some(reason));
}

/// Runs `tests` and the kernel parity `cases` (each on the shared device, [`gpu_or_skip`], to completion with
/// [`crate::block_on`]; a skipped case is reported as [`skip_test`] reports) as a `harness = false` test binary
/// would: `cargo test --test NAME [FILTER] [--exact] [--list] [--ignored]` are understood. Without a usable
/// adapter every selected test is reported as `SKIPPED` and counted (never as passed); when an adapter is required
/// (`CI=true` or `DPR_GPU_REQUIRE_ADAPTER=1`) they fail instead. Returns the process exit code: failure when a test
/// failed.
pub fn run_tests(tests: &[GpuTest], cases: &[super::parity::Case]) -> std::process::ExitCode {
    let run_case = |case: super::parity::Case| {
        move || {
            let gpu = gpu_or_skip().expect("the adapter was checked before the case ran");
            if let super::parity::Outcome::Skipped(reason) = crate::block_on((case.run)(&gpu)) {
                skip_test(reason);
            }
        }
    };
    let bodies: Vec<NamedBody> = tests
        .iter()
        .map(|&(name, body)| (name, Box::new(body) as Box<dyn Fn()>))
        .chain(cases.iter().map(|&case| (case.name, Box::new(run_case(case)) as Box<dyn Fn()>)))
        .collect();
    run_bodies(&bodies)
}

/// A test's name and body, as [`run_bodies`] runs them.
type NamedBody = (&'static str, Box<dyn Fn()>);

fn run_bodies(tests: &[NamedBody]) -> std::process::ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let exact = args.iter().any(|a| a == "--exact");
    let flag_with_value = ["--test-threads", "--format", "--color", "--skip", "-Z"];
    let mut filters = Vec::new();
    let mut skip_next = false;
    for a in &args {
        if std::mem::take(&mut skip_next) {
            continue;
        }
        if flag_with_value.contains(&a.as_str()) {
            skip_next = true;
        } else if !a.starts_with('-') {
            filters.push(a.clone());
        }
    }
    let selected: Vec<&NamedBody> = tests
        .iter()
        .filter(|(name, _)| {
            filters.is_empty() || filters.iter().any(|f| if exact { name == f } else { name.contains(f.as_str()) })
        })
        .collect();
    if args.iter().any(|a| a == "--list") {
        for (name, _) in &selected {
            println!("{name}: test");
        }
        return std::process::ExitCode::SUCCESS;
    }
    if args.iter().any(|a| a == "--ignored") {
        println!("\nrunning 0 tests\n\ntest result: ok. 0 passed; 0 failed; 0 skipped\n");
        return std::process::ExitCode::SUCCESS;
    }
    println!("\nrunning {} tests", selected.len());
    let status = adapter_status();
    let (mut passed, mut failed, mut skipped, mut unsupported) = (Vec::new(), Vec::new(), 0usize, 0usize);
    for (name, body) in selected {
        let outcome = match &status {
            Err(reason) if !adapter_required() => {
                println!("test {name} ... SKIPPED (no GPU adapter: {reason})");
                skipped += 1;
                continue;
            }
            Err(reason) => Err(format!("no usable GPU adapter, and CI=true or {REQUIRE_ENV}=1 requires one: {reason}")),
            Ok(()) => {
                SKIP_REASON.with(|r| r.borrow_mut().take());
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(body)).map_err(|e| {
                    e.downcast_ref::<String>()
                        .cloned()
                        .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                        .unwrap_or_else(|| "panicked".into())
                })
            }
        };
        let skip_reason = SKIP_REASON.with(|r| r.borrow_mut().take());
        match outcome {
            Ok(()) if skip_reason.is_some() => {
                println!("test {name} ... SKIPPED ({})", skip_reason.unwrap_or_default());
                unsupported += 1;
            }
            Ok(()) => {
                println!("test {name} ... ok");
                passed.push(name);
            }
            Err(message) => {
                println!("test {name} ... FAILED");
                failed.push((name, message));
            }
        }
    }
    if !failed.is_empty() {
        println!("\nfailures:");
        for (name, message) in &failed {
            println!("---- {name} ----\n{message}\n");
        }
    }
    let verdict = if failed.is_empty() { "ok" } else { "FAILED" };
    println!(
        "\ntest result: {verdict}. {} passed; {} failed; {skipped} skipped (no GPU adapter); {unsupported} skipped \
         (the adapter lacks a feature the test needs)\n",
        passed.len(),
        failed.len()
    );
    if skipped > 0 {
        let mut err = std::io::stderr().lock();
        let _ =
            writeln!(err, "=== {skipped} GPU tests SKIPPED: no GPU adapter (set {REQUIRE_ENV}=1 to fail instead) ===");
    }
    if failed.is_empty() { std::process::ExitCode::SUCCESS } else { std::process::ExitCode::FAILURE }
}
