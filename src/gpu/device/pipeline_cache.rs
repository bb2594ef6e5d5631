//! The driver's pipeline cache kept across runs, where the adapter has `wgpu::Features::PIPELINE_CACHE` (wgpu
//! offers it on Vulkan): one [`PipelineCache`] per device, which every compute pipeline is created with
//! ([`super::kernel::Kernel::with_source`]), so a later process skips the driver's compilation of the pipelines
//! an earlier one compiled.
//!
//! The cache lives in the cache directory ([`super::cache_dir`]: `DPR_GPU_CACHE_DIR`, else
//! `$XDG_CACHE_HOME/dpr-gpu`, else `$HOME/.cache/dpr-gpu`), in a file named by
//! `wgpu::util::pipeline_cache_key` (the backend, vendor and device: [`cache_file`]). The driver's data are
//! wrapped in a header of ours ([`encode`]: magic, format version, length, CRC-32), because
//! `Device::create_pipeline_cache` hands them to the driver unchecked: a file is used only when it is a regular
//! file of at most [`MAX_FILE_BYTES`] whose header and checksum verify ([`read`]); anything else is ignored with
//! a one-line warning naming the file, the device starts with an empty cache (wgpu's `fallback`, which also
//! covers data from another driver version), and the file is replaced when the cache is saved.
//!
//! The cache is saved ([`PipelineCache::save`]) when the device is dropped (the end of a `register`, a
//! `Registrar` or a `Gpu`), and only when the driver's data differ from the file's: written atomically
//! ([`crate::io::write_atomic`]), never onto anything but a regular file. [`PIPELINE_CACHE_ENV`]`=0` turns the
//! cache off. A browser has no pipeline cache.

use crate::error::{Error, Result};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Environment variable that turns the pipeline cache off: `0`, `off`, `false` or `no`.
pub const PIPELINE_CACHE_ENV: &str = "DPR_GPU_PIPELINE_CACHE";
/// Larger cache files are ignored (with a warning) rather than read.
pub const MAX_FILE_BYTES: u64 = 64 << 20;
/// The first bytes of a cache file.
pub const MAGIC: [u8; 8] = *b"dprgpuPC";
/// The version of the header's layout.
pub const VERSION: u32 = 1;
/// Header bytes before the driver's data: [`MAGIC`], [`VERSION`] (u32), the data's length (u64) and their
/// CRC-32 (u32), little-endian.
pub const HEADER_BYTES: usize = 8 + 4 + 8 + 4;

/// Whether the environment leaves the cache on (see [`PIPELINE_CACHE_ENV`]).
pub fn enabled() -> bool {
    enabled_by(std::env::var(PIPELINE_CACHE_ENV).ok().as_deref())
}

/// Whether a value of [`PIPELINE_CACHE_ENV`] (`None`: unset) leaves the cache on.
pub fn enabled_by(value: Option<&str>) -> bool {
    !value.is_some_and(|v| matches!(v.trim().to_ascii_lowercase().as_str(), "0" | "off" | "false" | "no"))
}

/// The device features the cache wants from `adapter`: `PIPELINE_CACHE` where the adapter has it and the cache
/// is on (never in a browser).
pub fn device_features(adapter: &wgpu::Adapter) -> wgpu::Features {
    let wanted = !cfg!(target_arch = "wasm32") && enabled();
    if wanted { adapter.features() & wgpu::Features::PIPELINE_CACHE } else { wgpu::Features::empty() }
}

/// The cache file of the adapter `info` in this process's cache directory, or `None` when wgpu keeps no
/// cache for its backend or no cache directory is set.
pub fn cache_file(info: &wgpu::AdapterInfo) -> Option<PathBuf> {
    let name = wgpu::util::pipeline_cache_key(info)?;
    super::cache_dir::cache_dir().map(|dir| dir.join(name))
}

/// The driver's `data` with our header in front.
pub fn encode(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_BYTES + data.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(data.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(data).to_le_bytes());
    out.extend_from_slice(data);
    out
}

/// The driver's data in `bytes` (what [`encode`] wrote), or why they cannot be used.
pub fn decode(bytes: &[u8]) -> std::result::Result<&[u8], String> {
    if bytes.len() < HEADER_BYTES {
        return Err(format!("{} bytes, shorter than the {HEADER_BYTES}-byte header", bytes.len()));
    }
    let (header, data) = bytes.split_at(HEADER_BYTES);
    let word = |at: usize, n: usize| header[at..at + n].iter().rev().fold(0u64, |v, &b| (v << 8) | u64::from(b));
    if header[..8] != MAGIC {
        return Err("not a dpr-gpu pipeline cache (wrong magic)".to_string());
    }
    let version = word(8, 4);
    if version != u64::from(VERSION) {
        return Err(format!("format version {version}, expected {VERSION}"));
    }
    let length = word(12, 8);
    if length != data.len() as u64 {
        return Err(format!("the header gives {length} bytes of data, the file holds {}", data.len()));
    }
    let (stored, actual) = (word(20, 4), u64::from(crc32fast::hash(data)));
    if stored != actual {
        return Err(format!("checksum mismatch (CRC-32 {actual:08x}, the header says {stored:08x})"));
    }
    Ok(data)
}

