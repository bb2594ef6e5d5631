//! Typed storage buffers: upload, sentinel fill, readback through a staging buffer, and a [`Workspace`] of
//! named buffers that are created once and reused (grown when a call needs more). Every host-to-device write
//! goes through [`write`], which counts the bytes on the context ([`GpuContext::transfers`]).
//!
//! Readbacks are futures: a browser cannot block on the GPU, so a mapping is awaited ([`map_staging`]). Natively
//! the device is polled to completion first and the future is ready when awaited; `crate::block_on` runs it.

use super::context::GpuContext;
use crate::error::{Error, Result};
use bytemuck::Pod;
use std::collections::HashMap;
use std::marker::PhantomData;

/// Usage of every storage buffer: bindable, and a copy source and destination (upload, readback).
pub const STORAGE_USAGE: wgpu::BufferUsages =
    wgpu::BufferUsages::STORAGE.union(wgpu::BufferUsages::COPY_SRC).union(wgpu::BufferUsages::COPY_DST);

/// Bytes of a buffer holding `bytes` of data: at least 16 (empty arrays still bind), a multiple of 4.
pub fn padded_size(bytes: u64) -> u64 {
    bytes.max(16).next_multiple_of(4)
}

/// Creates a storage buffer of `bytes` (padded), checking it against the chunking cap.
pub fn storage_buffer(ctx: &GpuContext, label: &str, bytes: u64) -> Result<wgpu::Buffer> {
    let size = padded_size(bytes);
    if size > ctx.max_buffer_bytes() {
        return Err(Error::Gpu(format!(
            "buffer '{label}' needs {size} bytes, more than the limit of {} bytes (max_storage_buffer_binding_size, \
             max_buffer_size or {})",
            ctx.max_buffer_bytes(),
            super::context::MAX_BUFFER_ENV
        )));
    }
    Ok(ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: STORAGE_USAGE,
        mapped_at_creation: false,
    }))
}

/// Writes `data` into `buffer` at `offset` (queued before the next submission) and counts the bytes in
/// [`GpuContext::transfers`]: every host-to-device write of the crate goes through here.
pub fn write<T: Pod>(ctx: &GpuContext, buffer: &wgpu::Buffer, offset: u64, data: &[T]) {
    if data.is_empty() {
        return;
    }
    let bytes: &[u8] = bytemuck::cast_slice(data);
    ctx.queue.write_buffer(buffer, offset, bytes);
    ctx.count_upload(bytes.len() as u64);
}

/// A storage buffer of `len` elements of `T`.
#[derive(Debug)]
pub struct GpuBuffer<T: Pod> {
    buffer: wgpu::Buffer,
    len: usize,
    _element: PhantomData<T>,
}

impl<T: Pod> GpuBuffer<T> {
    /// Uploads `data`.
    pub fn from_slice(ctx: &GpuContext, label: &str, data: &[T]) -> Result<GpuBuffer<T>> {
        let buffer = storage_buffer(ctx, label, std::mem::size_of_val(data) as u64)?;
        write(ctx, &buffer, 0, data);
        Ok(GpuBuffer { buffer, len: data.len(), _element: PhantomData })
    }

    /// The wgpu buffer.
    pub fn raw(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// Elements.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no element.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Reads the contents back (after all submitted work).
    pub async fn read_back(&self, ctx: &GpuContext) -> Result<Vec<T>> {
        let bytes = read_bytes(ctx, &self.buffer, 0, (self.len * std::mem::size_of::<T>()) as u64).await?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }
}

/// Copies `size` bytes at `offset` of `buffer` into a staging buffer and reads them (after the GPU is done).
pub async fn read_bytes(ctx: &GpuContext, buffer: &wgpu::Buffer, offset: u64, size: u64) -> Result<Vec<u8>> {
    if size == 0 {
        return Ok(Vec::new());
    }
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("dpr-gpu readback"),
        size: size.next_multiple_of(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(buffer, offset, &staging, 0, Some(size.next_multiple_of(4)));
    let index = ctx.queue.submit([encoder.finish()]);
    ctx.count_readback(size.next_multiple_of(4));
    let mut bytes = map_staging(ctx, &staging, index).await?;
    bytes.truncate(size as usize);
    Ok(bytes)
}

/// Maps a `MAP_READ` buffer once `submission` is done and returns its bytes. Natively the device is polled until
/// the submission is done, which runs the mapping's callback, so the future is ready when awaited; in a browser
/// the poll returns at once and the page's event loop completes the mapping while the future waits.
pub async fn map_staging(
    ctx: &GpuContext,
    staging: &wgpu::Buffer,
    submission: wgpu::SubmissionIndex,
) -> Result<Vec<u8>> {
    let (tx, rx) = futures_channel::oneshot::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    ctx.wait(Some(submission))?;
    rx.await
        .map_err(|_| Error::Gpu("readback callback never ran".into()))?
        .map_err(|e| Error::Gpu(format!("mapping a readback buffer: {e}")))?;
    ctx.deferred_errors("reading back")?;
    let bytes = staging.get_mapped_range(..).map_err(|e| Error::Gpu(format!("reading a mapped buffer: {e}")))?.to_vec();
    staging.unmap();
    Ok(bytes)
}

/// Named scratch buffers reused across calls. When `poison` is set, every buffer handed out is first filled
/// with that bit pattern, so a kernel that leaves an element unwritten shows up in the results.
#[derive(Debug, Default)]
pub struct Workspace {
    buffers: HashMap<&'static str, wgpu::Buffer>,
    /// Fill pattern (bits of an f32 or u32) written into each buffer when it is handed out.
    pub poison: Option<u32>,
}

impl Workspace {
    /// A buffer of at least `bytes` named `name`: the cached one when large enough, else a new one.
    pub fn buffer(&mut self, ctx: &GpuContext, name: &'static str, bytes: u64) -> Result<wgpu::Buffer> {
        let need = padded_size(bytes);
        let buffer = match self.buffers.get(name) {
            Some(b) if b.size() >= need => b.clone(),
            _ => {
                // Grow by a quarter beyond the request (within the cap) so slowly growing inputs reuse it.
                let cap = ctx.max_buffer_bytes();
                let size = if need <= cap { (need + need / 4).min(cap).next_multiple_of(4).min(cap) } else { need };
                let b = storage_buffer(ctx, name, size.max(need))?;
                self.buffers.insert(name, b.clone());
                b
            }
        };
        if let Some(bits) = self.poison {
            let pattern: Vec<u32> = vec![bits; (need / 4) as usize];
            write(ctx, &buffer, 0, &pattern);
        }
        Ok(buffer)
    }

    /// `buffer` with `data` written at offset 0.
    pub fn upload<T: Pod>(&mut self, ctx: &GpuContext, name: &'static str, data: &[T]) -> Result<wgpu::Buffer> {
        let buffer = self.buffer(ctx, name, std::mem::size_of_val(data) as u64)?;
        write(ctx, &buffer, 0, data);
        Ok(buffer)
    }

    /// Total bytes held.
    pub fn bytes(&self) -> u64 {
        self.buffers.values().map(wgpu::Buffer::size).sum()
    }
}
