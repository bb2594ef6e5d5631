//! Finding the scenes of an evaluation dataset and their ground truth.
//!
//! Accepted layouts:
//! - a folder of scene folders, each with `cloud_bin_<k>.ply` fragments, `gt.log` and (optionally) `gt.info`;
//! - a single such scene folder (or its `gt.log` file);
//! - a pairs file (`source target t00 .. t33`, p_target = T p_source, paths relative to the file, `#` comments).
//!   Its distinct files are numbered in order of first appearance (source before target on each line), and
//!   each pair becomes the gt record `i j` = `target_index source_index`, so that, as in 3DMatch, record
//!   `i j` maps j into i. Result logs for a pairs file use the same numbering.

use super::gtlog::{read_info, read_log};
use crate::error::{Error, Result};
use nalgebra::{Matrix4, Matrix6};
use serde::Serialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Which rules apply to a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Protocol {
    /// 3DMatch: fragment indices are temporal; consecutive pairs (j = i + 1) do not count for recall; success
    /// uses the gt.info information matrix.
    ThreeDMatch,
    /// A pairs file: every pair counts; success compares source-point RMSE under the estimate and the ground
    /// truth.
    PairsFile,
}

/// One ground-truth pair.
#[derive(Clone, Debug, PartialEq)]
pub struct GtEntry {
    /// Target fragment (x_i = T x_j).
    pub i: usize,
    /// Source fragment.
    pub j: usize,
    /// The pose of fragment j in fragment i's frame: x_i = i_from_j x_j.
    pub i_from_j: Matrix4<f64>,
    /// The gt.info information matrix, when known.
    pub information: Option<Matrix6<f64>>,
}

/// One scene of a dataset.
#[derive(Clone, Debug)]
pub struct SceneData {
    /// Scene name (folder or pairs-file folder name).
    pub name: String,
    /// Folder the ground truth came from.
    pub dir: PathBuf,
    /// Cloud file of each fragment index.
    pub files: Vec<PathBuf>,
    /// Ground-truth pairs, in file order.
    pub gt: Vec<GtEntry>,
    /// The rules that apply.
    pub protocol: Protocol,
    index: HashMap<(usize, usize), usize>,
}

impl SceneData {
    /// A scene from its parts (the pair index is built here).
    pub fn new(name: String, dir: PathBuf, files: Vec<PathBuf>, gt: Vec<GtEntry>, protocol: Protocol) -> SceneData {
        let index = gt.iter().enumerate().map(|(k, e)| ((e.i, e.j), k)).collect();
        SceneData { name, dir, files, gt, protocol, index }
    }

    /// The ground truth of pair (i, j), if it is in gt.log.
    pub fn lookup(&self, i: usize, j: usize) -> Option<&GtEntry> {
        self.index.get(&(i, j)).map(|&k| &self.gt[k])
    }

    /// Mutable access to the ground truth of pair (i, j).
    pub fn lookup_mut(&mut self, i: usize, j: usize) -> Option<&mut GtEntry> {
        self.index.get(&(i, j)).map(|&k| &mut self.gt[k])
    }

    /// Whether a pair counts for registration recall and precision: j - i > 1 under 3DMatch, every pair for a
    /// pairs file.
    pub fn counts_for_recall(&self, i: usize, j: usize) -> bool {
        match self.protocol {
            Protocol::ThreeDMatch => j > i + 1,
            Protocol::PairsFile => true,
        }
    }

    /// Number of fragments (the `n` written in result-log headers).
    pub fn fragment_count(&self) -> usize {
        self.files.len()
    }
}

/// Loads every scene under `path` (see the module docs for the layouts).
pub fn load_dataset(path: &Path) -> Result<Vec<SceneData>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() {
        if path.extension().is_some_and(|e| e == "log") {
            let dir = path.parent().unwrap_or(Path::new("."));
            return Ok(vec![load_scene(dir, path)?]);
        }
        return Ok(vec![load_pairs_file(path)?]);
    }
    if path.join("gt.log").is_file() {
        return Ok(vec![load_scene(path, &path.join("gt.log"))?]);
    }
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| Error::io(path, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("gt.log").is_file())
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        if path.join("pairs.txt").is_file() {
            return Ok(vec![load_pairs_file(&path.join("pairs.txt"))?]);
        }
        return Err(Error::invalid(format!(
            "{}: no scenes found (expected scene folders with gt.log, a gt.log, or a pairs.txt)",
            path.display()
        )));
    }
    dirs.iter().map(|d| load_scene(d, &d.join("gt.log"))).collect()
}

/// Every file of the dataset at `path`, to protect from a command's outputs: `path` itself when it is a file,
/// each fragment wherever it lies, and every data file in each scene's folder: clouds, `.txt`, `.log` and
/// `.info` files (the ground truth in any of its forms, such as `synth`'s poses.txt, pairs files, scan lists),
/// whatever their names. Weights, checkpoints and CSV logs written beside the data are not data.
pub fn dataset_files(path: &Path) -> Result<Vec<PathBuf>> {
    let is_data = |p: &Path| {
        let ext = p.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
        ext.is_some_and(|e| e == "log" || e == "info" || crate::io::SUPPORTED_EXTENSIONS.contains(&e.as_str()))
    };
    let mut files = Vec::new();
    if path.is_file() {
        files.push(path.to_path_buf());
    }
    for scene in load_dataset(path)? {
        if let Ok(entries) = std::fs::read_dir(&scene.dir) {
            files.extend(entries.flatten().map(|e| e.path()).filter(|p| p.is_file() && is_data(p)));
        }
        files.extend(scene.files);
    }
    Ok(files)
}