/// The driver's data in the cache file at `path`: `Ok(None)` when there is no file, `Err` (the reason, naming
/// the file) when it cannot be used: not a regular file, unreadable, over [`MAX_FILE_BYTES`], or failing
/// [`decode`].
pub fn read(path: &Path) -> std::result::Result<Option<Vec<u8>>, String> {
    let named = |why: String| format!("{}: {why}", path.display());
    // Checked before opening: opening a FIFO would block until a writer comes.
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => return Err(named("not a regular file".to_string())),
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(named(e.to_string())),
    }
    let file = std::fs::File::open(path).map_err(|e| named(e.to_string()))?;
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES + 1).read_to_end(&mut bytes).map_err(|e| named(e.to_string()))?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(named(format!("larger than {MAX_FILE_BYTES} bytes")));
    }
    let data = decode(&bytes).map_err(named)?;
    Ok(Some(data.to_vec()))
}

/// Writes `data` (the driver's) to `path` with our header, atomically, its directory created; refuses to write
/// onto anything but a regular file. Errors name the file.
pub fn write(path: &Path, data: &[u8]) -> Result<()> {
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        let why = std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a regular file; not replacing it");
        return Err(Error::io(path, why));
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    crate::io::write_atomic(path, &encode(data))
}

/// A device's pipeline cache and the file it is kept in.
#[derive(Debug)]
pub struct PipelineCache {
    cache: wgpu::PipelineCache,
    path: PathBuf,
    /// Length and CRC-32 of the data the file holds (as read or last written): unchanged data are not rewritten.
    on_disk: Mutex<Option<(usize, u32)>>,
}

impl PipelineCache {
    /// The cache of `device` (whose features are `features`, on the adapter `info`), filled from its file when
    /// that file can be used (else a warning naming it, and an empty cache). `None` when the device lacks
    /// `PIPELINE_CACHE`, the cache is off ([`PIPELINE_CACHE_ENV`]), there is no cache file for this adapter
    /// ([`cache_file`]), or in a browser.
    pub fn open(device: &wgpu::Device, info: &wgpu::AdapterInfo, features: wgpu::Features) -> Option<PipelineCache> {
        if cfg!(target_arch = "wasm32") || !features.contains(wgpu::Features::PIPELINE_CACHE) || !enabled() {
            return None;
        }
        PipelineCache::open_at(device, cache_file(info)?)
    }

    /// [`PipelineCache::open`] with the file at `path`, on a device with `PIPELINE_CACHE`.
    pub fn open_at(device: &wgpu::Device, path: PathBuf) -> Option<PipelineCache> {
        let data = read(&path).unwrap_or_else(|why| {
            eprintln!("warning: ignoring the pipeline cache: {why}");
            None
        });
        let on_disk = data.as_ref().map(|d| (d.len(), crc32fast::hash(d)));
        let cache = match create(device, data.as_deref()) {
            Ok(cache) => cache,
            Err(why) => {
                // wgpu refuses data it can tell are another device's even with `fallback`: start empty.
                eprintln!("warning: ignoring the pipeline cache: {}: {why}", path.display());
                create(device, None).ok()?
            }
        };
        Some(PipelineCache { cache, path, on_disk: Mutex::new(on_disk) })
    }

    /// The wgpu cache pipelines are created with.
    pub fn wgpu(&self) -> &wgpu::PipelineCache {
        &self.cache
    }

    /// The file the cache is kept in.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes the driver's data to the file when they differ from what it holds; `Ok(true)` when it was
    /// written. Errors name the file.
    pub fn save(&self) -> Result<bool> {
        let Some(data) = self.cache.get_data() else { return Ok(false) };
        let fingerprint = Some((data.len(), crc32fast::hash(&data)));
        let mut on_disk = self.on_disk.lock().unwrap_or_else(|e| e.into_inner());
        if data.is_empty() || *on_disk == fingerprint {
            return Ok(false);
        }
        write(&self.path, &data)?;
        *on_disk = fingerprint;
        Ok(true)
    }
}

