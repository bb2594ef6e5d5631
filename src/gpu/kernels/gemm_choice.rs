//! The GEMM choice recorded per adapter by `dpr-gpu bench --gemm-sweep`: the fastest [`GemmVariant`] (and, for
//! `fast` and `coop_f16`, tile shape) it measured, kept in a small JSON file ([`choice_file`]: `gemm_choice.json` in
//! [`CACHE_DIR_ENV`], else `$XDG_CACHE_HOME/dpr-gpu`, else `$HOME/.cache/dpr-gpu`) under a key naming the adapter,
//! its backend and its driver ([`adapter_key`]). [`super::gemm::select`] takes the recorded choice for its adapter
//! when there is one the device can run, unless [`super::gemm::GEMM_ENV`] asks for a variant.
//!
//! The file is written atomically (temp file + rename, [`crate::io::write_atomic`]), read only up to
//! [`MAX_FILE_BYTES`] and [`MAX_ENTRIES`] adapters; a file that is too large, unreadable or not the expected JSON
//! is ignored with a warning on stderr (and replaced by the next sweep). Deleting it restores the automatic rule.

use super::dense_coop_f16::CoopTile;
use super::dense_fast::FastTile;
use crate::error::{Error, Result};
pub use crate::gpu::device::cache_dir::{CACHE_DIR_ENV, cache_dir_from};
use crate::gpu::device::features::GemmVariant;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// The file's name in the cache directory.
pub const FILE_NAME: &str = "gemm_choice.json";
/// The `schema` field of the file.
pub const SCHEMA: &str = "dpr-gpu-gemm-choice/1";
/// Larger files are ignored (with a warning) rather than read.
pub const MAX_FILE_BYTES: u64 = 64 * 1024;
/// Most adapters the file keeps (the oldest records are dropped when a new one would pass it); a file with
/// more is ignored.
pub const MAX_ENTRIES: usize = 64;
/// Longest adapter key kept (longer driver strings are cut).
const MAX_KEY_CHARS: usize = 400;

/// A GEMM kernel and its tile shape: [`GemmChoice::tile`] applies to [`GemmVariant::Fast`] and
/// [`GemmChoice::coop`] to [`GemmVariant::CoopF16`] (each the default otherwise).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GemmChoice {
    /// The kernel.
    pub variant: GemmVariant,
    /// The fast kernel's tile shape.
    pub tile: FastTile,
    /// The cooperative-matrix kernel's tile shape.
    pub coop: CoopTile,
}

impl GemmChoice {
    /// `variant` with the default tiles.
    pub fn of(variant: GemmVariant) -> GemmChoice {
        GemmChoice { variant, tile: FastTile::DEFAULT, coop: CoopTile::DEFAULT }
    }

    /// `fast` at `tile`.
    pub fn fast(tile: FastTile) -> GemmChoice {
        GemmChoice { tile, ..GemmChoice::of(GemmVariant::Fast) }
    }

    /// `coop_f16` at `coop`.
    pub fn coop(coop: CoopTile) -> GemmChoice {
        GemmChoice { coop, ..GemmChoice::of(GemmVariant::CoopF16) }
    }

    /// The name of the tile shape that runs (`128x128`, `64x64/4sg`; the portable kernel's fixed `64x64`).
    pub fn tile_name(&self) -> String {
        match self.variant {
            GemmVariant::Fast => self.tile.name(),
            GemmVariant::CoopF16 => self.coop.name(),
            GemmVariant::Portable => {
                let (m, n) = self.variant.tile();
                format!("{m}x{n}")
            }
        }
    }

    /// `fast 64x128`, `coop_f16 128x128/8sg`, `portable`.
    pub fn name(&self) -> String {
        match self.variant {
            GemmVariant::Portable => self.variant.name().to_string(),
            v => format!("{v} {}", self.tile_name()),
        }
    }
}

/// One adapter's record in the file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// [`GemmVariant::name`].
    pub variant: String,
    /// [`FastTile::name`] for `fast`, [`CoopTile::name`] for `coop_f16`, the fast default's name for
    /// `portable` (and, in records written before the cooperative kernel had tile shapes, for `coop_f16`).
    pub tile: String,
    /// The throughput that made it the choice (GFLOP/s over the swept shapes).
    pub gflops: f64,
    /// When it was recorded (seconds since the Unix epoch): the oldest go first past [`MAX_ENTRIES`].
    pub recorded_unix: u64,
}

impl Entry {
    /// The choice it records, or `None` when it names no known variant or tile. A `coop_f16` record naming a
    /// fast tile (as written before the cooperative kernel had tile shapes) is its default shape.
    pub fn choice(&self) -> Option<GemmChoice> {
        let variant = GemmVariant::parse(&self.variant).ok().flatten()?;
        match variant {
            GemmVariant::CoopF16 => {
                let older = || FastTile::parse(&self.tile).map(|_| CoopTile::DEFAULT);
                Some(GemmChoice::coop(CoopTile::parse(&self.tile).or_else(older)?))
            }
            _ => Some(GemmChoice { tile: FastTile::parse(&self.tile)?, ..GemmChoice::of(variant) }),
        }
    }
}

