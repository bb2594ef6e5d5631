//! Device acquisition for GPU tests and benchmarks, with the missing-adapter policy in one place.
//!
//! Without a usable adapter: when `CI=true` or `DPR_GPU_REQUIRE_ADAPTER=1`, [`gpu_or_skip`] panics with
//! the reason (CI never skips silently); otherwise it prints a loud `SKIPPED (no GPU adapter)` line to the
//! real stderr (not captured by the test harness) and returns `None`, and the caller returns early.
//!
//! The backend is `DPR_GPU_BACKEND` / `WGPU_BACKEND` when set, else Vulkan only: without a Vulkan driver
//! wgpu would otherwise pick a GL adapter, which is not what CI means to test (lavapipe is Vulkan).

use super::Gpu;
use super::context::{self, GpuContext};
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