impl Drop for PipelineCache {
    fn drop(&mut self) {
        if let Err(e) = self.save() {
            eprintln!("warning: the pipeline cache was not saved: {e}");
        }
    }
}

/// A pipeline cache on `device` from `data`, or the device's validation error.
fn create(device: &wgpu::Device, data: Option<&[u8]>) -> std::result::Result<wgpu::PipelineCache, String> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    // SAFETY: `data` come from `PipelineCache::get_data` of an earlier device on an adapter with the same
    // `pipeline_cache_key` (the file is named by it), through a file whose header, length and CRC-32 verified
    // (`read`); wgpu checks its own header of the data and the driver's version before using them, and falls back
    // to an empty cache where they are outdated (`fallback: true`).
    let cache = unsafe {
        device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
            label: Some("dpr-gpu pipeline cache"),
            data,
            fallback: true,
        })
    };
    match crate::block_on(scope.pop()) {
        None => Ok(cache),
        Some(e) => Err(e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("dpr-gpu-pipeline-cache-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn encoded_data_decode_back_and_any_damage_is_refused() {
        let data: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        let bytes = encode(&data);
        assert_eq!(bytes.len(), HEADER_BYTES + data.len());
        assert_eq!(decode(&bytes).unwrap(), &data[..]);
        assert_eq!(decode(&encode(&[])).unwrap(), &[] as &[u8]);
        // Every single flipped bit, in the header or the data, is caught.
        for at in (0..bytes.len()).step_by(37).chain(0..HEADER_BYTES) {
            let mut bad = bytes.clone();
            bad[at] ^= 0x10;
            assert!(decode(&bad).is_err(), "a flip at byte {at} went unnoticed");
        }
        let truncated = decode(&bytes[..bytes.len() - 1]).unwrap_err();
        assert!(truncated.contains("header gives 1000 bytes"), "{truncated}");
        assert!(decode(&bytes[..10]).unwrap_err().contains("shorter than"));
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(decode(&longer).is_err(), "trailing bytes");
        let mut foreign = bytes.clone();
        foreign[..8].copy_from_slice(b"WGPUCACH");
        assert!(decode(&foreign).unwrap_err().contains("magic"));
        let mut future = bytes;
        future[8] = 2;
        assert!(decode(&future).unwrap_err().contains("version 2"));
    }

    #[test]
    fn files_round_trip_and_unusable_ones_are_refused_naming_the_file() {
        let dir = temp_dir("files");
        let path = dir.join("nested").join("wgpu_pipeline_cache_vulkan_1_2");
        assert_eq!(read(&path), Ok(None), "no file yet");
        write(&path, b"driver data").unwrap();
        assert_eq!(read(&path).unwrap().as_deref(), Some(&b"driver data"[..]));
        let names: Vec<_> =
            std::fs::read_dir(path.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![path.file_name().unwrap().to_owned()], "no temp file is left");
        let name = path.display().to_string();
        std::fs::write(&path, b"garbage that is long enough to hold a header").unwrap();
        let why = read(&path).unwrap_err();
        assert!(why.starts_with(&name) && why.contains("magic"), "{why}");
        let mut truncated = encode(b"driver data");
        truncated.truncate(truncated.len() - 3);
        std::fs::write(&path, &truncated).unwrap();
        assert!(read(&path).unwrap_err().contains("the file holds 8"));
        // Oversized: refused by its length alone (the header claims it all).
        let big = std::fs::File::create(&path).unwrap();
        big.set_len(MAX_FILE_BYTES + 1).unwrap();
        let why = read(&path).unwrap_err();
        assert!(why.starts_with(&name) && why.contains("larger than"), "{why}");
        // A directory where the file should be is neither read nor replaced.
        std::fs::remove_file(&path).unwrap();
        std::fs::create_dir(&path).unwrap();
        assert!(read(&path).is_err());
        assert!(write(&path, b"x").unwrap_err().to_string().contains("not a regular file"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[cfg(unix)]
    #[test]
    fn a_fifo_is_neither_read_nor_written() {
        let dir = temp_dir("fifo");
        let path = dir.join("cache");
        let status = std::process::Command::new("mkfifo").arg(&path).status();
        if !status.is_ok_and(|s| s.success()) {
            return; // no mkfifo on this system
        }
        assert!(read(&path).unwrap_err().contains("not a regular file"), "read without blocking");
        assert!(write(&path, b"x").unwrap_err().to_string().contains("not a regular file"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_variable_turns_the_cache_off() {
        assert!(enabled_by(None));
        assert!(enabled_by(Some("1")));
        assert!(enabled_by(Some("on")));
        for off in ["0", "off", " OFF ", "false", "no"] {
            assert!(!enabled_by(Some(off)), "{off}");
        }
    }
}