/// The whole file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChoiceFile {
    /// [`SCHEMA`].
    pub schema: String,
    /// Adapter key ([`adapter_key`]) -> record.
    pub adapters: BTreeMap<String, Entry>,
}

/// The choice file of this process's environment, or `None` without any of the directories' variables.
pub fn choice_file() -> Option<PathBuf> {
    crate::gpu::device::cache_dir::cache_dir().map(|d| d.join(FILE_NAME))
}

/// The key of an adapter: its name, backend and driver (`driver` and `driver_info`), which a driver update
/// changes (so a new driver is measured again).
pub fn adapter_key(info: &wgpu::AdapterInfo) -> String {
    let key = format!("{} | {:?} | {} | {}", info.name, info.backend, info.driver, info.driver_info);
    key.chars().take(MAX_KEY_CHARS).collect()
}

/// The file at `path`: `Ok(None)` when it does not exist, `Err` (the reason, naming the file) when it cannot be
/// used: unreadable, over [`MAX_FILE_BYTES`], not the schema's JSON, or over [`MAX_ENTRIES`] adapters.
pub fn read(path: &Path) -> std::result::Result<Option<ChoiceFile>, String> {
    let file = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(format!("{}: {e}", path.display())),
    };
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES + 1).read_to_end(&mut bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(format!("{}: larger than {MAX_FILE_BYTES} bytes", path.display()));
    }
    let parsed: ChoiceFile =
        serde_json::from_slice(&bytes).map_err(|e| format!("{}: not a GEMM choice file: {e}", path.display()))?;
    if parsed.schema != SCHEMA {
        return Err(format!("{}: schema '{}', expected '{SCHEMA}'", path.display(), parsed.schema));
    }
    if parsed.adapters.len() > MAX_ENTRIES {
        return Err(format!("{}: {} adapters, at most {MAX_ENTRIES}", path.display(), parsed.adapters.len()));
    }
    Ok(Some(parsed))
}

/// [`read`], a file that cannot be used reported on stderr and taken as empty.
pub fn read_or_warn(path: &Path) -> ChoiceFile {
    match read(path) {
        Ok(file) => file.unwrap_or_default(),
        Err(why) => {
            eprintln!("warning: ignoring the recorded GEMM choice: {why}");
            ChoiceFile::default()
        }
    }
}

/// The choice recorded for `key` in the file at `path` (`None`: no file, no record, or a record naming no
/// known variant or tile; an unusable file is reported on stderr).
pub fn lookup(path: &Path, key: &str) -> Option<GemmChoice> {
    read_or_warn(path).adapters.get(key).and_then(Entry::choice)
}

