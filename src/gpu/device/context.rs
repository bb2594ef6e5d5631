//! The GPU context: instance, adapter, device and queue.
//!
//! The backend set comes from `DPR_GPU_BACKEND`, else `WGPU_BACKEND` (a comma list such as `vulkan` or
//! `metal,dx12`), else the primary backends (Vulkan, Metal, DX12; never the GL fallback, whose compute
//! support is too limited). `WGPU_ADAPTER_NAME` picks an adapter by case-insensitive substring, else
//! `DPR_GPU_ADAPTER_INDEX` by position (so identical GPUs of one machine can be told apart). The device
//! gets the adapter's own limits (so large buffers and 2-D grids can be used) after a check that the few
//! limits the kernels rely on are met; a shortfall is an [`Error::Gpu`] naming the limit. Every operation runs
//! inside validation and out-of-memory error scopes ([`GpuContext::scoped`]), so device errors come back as
//! `Error::Gpu` instead of panicking.
//!
//! Nothing here blocks in a browser: the context is requested by an async constructor ([`GpuContext::request`];
//! the native constructors run it with [`crate::block_on`]), [`GpuContext::wait`] is a no-op there, and a scope's
//! errors, which the page's event loop delivers later, surface at the next readback
//! ([`GpuContext::deferred_errors`]).

use crate::error::{Error, Result};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Environment variable that selects the wgpu backends (takes precedence over `WGPU_BACKEND`).
pub const BACKEND_ENV: &str = "DPR_GPU_BACKEND";

/// Environment variable capping the size of one GPU buffer in MiB (default [`DEFAULT_MAX_BUFFER_MIB`]);
/// work is chunked so that no buffer exceeds it.
pub const MAX_BUFFER_ENV: &str = "DPR_GPU_MAX_BUFFER_MIB";

/// Default per-buffer cap: enough for 5000 patches x 2048 points chunked, small enough for any GPU.
pub const DEFAULT_MAX_BUFFER_MIB: u64 = 128;
/// Environment variable that lets `--backend auto` take a software adapter (lavapipe, llvmpipe, WARP).
pub const ALLOW_SOFTWARE_ENV: &str = "DPR_GPU_ALLOW_SOFTWARE";

/// Environment variable that picks the adapter by position: 0 is the first hardware adapter in the driver's
/// enumeration order, then the next; software rasterisers come after every hardware adapter. On a machine with
/// several identical GPUs (which `WGPU_ADAPTER_NAME` cannot tell apart) it puts each process on its own GPU;
/// `dpr_gpu.distributed` sets it to each Ray actor's GPU id.
pub const ADAPTER_INDEX_ENV: &str = "DPR_GPU_ADAPTER_INDEX";

/// Which adapters a context may take.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterPolicy {
    /// Any adapter, software rasterisers included (`--backend gpu`: the user asked for a GPU backend).
    Any,
    /// Hardware adapters only: never one whose device type is CPU (`--backend auto`), unless
    /// [`ALLOW_SOFTWARE_ENV`] is set to 1 or `WGPU_ADAPTER_NAME` names one.
    HardwareOnly,
}

/// Reads one limit as a u64.
type LimitGetter = fn(&wgpu::Limits) -> u64;

/// Limits the kernels need, with the minimum value each needs.
const REQUIRED_LIMITS: &[(&str, LimitGetter, u64)] = &[
    ("max_bind_groups", |l| l.max_bind_groups.into(), 1),
    ("max_storage_buffers_per_shader_stage", |l| l.max_storage_buffers_per_shader_stage.into(), 6),
    ("max_uniform_buffers_per_shader_stage", |l| l.max_uniform_buffers_per_shader_stage.into(), 1),
    ("max_compute_invocations_per_workgroup", |l| l.max_compute_invocations_per_workgroup.into(), 256),
    ("max_compute_workgroup_size_x", |l| l.max_compute_workgroup_size_x.into(), 256),
    ("max_compute_workgroup_storage_size", |l| l.max_compute_workgroup_storage_size.into(), 8192),
    ("max_compute_workgroups_per_dimension", |l| l.max_compute_workgroups_per_dimension.into(), 1024),
    ("max_storage_buffer_binding_size", |l| l.max_storage_buffer_binding_size, 1 << 20),
];

