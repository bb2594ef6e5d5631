//! Records a batch of dispatches, copies and readbacks into one command buffer and submits it once.
//!
//! Uniform parameters of all dispatches go into one uniform buffer (slots aligned to
//! `min_uniform_buffer_offset_alignment`), bind groups are created at submit, dispatches share compute
//! passes (split only around copies), and readbacks land in one staging buffer mapped after the submission.
//! With profiling on and `TIMESTAMP_QUERY` available, the first and last pass carry timestamps and the
//! elapsed GPU time is added to [`Gpu::take_gpu_time`](crate::gpu::Gpu::take_gpu_time). The parameter bytes and
//! the bytes read back are counted on the context ([`super::context::GpuContext::transfers`]).

use super::kernel::{GpuKernel, Kernel, grid};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use wgpu::util::DeviceExt;

enum Op<'a> {
    Dispatch { kernel: &'a Kernel, params: (u64, u64), buffers: Vec<wgpu::Buffer>, grid: [u32; 2] },
    Copy { src: wgpu::Buffer, src_offset: u64, dst: wgpu::Buffer, dst_offset: u64, size: u64 },
    Clear { buffer: wgpu::Buffer },
}

/// A batch of GPU work; see the module docs.
pub struct Recorder<'a> {
    gpu: &'a Gpu,
    label: &'static str,
    params: Vec<u8>,
    ops: Vec<Op<'a>>,
    reads: Vec<(wgpu::Buffer, u64, u64)>,
}

/// Submitted work whose readbacks are not yet collected.
pub struct Pending {
    submission: wgpu::SubmissionIndex,
    staging: Option<wgpu::Buffer>,
    /// (offset in staging, size) of each read, in request order.
    reads: Vec<(u64, u64)>,
    timestamps: bool,
    label: &'static str,
}

/// The bytes of each requested read, in request order.
pub type Readback = Vec<Vec<u8>>;