/// Records `choice` for `key` in the file at `path` (its directory created), keeping the other adapters' records
/// (at most [`MAX_ENTRIES`] in all, the oldest dropped); an unusable existing file is replaced. Written
/// atomically. Errors name the file.
pub fn record(path: &Path, key: &str, choice: GemmChoice, gflops: f64) -> Result<()> {
    let mut file = read_or_warn(path);
    file.schema = SCHEMA.to_string();
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let entry = Entry {
        variant: choice.variant.name().to_string(),
        tile: match choice.variant {
            GemmVariant::CoopF16 => choice.coop.name(),
            _ => choice.tile.name(),
        },
        gflops: if gflops.is_finite() { gflops } else { 0.0 },
        recorded_unix: now,
    };
    file.adapters.insert(key.chars().take(MAX_KEY_CHARS).collect(), entry);
    while file.adapters.len() > MAX_ENTRIES {
        let oldest = file.adapters.iter().min_by_key(|(_, e)| e.recorded_unix).map(|(k, _)| k.clone());
        match oldest {
            Some(k) => file.adapters.remove(&k),
            None => break,
        };
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let text = serde_json::to_string_pretty(&file)
        .map_err(|e| Error::invalid(format!("{}: encoding the GEMM choice: {e}", path.display())))?;
    crate::io::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("dpr-gpu-gemm-choice-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_recorded_choice_reads_back_per_adapter_and_keeps_the_others() {
        let dir = temp_dir("roundtrip");
        let path = dir.join("nested").join(FILE_NAME);
        assert_eq!(read(&path), Ok(None), "no file yet");
        let fast = GemmChoice::fast(FastTile { bm: 1, bn: 2 });
        record(&path, "gpu a | Vulkan | d | 1", fast, 1234.5).unwrap();
        record(&path, "gpu b | Metal | d | 2", GemmChoice::of(GemmVariant::Portable), 10.0).unwrap();
        assert_eq!(lookup(&path, "gpu a | Vulkan | d | 1"), Some(fast));
        assert_eq!(lookup(&path, "gpu b | Metal | d | 2"), Some(GemmChoice::of(GemmVariant::Portable)));
        assert_eq!(lookup(&path, "gpu a | Vulkan | d | 2"), None, "another driver is another key");
        let file = read(&path).unwrap().unwrap();
        assert_eq!(file.schema, SCHEMA);
        assert_eq!(file.adapters["gpu a | Vulkan | d | 1"].tile, "64x128");
        assert_eq!(file.adapters["gpu a | Vulkan | d | 1"].gflops, 1234.5);
        // Re-recording replaces the adapter's record, a cooperative tile and all; no temp file is left beside it.
        let coop = GemmChoice::coop(CoopTile::ALL[4]);
        record(&path, "gpu a | Vulkan | d | 1", coop, 9.0).unwrap();
        assert_eq!(lookup(&path, "gpu a | Vulkan | d | 1"), Some(coop));
        assert_eq!(read(&path).unwrap().unwrap().adapters["gpu a | Vulkan | d | 1"].tile, "128x128/8sg");
        let names: Vec<_> =
            std::fs::read_dir(path.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from(FILE_NAME)]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn corrupt_oversized_or_unknown_files_and_records_are_ignored() {
        let dir = temp_dir("corrupt");
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(FILE_NAME);
        std::fs::write(&path, b"{\"schema\": \"dpr-gpu-gemm-choice/1\", \"adapters\": {").unwrap();
        let why = read(&path).unwrap_err();
        assert!(why.contains(FILE_NAME) && why.contains("not a GEMM choice file"), "{why}");
        assert_eq!(lookup(&path, "k"), None);
        std::fs::write(&path, vec![b' '; MAX_FILE_BYTES as usize + 1]).unwrap();
        assert!(read(&path).unwrap_err().contains("larger than"));
        std::fs::write(&path, br#"{"schema": "other/1", "adapters": {}}"#).unwrap();
        assert!(read(&path).unwrap_err().contains("schema"));
        // A record naming an unknown variant or tile is no choice.
        let text = r#"{"schema": "dpr-gpu-gemm-choice/1", "adapters": {
            "a": {"variant": "tensor", "tile": "128x128", "gflops": 1, "recorded_unix": 0},
            "b": {"variant": "fast", "tile": "512x512", "gflops": 1, "recorded_unix": 0}}}"#;
        std::fs::write(&path, text).unwrap();
        assert_eq!(lookup(&path, "a"), None);
        assert_eq!(lookup(&path, "b"), None);
        // A cooperative record names a cooperative tile, or the fast default as older versions wrote; a fast
        // record does not take a cooperative tile.
        let text = r#"{"schema": "dpr-gpu-gemm-choice/1", "adapters": {
            "old": {"variant": "coop_f16", "tile": "128x128", "gflops": 1, "recorded_unix": 0},
            "new": {"variant": "coop_f16", "tile": "128x64/4sg", "gflops": 1, "recorded_unix": 0},
            "bad": {"variant": "coop_f16", "tile": "256x256/4sg", "gflops": 1, "recorded_unix": 0},
            "mixed": {"variant": "fast", "tile": "64x64/4sg", "gflops": 1, "recorded_unix": 0}}}"#;
        std::fs::write(&path, text).unwrap();
        assert_eq!(lookup(&path, "old"), Some(GemmChoice::of(GemmVariant::CoopF16)));
        assert_eq!(lookup(&path, "new"), Some(GemmChoice::coop(CoopTile::ALL[1])));
        assert_eq!(lookup(&path, "bad"), None);
        assert_eq!(lookup(&path, "mixed"), None);
        // A corrupt file is replaced by the next record.
        std::fs::write(&path, b"\xff\xfe garbage").unwrap();
        record(&path, "k", GemmChoice::of(GemmVariant::Fast), 1.0).unwrap();
        assert_eq!(lookup(&path, "k"), Some(GemmChoice::of(GemmVariant::Fast)));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_file_keeps_at_most_max_entries_dropping_the_oldest() {
        let dir = temp_dir("bounded");
        let path = dir.join(FILE_NAME);
        let mut file = ChoiceFile { schema: SCHEMA.into(), adapters: BTreeMap::new() };
        for i in 0..MAX_ENTRIES {
            let e =
                Entry { variant: "fast".into(), tile: "128x128".into(), gflops: 1.0, recorded_unix: 100 + i as u64 };
            file.adapters.insert(format!("k{i:03}"), e);
        }
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(&path, serde_json::to_string(&file).unwrap()).unwrap();
        record(&path, "new", GemmChoice::of(GemmVariant::Portable), 1.0).unwrap();
        let back = read(&path).unwrap().unwrap();
        assert_eq!(back.adapters.len(), MAX_ENTRIES);
        assert!(!back.adapters.contains_key("k000") && back.adapters.contains_key("new"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