/// Bytes moved between host and device, counted where buffers are written ([`super::buffer::write`]) and read
/// back ([`super::recorder`], [`super::buffer::read_bytes`]); [`GpuContext::transfers`] gives the running
/// totals and [`Transfers::since`] the traffic of a stretch of work.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Transfers {
    /// Data written from the host into storage buffers (inputs, weights, sentinel fills), in bytes.
    pub host_to_device_bytes: u64,
    /// Data copied back to the host (results; timestamp resolves excluded), in bytes.
    pub device_to_host_bytes: u64,
    /// Uniform parameter bytes written (each submission's parameter structs at their aligned offsets).
    pub uniform_bytes: u64,
}

impl Transfers {
    /// The traffic between `earlier` and `self` (both totals of the same context).
    pub fn since(self, earlier: Transfers) -> Transfers {
        Transfers {
            host_to_device_bytes: self.host_to_device_bytes.saturating_sub(earlier.host_to_device_bytes),
            device_to_host_bytes: self.device_to_host_bytes.saturating_sub(earlier.device_to_host_bytes),
            uniform_bytes: self.uniform_bytes.saturating_sub(earlier.uniform_bytes),
        }
    }
}

/// Instance, adapter, device and queue, plus the limits work is chunked by.
pub struct GpuContext {
    /// The driver's pipeline cache kept across runs ([`super::pipeline_cache`]), where the device has one;
    /// saved to its file when the context is dropped, before the device (fields drop in order).
    pipeline_cache: Option<super::pipeline_cache::PipelineCache>,
    /// The adapter the device was created on.
    pub adapter: wgpu::Adapter,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter's description.
    pub info: wgpu::AdapterInfo,
    /// The device's limits (the adapter's).
    pub limits: wgpu::Limits,
    /// Optional features enabled on the device (`TIMESTAMP_QUERY` when the adapter has it; the cooperative-matrix
    /// GEMM's `SHADER_F16 | SUBGROUP | EXPERIMENTAL_COOPERATIVE_MATRIX` when [`super::features::device_features`]
    /// asks for them).
    pub features: wgpu::Features,
    max_buffer_bytes: AtomicU64,
    uncaptured: Arc<Mutex<Vec<String>>>,
    /// Running totals of [`Transfers`]: host to device, device to host, uniform.
    transferred: [AtomicU64; 3],
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.adapter_info()).finish_non_exhaustive()
    }
}

/// The backends named by `DPR_GPU_BACKEND` / `WGPU_BACKEND`, else the primary ones.
pub fn backends_from_env() -> Result<wgpu::Backends> {
    for var in [BACKEND_ENV, "WGPU_BACKEND"] {
        if let Ok(value) = std::env::var(var) {
            return parse_backends(&value).map_err(|e| Error::Gpu(format!("{var}: {e}")));
        }
    }
    Ok(wgpu::Backends::PRIMARY)
}

/// Parses a comma list of backend names (vulkan/vk, metal/mtl, dx12/d3d12, gl/gles/opengl).
pub fn parse_backends(list: &str) -> std::result::Result<wgpu::Backends, String> {
    let mut out = wgpu::Backends::empty();
    for name in list.split(',').map(|s| s.trim().to_ascii_lowercase()).filter(|s| !s.is_empty()) {
        out |= match name.as_str() {
            "vulkan" | "vk" => wgpu::Backends::VULKAN,
            "metal" | "mtl" => wgpu::Backends::METAL,
            "dx12" | "d3d12" => wgpu::Backends::DX12,
            "gl" | "gles" | "opengl" => wgpu::Backends::GL,
            "primary" => wgpu::Backends::PRIMARY,
            other => return Err(format!("unknown backend '{other}' (expected vulkan, metal, dx12, gl or primary)")),
        };
    }
    if out.is_empty() {
        return Err(format!("no backend named in '{list}'"));
    }
    Ok(out)
}

impl GpuContext {
    /// A context on the backends from the environment ([`backends_from_env`]), on any adapter.
    pub fn new() -> Result<GpuContext> {
        GpuContext::with_policy(backends_from_env()?, AdapterPolicy::Any)
    }

    /// A context on one of `backends`, on any adapter; `Error::Gpu` when no adapter exists or one lacks a
    /// needed limit.
    pub fn with_backends(backends: wgpu::Backends) -> Result<GpuContext> {
        GpuContext::with_policy(backends, AdapterPolicy::Any)
    }

