//! The bottom of the GPU path, which knows no kernel: the device and its error scopes ([`context`]), the
//! features requested when it is created ([`features`]), typed buffers and readback ([`buffer`]), the kernel
//! trait and its compiled form ([`kernel`]), batched dispatch ([`recorder`]), and the composition of a kernel's WGSL from shared modules
//! ([`wgsl`]).

pub mod buffer;
pub mod context;
pub mod features;
pub mod kernel;
pub mod recorder;
pub mod wgsl;