impl<'a> Recorder<'a> {
    /// An empty batch; `label` names it in errors.
    pub fn new(gpu: &'a Gpu, label: &'static str) -> Recorder<'a> {
        Recorder { gpu, label, params: Vec::new(), ops: Vec::new(), reads: Vec::new() }
    }

    /// The device this batch runs on.
    pub fn gpu(&self) -> &'a Gpu {
        self.gpu
    }

    /// Dispatches `workgroups` workgroups of kernel `K` (folded into 2-D past the per-dimension limit) with
    /// `params` at binding 0 and `buffers` at bindings 1...
    pub fn dispatch<K: GpuKernel>(
        &mut self,
        params: &K::Params,
        buffers: &[&wgpu::Buffer],
        workgroups: u64,
    ) -> Result<()> {
        let kernel: &'a Kernel = self.gpu.kernels.get::<K>(&self.gpu.context)?;
        self.dispatch_on::<K>(kernel, params, buffers, workgroups)
    }

    /// [`Recorder::dispatch`] on a given pipeline of `K` (one of its generated variants, such as a tile shape
    /// of the fast GEMM); an error when `kernel` is not one of `K`'s.
    pub fn dispatch_on<K: GpuKernel>(
        &mut self,
        kernel: &'a Kernel,
        params: &K::Params,
        buffers: &[&wgpu::Buffer],
        workgroups: u64,
    ) -> Result<()> {
        if kernel.spec.name != K::NAME {
            return Err(Error::Gpu(format!("a pipeline of '{}' dispatched as '{}'", kernel.spec.name, K::NAME)));
        }
        if buffers.len() + 1 != kernel.spec.binds.len() {
            return Err(Error::Gpu(format!(
                "kernel '{}' takes {} buffers, got {}",
                kernel.spec.name,
                kernel.spec.binds.len() - 1,
                buffers.len()
            )));
        }
        if workgroups == 0 {
            return Ok(());
        }
        let grid = grid(workgroups, self.gpu.context.limits.max_compute_workgroups_per_dimension)
            .map_err(|e| Error::Gpu(format!("kernel '{}': {e}", kernel.spec.name)))?;
        let align = u64::from(self.gpu.context.limits.min_uniform_buffer_offset_alignment).max(16) as usize;
        let offset = self.params.len().next_multiple_of(align);
        self.params.resize(offset, 0);
        self.params.extend_from_slice(bytemuck::bytes_of(params));
        let size = std::mem::size_of::<K::Params>() as u64;
        self.ops.push(Op::Dispatch {
            kernel,
            params: (offset as u64, size),
            buffers: buffers.iter().map(|b| (*b).clone()).collect(),
            grid,
        });
        Ok(())
    }

    /// Copies `size` bytes between buffers (after the dispatches recorded so far).
    pub fn copy(&mut self, src: &wgpu::Buffer, src_offset: u64, dst: &wgpu::Buffer, dst_offset: u64, size: u64) {
        if size > 0 {
            self.ops.push(Op::Copy { src: src.clone(), src_offset, dst: dst.clone(), dst_offset, size });
        }
    }

    /// Fills `buffer` with zeros (after the dispatches recorded so far).
    pub fn clear(&mut self, buffer: &wgpu::Buffer) {
        self.ops.push(Op::Clear { buffer: buffer.clone() });
    }

    /// Reads `size` bytes at `offset` of `buffer` once everything recorded has run; returns the index of the
    /// read in the [`Readback`].
    pub fn read(&mut self, buffer: &wgpu::Buffer, offset: u64, size: u64) -> usize {
        self.reads.push((buffer.clone(), offset, size));
        self.reads.len() - 1
    }

    /// Submits the batch without waiting.
    pub fn submit(self) -> Result<Pending> {
        let ctx = &self.gpu.context;
        let label = self.label;
        ctx.scoped(label, || self.encode_and_submit())?
    }

    /// Submits the batch and awaits its readbacks.
    pub async fn finish(self) -> Result<Readback> {
        let gpu = self.gpu;
        self.submit()?.wait(gpu).await
    }

    fn encode_and_submit(self) -> Result<Pending> {
        let ctx = &self.gpu.context;
        let device = &ctx.device;
        ctx.count_uniform(self.params.len() as u64);
        let params = (!self.params.is_empty()).then(|| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("dpr-gpu params"),
                contents: &self.params,
                usage: wgpu::BufferUsages::UNIFORM,
            })
        });
        let runs = dispatch_runs(&self.ops);
        let timestamps = self.gpu.profiling() && ctx.has_timestamps() && !runs.is_empty();
        let query = timestamps.then(|| timestamp_query(device));

        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(self.label) });
        let mut i = 0;
        while i < self.ops.len() {
            match &self.ops[i] {
                Op::Copy { src, src_offset, dst, dst_offset, size } => {
                    encoder.copy_buffer_to_buffer(src, *src_offset, dst, *dst_offset, Some(*size));
                    i += 1;
                }
                Op::Clear { buffer } => {
                    encoder.clear_buffer(buffer, 0, None);
                    i += 1;
                }
                Op::Dispatch { .. } => {
                    let run_index = runs.iter().position(|r| r.start == i).expect("dispatch starts a run");
                    let run = runs[run_index].clone();
                    let timestamp_writes = query.as_ref().map(|(set, _)| wgpu::ComputePassTimestampWrites {
                        query_set: set,
                        beginning_of_pass_write_index: (run_index == 0).then_some(0),
                        end_of_pass_write_index: (run_index + 1 == runs.len()).then_some(1),
                    });
                    let pass = encoder
                        .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(self.label), timestamp_writes });
                    record_pass(device, pass, &self.ops[run.clone()], params.as_ref());
                    i = run.end;
                }
            }
        }

        let mut reads = self.reads;
        // What comes back to the host: every read, as copied (rounded up to 4 bytes); not the timestamps.
        ctx.count_readback(reads.iter().map(|(_, _, size)| size.next_multiple_of(4)).sum());
        if let Some((set, resolve)) = &query {
            encoder.resolve_query_set(set, 0..2, resolve, 0);
            reads.push((resolve.clone(), 0, 16));
        }
        let (staging, layout) = record_readback(device, &mut encoder, &reads);
        let submission = ctx.queue.submit([encoder.finish()]);
        Ok(Pending { submission, staging, reads: layout, timestamps: query.is_some(), label: self.label })
    }
}