    /// A context on one of `backends` on an adapter `policy` allows (blocks: [`GpuContext::request`] awaits).
    pub fn with_policy(backends: wgpu::Backends, policy: AdapterPolicy) -> Result<GpuContext> {
        crate::block_on(GpuContext::request(backends, policy))
    }

    /// A context on one of `backends` on an adapter `policy` allows, the adapter and device awaited.
    pub async fn request(backends: wgpu::Backends, policy: AdapterPolicy) -> Result<GpuContext> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        desc.flags = wgpu::InstanceFlags::default().with_env();
        let instance = wgpu::Instance::new(desc);
        let adapter = pick_adapter(&instance, backends, policy).await?;
        let info = adapter.get_info();
        let name = format!("{} ({:?})", info.name, info.backend);
        if !adapter.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS) {
            return Err(Error::Gpu(format!("adapter {name} does not support compute shaders")));
        }
        let limits = adapter.limits();
        for (limit, get, min) in REQUIRED_LIMITS {
            let have = get(&limits);
            if have < *min {
                return Err(Error::Gpu(format!("adapter {name} has {limit} = {have}; dpr-gpu needs at least {min}")));
            }
        }
        let features = (adapter.features() & wgpu::Features::TIMESTAMP_QUERY)
            | super::features::device_features(&adapter)
            | super::pipeline_cache::device_features(&adapter);
        let experimental = if features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
            // SAFETY: wgpu marks cooperative matrices experimental (its implementation may have bugs). The feature
            // is requested only for the `dense_coop_f16` kernel, on an adapter that reports the configuration the
            // kernel uses (`features::coop_f16_support`), and `DPR_GPU_GEMM=fast|portable` keeps it off.
            unsafe { wgpu::ExperimentalFeatures::enabled() }
        } else {
            wgpu::ExperimentalFeatures::disabled()
        };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("dpr-gpu"),
                required_features: features,
                required_limits: limits.clone(),
                experimental_features: experimental,
                ..Default::default()
            })
            .await
            .map_err(|e| Error::Gpu(format!("requesting a device on {name}: {e}")))?;
        let uncaptured = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&uncaptured);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        let max_buffer_mib = std::env::var(MAX_BUFFER_ENV)
            .ok()
            .and_then(|v| v.trim().parse::<u64>().ok())
            .filter(|&v| v > 0)
            .unwrap_or(DEFAULT_MAX_BUFFER_MIB);
        let pipeline_cache = super::pipeline_cache::PipelineCache::open(&device, &info, features);
        let ctx = GpuContext {
            adapter,
            device,
            queue,
            info,
            limits,
            features,
            pipeline_cache,
            max_buffer_bytes: AtomicU64::new(0),
            uncaptured,
            transferred: Default::default(),
        };
        ctx.set_max_buffer_bytes(max_buffer_mib << 20);
        Ok(ctx)
    }

    /// One line describing the adapter: name, backend, type and driver.
    pub fn adapter_info(&self) -> String {
        let i = &self.info;
        let driver = [i.driver.as_str(), i.driver_info.as_str()]
            .iter()
            .filter(|s| !s.is_empty())
            .copied()
            .collect::<Vec<_>>()
            .join(" ");
        format!(
            "{} ({:?}, {:?}{}{})",
            i.name,
            i.backend,
            i.device_type,
            if driver.is_empty() { "" } else { ", " },
            driver
        )
    }

    /// The pipeline cache pipelines are created with, where the device keeps one across runs
    /// ([`super::pipeline_cache`]).
    pub fn pipeline_cache(&self) -> Option<&super::pipeline_cache::PipelineCache> {
        self.pipeline_cache.as_ref()
    }

    /// Largest buffer (and storage binding) the chunking may create, in bytes: the smallest of the device's
    /// `max_storage_buffer_binding_size`, `max_buffer_size` and the configured cap.
    pub fn max_buffer_bytes(&self) -> u64 {
        self.max_buffer_bytes.load(Ordering::Relaxed)
    }

    /// Sets the per-buffer cap (clamped to the device limits, rounded down to 256 bytes); tests shrink it to
    /// force chunking.
    pub fn set_max_buffer_bytes(&self, bytes: u64) {
        let device_max = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
        self.max_buffer_bytes.store((bytes.min(device_max) / 256 * 256).max(256), Ordering::Relaxed);
    }

    /// Bytes moved between host and device since the context was created.
    pub fn transfers(&self) -> Transfers {
        let [up, down, uniform] = &self.transferred;
        Transfers {
            host_to_device_bytes: up.load(Ordering::Relaxed),
            device_to_host_bytes: down.load(Ordering::Relaxed),
            uniform_bytes: uniform.load(Ordering::Relaxed),
        }
    }

    /// Counts `bytes` written into a storage buffer.
    pub(crate) fn count_upload(&self, bytes: u64) {
        self.transferred[0].fetch_add(bytes, Ordering::Relaxed);
    }

    /// Counts `bytes` read back to the host.
    pub(crate) fn count_readback(&self, bytes: u64) {
        self.transferred[1].fetch_add(bytes, Ordering::Relaxed);
    }

    /// Counts `bytes` of uniform parameters written.
    pub(crate) fn count_uniform(&self, bytes: u64) {
        self.transferred[2].fetch_add(bytes, Ordering::Relaxed);
    }

    /// Whether GPU timestamps can be taken.
    pub fn has_timestamps(&self) -> bool {
        self.features.contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Runs `f` inside validation and out-of-memory error scopes; any captured (or uncaptured) device error
    /// becomes `Error::Gpu("{what}: {error}")`. Natively the scopes' errors are known when they are popped; in a
    /// browser they arrive later, through the page's event loop, and the next readback reports them
    /// ([`GpuContext::deferred_errors`]).
    pub fn scoped<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let popped = [validation.pop(), oom.pop()];
        #[cfg(not(target_arch = "wasm32"))]
        {
            let messages: Vec<String> = popped.into_iter().flat_map(crate::block_on).map(|e| e.to_string()).collect();
            if !messages.is_empty() {
                return Err(Error::Gpu(format!("{what}: {}", messages.join("; "))));
            }
        }
        #[cfg(target_arch = "wasm32")]
        {
            let sink = Arc::clone(&self.uncaptured);
            let what = what.to_string();
            wasm_bindgen_futures::spawn_local(async move {
                for scope in popped {
                    if let Some(e) = scope.await
                        && let Ok(mut v) = sink.lock()
                    {
                        v.push(format!("{what}: {e}"));
                    }
                }
            });
        }
        self.deferred_errors(what)?;
        Ok(out)
    }

    /// The device errors reported outside a scope (and, in a browser, those of earlier scopes that have arrived
    /// since), as one `Error::Gpu("{what}: ...")`; taken, so each is reported once.
    pub fn deferred_errors(&self, what: &str) -> Result<()> {
        let messages = self.uncaptured.lock().map(|mut v| std::mem::take(&mut *v)).unwrap_or_default();
        if messages.is_empty() { Ok(()) } else { Err(Error::Gpu(format!("{what}: {}", messages.join("; ")))) }
    }

    /// Blocks until `submission` has finished (all work when `None`). In a browser there is no blocking wait: it
    /// returns at once, and readbacks await their mapping instead ([`super::buffer::map_staging`]).
    pub fn wait(&self, submission: Option<wgpu::SubmissionIndex>) -> Result<()> {
        if cfg!(target_arch = "wasm32") {
            return Ok(());
        }
        self.device
            .poll(wgpu::PollType::Wait { submission_index: submission, timeout: None })
            .map(|_| ())
            .map_err(|e| Error::Gpu(format!("waiting for the GPU: {e}")))
    }
}

