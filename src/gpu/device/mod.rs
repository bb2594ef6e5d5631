//! The bottom of the GPU path, which knows no kernel: the device and its error scopes ([`context`]), the
//! features requested when it is created ([`features`]), typed buffers and readback ([`buffer`]), the kernel
//! trait and its compiled form ([`kernel`]), batched dispatch ([`recorder`]), the composition of a kernel's WGSL
//! from shared modules ([`wgsl`]), and the driver's pipeline cache kept across runs ([`pipeline_cache`], in
//! [`cache_dir`]).

pub mod buffer;
pub mod cache_dir;
pub mod context;
pub mod features;
pub mod kernel;
pub mod pipeline_cache;
pub mod recorder;
pub mod wgsl;