fn folder_name(dir: &Path) -> String {
    let canonical = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    canonical.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "scene".into())
}

/// A 3DMatch scene folder: gt.log (required), gt.info (optional), cloud_bin_k.ply.
pub fn load_scene(dir: &Path, log_path: &Path) -> Result<SceneData> {
    let log = read_log(log_path)?;
    let mut n = log.iter().map(|r| r.n.max(r.i + 1).max(r.j + 1)).max().unwrap_or(0);
    while dir.join(format!("cloud_bin_{n}.ply")).is_file() {
        n += 1;
    }
    let mut gt: Vec<GtEntry> =
        log.iter().map(|r| GtEntry { i: r.i, j: r.j, i_from_j: r.i_from_j, information: None }).collect();
    let info_path = log_path.with_file_name("gt.info");
    if info_path.is_file() {
        let info = read_info(&info_path)?;
        let by_pair: HashMap<(usize, usize), Matrix6<f64>> =
            info.into_iter().map(|r| ((r.i, r.j), r.information)).collect();
        for e in &mut gt {
            e.information = by_pair.get(&(e.i, e.j)).copied();
            if let Some(m) = e.information
                && (m[(0, 0)] <= 0.0 || m[(0, 0)].is_nan())
            {
                return Err(Error::parse(
                    &info_path,
                    format!("pair ({}, {})", e.i, e.j),
                    "information matrix has no points (element (1,1) must be positive)",
                ));
            }
        }
    }
    let files = (0..n).map(|k| dir.join(format!("cloud_bin_{k}.ply"))).collect();
    Ok(SceneData::new(folder_name(dir), dir.to_path_buf(), files, gt, Protocol::ThreeDMatch))
}

/// A pairs file (`source target` + 16 numbers, p_target = T p_source).
pub fn load_pairs_file(path: &Path) -> Result<SceneData> {
    let text = crate::io::read_list(path, "a pairs file")?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut files: Vec<PathBuf> = Vec::new();
    let mut ids: HashMap<String, usize> = HashMap::new();
    let mut id_of = |name: &str, files: &mut Vec<PathBuf>| {
        *ids.entry(name.to_string()).or_insert_with(|| {
            files.push(base.join(name));
            files.len() - 1
        })
    };
    let mut gt = Vec::new();
    let mut seen: HashMap<(usize, usize), usize> = HashMap::new();
    for (k, line) in text.lines().enumerate() {
        let line_no = k + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() != 18 {
            return Err(Error::parse(
                path,
                format!("line {line_no}"),
                format!("expected `source target` and 16 matrix numbers, found {} fields", fields.len()),
            ));
        }
        let mut m = Matrix4::zeros();
        for (c, f) in fields[2..].iter().enumerate() {
            let v: f64 = f.parse().ok().filter(|v: &f64| v.is_finite()).ok_or_else(|| {
                Error::parse(path, format!("line {line_no}"), format!("`{f}` is not a finite number"))
            })?;
            m[(c / 4, c % 4)] = v;
        }
        if let Some(problem) = crate::pose::rigidity_problem(&m) {
            return Err(Error::parse(path, format!("line {line_no}"), problem));
        }
        let j = id_of(fields[0], &mut files);
        let i = id_of(fields[1], &mut files);
        if let Some(first) = seen.insert((i, j), line_no) {
            return Err(Error::parse(
                path,
                format!("line {line_no}"),
                format!("duplicate pair {} -> {} (first at line {first})", fields[0], fields[1]),
            ));
        }
        gt.push(GtEntry { i, j, i_from_j: m, information: None });
    }
    if gt.is_empty() {
        return Err(Error::parse(path, "end of file", "no pairs"));
    }
    Ok(SceneData::new(folder_name(&base), base, files, gt, Protocol::PairsFile))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_files_number_files_by_first_appearance() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let id = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1";
        std::fs::write(dir.join("pairs.txt"), format!("# c\na.ply b.ply {id}\nc.ply a.ply {id}\n")).unwrap();
        let s = load_pairs_file(&dir.join("pairs.txt")).unwrap();
        assert_eq!(s.files, vec![dir.join("a.ply"), dir.join("b.ply"), dir.join("c.ply")]);
        assert_eq!((s.gt[0].i, s.gt[0].j), (1, 0));
        assert_eq!((s.gt[1].i, s.gt[1].j), (0, 2));
        assert!(s.counts_for_recall(1, 0));
        std::fs::write(dir.join("bad.txt"), format!("a.ply b.ply {id} 7\n")).unwrap();
        let e = load_pairs_file(&dir.join("bad.txt")).unwrap_err().to_string();
        assert!(e.contains("bad.txt") && e.contains("line 1"), "{e}");
    }
}