/// The adapter named by `WGPU_ADAPTER_NAME`, else the default high-performance one.
async fn pick_adapter(
    instance: &wgpu::Instance,
    backends: wgpu::Backends,
    policy: AdapterPolicy,
) -> Result<wgpu::Adapter> {
    let adapters = instance.enumerate_adapters(backends).await;
    let names =
        || adapters.iter().map(|a| format!("{} ({:?})", a.get_info().name, a.get_info().backend)).collect::<Vec<_>>();
    if let Ok(wanted) = std::env::var("WGPU_ADAPTER_NAME") {
        let wanted_lc = wanted.to_lowercase();
        return adapters.iter().find(|a| a.get_info().name.to_lowercase().contains(&wanted_lc)).cloned().ok_or_else(
            || Error::Gpu(format!("WGPU_ADAPTER_NAME={wanted} matches none of the adapters {:?}", names())),
        );
    }
    let software_allowed = std::env::var(ALLOW_SOFTWARE_ENV).is_ok_and(|v| v.trim() == "1");
    let take_software = policy == AdapterPolicy::Any || software_allowed;
    if let Ok(text) = std::env::var(ADAPTER_INDEX_ENV) {
        let index: usize = text.trim().parse().map_err(|_| {
            Error::Gpu(format!("{ADAPTER_INDEX_ENV}={text} is not an adapter index (0 for the first adapter)"))
        })?;
        let types: Vec<wgpu::DeviceType> = adapters.iter().map(|a| a.get_info().device_type).collect();
        let order = adapter_order(&types, take_software);
        return order.get(index).map(|&k| adapters[k].clone()).ok_or_else(|| {
            let all = names();
            let usable: Vec<&String> = order.iter().map(|&k| &all[k]).collect();
            Error::Gpu(format!(
                "{ADAPTER_INDEX_ENV}={index} but only {} adapter(s) can be used: {usable:?}",
                usable.len()
            ))
        });
    }
    if policy == AdapterPolicy::HardwareOnly && !software_allowed {
        // The best hardware adapter: discrete, then integrated, then virtual, then other; never a CPU device.
        let rank = |t: wgpu::DeviceType| match t {
            wgpu::DeviceType::DiscreteGpu => Some(0),
            wgpu::DeviceType::IntegratedGpu => Some(1),
            wgpu::DeviceType::VirtualGpu => Some(2),
            wgpu::DeviceType::Other => Some(3),
            wgpu::DeviceType::Cpu => None,
        };
        let best = adapters.iter().filter_map(|a| Some((rank(a.get_info().device_type)?, a))).min_by_key(|(r, _)| *r);
        return best.map(|(_, a)| a.clone()).ok_or_else(|| {
            let seen = names();
            let what = if seen.is_empty() { "no adapter at all".to_string() } else { format!("only {seen:?}") };
            Error::Gpu(format!(
                "no hardware GPU adapter ({what}; software rasterisers are not used automatically: pass --backend \
                 gpu or set {ALLOW_SOFTWARE_ENV}=1 to use one)"
            ))
        });
    }
    let options = wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::from_env().unwrap_or(wgpu::PowerPreference::HighPerformance),
        ..Default::default()
    };
    instance
        .request_adapter(&options)
        .await
        .map_err(|e| Error::Gpu(format!("no GPU adapter on backends {backends:?} ({e}); adapters seen: {:?}", names())))
}