/// The compute passes of `ops`: maximal runs of dispatches (copies and clears go between them).
fn dispatch_runs(ops: &[Op<'_>]) -> Vec<std::ops::Range<usize>> {
    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
    for (i, op) in ops.iter().enumerate() {
        if let Op::Dispatch { .. } = op {
            match runs.last_mut() {
                Some(r) if r.end == i => r.end = i + 1,
                _ => runs.push(i..i + 1),
            }
        }
    }
    runs
}

/// A two-entry timestamp query set (start of the first pass, end of the last) and the buffer it resolves into.
fn timestamp_query(device: &wgpu::Device) -> (wgpu::QuerySet, wgpu::Buffer) {
    let set = device.create_query_set(&wgpu::QuerySetDescriptor {
        label: Some("dpr-gpu timestamps"),
        ty: wgpu::QueryType::Timestamp,
        count: 2,
    });
    let resolve = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("dpr-gpu timestamp resolve"),
        size: 16,
        usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    (set, resolve)
}

/// Records the dispatches `ops` (one run) into `pass`: each binds its slice of the `params` uniform at
/// binding 0 and its buffers from binding 1.
fn record_pass(device: &wgpu::Device, mut pass: wgpu::ComputePass<'_>, ops: &[Op<'_>], params: Option<&wgpu::Buffer>) {
    for op in ops {
        let Op::Dispatch { kernel, params: (offset, size), buffers, grid } = op else { continue };
        let uniform = params.expect("dispatches have parameters");
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: uniform,
                offset: *offset,
                size: wgpu::BufferSize::new(*size),
            }),
        }];
        entries.extend(
            buffers
                .iter()
                .enumerate()
                .map(|(b, buf)| wgpu::BindGroupEntry { binding: b as u32 + 1, resource: buf.as_entire_binding() }),
        );
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(kernel.spec.name),
            layout: &kernel.layout,
            entries: &entries,
        });
        pass.set_pipeline(&kernel.pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.dispatch_workgroups(grid[0], grid[1], 1);
    }
}

/// Copies every read into one staging buffer (each at an 8-byte aligned offset, copied rounded up to 4 bytes);
/// returns the buffer (none when nothing is read) and each read's (offset, size) in it.
fn record_readback(
    device: &wgpu::Device,
    encoder: &mut wgpu::CommandEncoder,
    reads: &[(wgpu::Buffer, u64, u64)],
) -> (Option<wgpu::Buffer>, Vec<(u64, u64)>) {
    let mut layout = Vec::with_capacity(reads.len());
    let mut total = 0u64;
    for (_, _, size) in reads {
        layout.push((total, *size));
        total += size.next_multiple_of(8);
    }
    let staging = (total > 0).then(|| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("dpr-gpu readback"),
            size: total,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    });
    if let Some(staging) = &staging {
        for ((buffer, offset, size), (dst, _)) in reads.iter().zip(&layout) {
            if *size > 0 {
                encoder.copy_buffer_to_buffer(buffer, *offset, staging, *dst, Some(size.next_multiple_of(4)));
            }
        }
    }
    (staging, layout)
}

impl Pending {
    /// Awaits the submission and returns the bytes of each read.
    pub async fn wait(self, gpu: &Gpu) -> Result<Readback> {
        let ctx = &gpu.context;
        let Some(staging) = self.staging else {
            ctx.wait(Some(self.submission))?;
            ctx.deferred_errors(self.label)?;
            return Ok(vec![Vec::new(); self.reads.len()]);
        };
        let bytes = super::buffer::map_staging(ctx, &staging, self.submission)
            .await
            .map_err(|e| Error::Gpu(format!("{}: {e}", self.label)))?;
        let mut out: Readback = self
            .reads
            .iter()
            .map(|&(offset, size)| bytes[offset as usize..(offset + size) as usize].to_vec())
            .collect();
        if self.timestamps {
            let stamps: Vec<u64> = bytemuck::pod_collect_to_vec(&out.pop().unwrap_or_default());
            if let [start, end] = stamps[..] {
                let ns = end.saturating_sub(start) as f64 * f64::from(ctx.queue.get_timestamp_period());
                gpu.add_gpu_time(ns as u64);
            }
        }
        Ok(out)
    }
}