/// The adapters `ADAPTER_INDEX_ENV` counts, as indices into `types` (the enumerated adapters' device types):
/// hardware adapters in enumeration order, then software rasterisers when `take_software`.
fn adapter_order(types: &[wgpu::DeviceType], take_software: bool) -> Vec<usize> {
    let software = |t: &wgpu::DeviceType| *t == wgpu::DeviceType::Cpu;
    let hardware = (0..types.len()).filter(|&k| !software(&types[k]));
    let rasterisers = (0..types.len()).filter(|&k| take_software && software(&types[k]));
    hardware.chain(rasterisers).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adapter_indices_count_hardware_first_in_enumeration_order() {
        use wgpu::DeviceType::{Cpu, DiscreteGpu, IntegratedGpu};
        // Two identical discrete GPUs with lavapipe enumerated between them, then an integrated GPU.
        let types = [DiscreteGpu, Cpu, DiscreteGpu, IntegratedGpu];
        assert_eq!(adapter_order(&types, false), [0, 2, 3]);
        assert_eq!(adapter_order(&types, true), [0, 2, 3, 1]);
        assert_eq!(adapter_order(&[Cpu], false), Vec::<usize>::new());
        assert_eq!(adapter_order(&[Cpu], true), [0]);
    }

    #[test]
    fn backend_lists_parse_and_reject_unknown_names() {
        assert_eq!(parse_backends("vulkan").unwrap(), wgpu::Backends::VULKAN);
        assert_eq!(parse_backends(" VK , metal").unwrap(), wgpu::Backends::VULKAN | wgpu::Backends::METAL);
        assert!(parse_backends("cuda").unwrap_err().contains("cuda"));
        assert!(parse_backends(" , ").is_err());
    }
}
