//! A trajectory: one pose per scan, `world_from_scan[k]` (x_world = T x_scan_k), and its files: the 3DMatch /
//! Redwood trajectory `.log` (per scan a header `k k N` and the 4x4 matrix, the layout of [`crate::eval::gtlog`])
//! and `synth`'s `poses.txt` (per line `k` and 16 numbers, row-major).

use crate::error::{Error, Result};
use crate::eval::gtlog::{LogRecord, format_log, parse_log};
use crate::pose::inverse;
use nalgebra::Matrix4;
use std::path::Path;

/// One pose per scan.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    /// x_world = world_from_scan[k] x_scan_k.
    pub world_from_scan: Vec<Matrix4<f64>>,
}

impl Trajectory {
    /// Number of scans.
    pub fn len(&self) -> usize {
        self.world_from_scan.len()
    }

    /// True without scans.
    pub fn is_empty(&self) -> bool {
        self.world_from_scan.is_empty()
    }

    /// The relative pose x_i = T x_j of scans i and j (the gt.log convention).
    pub fn i_from_j(&self, i: usize, j: usize) -> Matrix4<f64> {
        inverse(&self.world_from_scan[i]) * self.world_from_scan[j]
    }

    /// The same trajectory with the world moved to the first scan's frame (world_from_scan[0] = I).
    pub fn relative_to_first(&self) -> Trajectory {
        let Some(first) = self.world_from_scan.first() else { return self.clone() };
        let first_from_world = inverse(first);
        Trajectory { world_from_scan: self.world_from_scan.iter().map(|w| first_from_world * w).collect() }
    }

    /// The text of the trajectory `.log`: per scan k a line `k k N` and world_from_scan_k.
    pub fn to_log_text(&self) -> String {
        let n = self.len();
        let records: Vec<LogRecord> = self
            .world_from_scan
            .iter()
            .enumerate()
            .map(|(k, &world_from_k)| LogRecord { i: k, j: k, n, i_from_j: world_from_k })
            .collect();
        format_log(&records)
    }

    /// Builds a trajectory from `.log` records of the form `k k N` (any order); every k in 0..N must appear
    /// once and N must agree. `path` names the file in errors.
    pub fn from_log_records(records: &[LogRecord], path: &Path) -> Result<Trajectory> {
        let n = records.len();
        let mut poses: Vec<Option<Matrix4<f64>>> = vec![None; n];
        for r in records {
            if r.i != r.j {
                return Err(Error::parse(
                    path,
                    format!("record ({}, {})", r.i, r.j),
                    "a trajectory record's header is `k k N` (the same index twice); this looks like a pairwise \
                     log",
                ));
            }
            if r.n != n || r.i >= n {
                return Err(Error::parse(
                    path,
                    format!("record ({}, {}, {})", r.i, r.j, r.n),
                    format!("the file holds {n} records, so every header must be `k k {n}` with k < {n}"),
                ));
            }
            poses[r.i] = Some(r.i_from_j);
        }
        // Duplicates are refused by the parser, so n records with distinct k < n cover every k.
        Ok(Trajectory { world_from_scan: poses.into_iter().map(|p| p.expect("every k present")).collect() })
    }

    /// Parses the text of a trajectory `.log`; `path` is only used in error messages.
    pub fn parse_log(text: &str, path: &Path) -> Result<Trajectory> {
        Trajectory::from_log_records(&parse_log(text, path)?, path)
    }

    /// Reads a trajectory `.log`.
    pub fn read_log(path: &Path) -> Result<Trajectory> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Trajectory::parse_log(&text, path)
    }

    /// Writes the trajectory `.log` atomically.
    pub fn write_log(&self, path: &Path) -> Result<()> {
        crate::io::write_atomic(path, self.to_log_text().as_bytes())
    }

    /// Parses `synth`'s `poses.txt`: per non-comment line `k` and world_from_fragment_k as 16 numbers,
    /// row-major; every k in 0..N exactly once.
    pub fn parse_poses(text: &str, path: &Path) -> Result<Trajectory> {
        let mut poses: Vec<(usize, Matrix4<f64>, usize)> = Vec::new();
        for (line, l) in text.lines().enumerate().map(|(k, l)| (k + 1, l.trim())) {
            if l.is_empty() || l.starts_with('#') {
                continue;
            }
            let at = || format!("line {line}");
            let fields: Vec<&str> = l.split_whitespace().collect();
            if fields.len() != 17 {
                return Err(Error::parse(
                    path,
                    at(),
                    format!("expected an index and 16 matrix numbers, found {} fields", fields.len()),
                ));
            }
            let k: usize =
                fields[0].parse().map_err(|_| Error::parse(path, at(), format!("`{}` is not an index", fields[0])))?;
            let mut m = Matrix4::zeros();
            for (c, f) in fields[1..].iter().enumerate() {
                let v: f64 = f.parse().map_err(|_| Error::parse(path, at(), format!("`{f}` is not a number")))?;
                m[(c / 4, c % 4)] = v;
            }
            if let Some(problem) = crate::pose::rigidity_problem(&m) {
                return Err(Error::parse(path, at(), format!("pose {k}: {problem}")));
            }
            if let Some((_, _, first)) = poses.iter().find(|(other, _, _)| *other == k) {
                return Err(Error::parse(path, at(), format!("duplicate pose {k} (first at line {first})")));
            }
            poses.push((k, m, line));
        }
        poses.sort_by_key(|(k, _, _)| *k);
        if let Some((pos, (k, _, line))) = poses.iter().enumerate().find(|(pos, (k, _, _))| pos != k) {
            return Err(Error::parse(
                path,
                format!("line {line}"),
                format!("pose {k} found but pose {pos} is missing"),
            ));
        }
        Ok(Trajectory { world_from_scan: poses.into_iter().map(|(_, m, _)| m).collect() })
    }

    /// Reads `synth`'s `poses.txt`.
    pub fn read_poses(path: &Path) -> Result<Trajectory> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Trajectory::parse_poses(&text, path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{matrix_from_parts, matrix_from_quaternion};
    use crate::rng::Rng;

    fn random_trajectory(seed: u64, n: usize) -> Trajectory {
        let mut rng = Rng::new(seed);
        Trajectory {
            world_from_scan: (0..n)
                .map(|_| {
                    let r = matrix_from_quaternion(rng.unit_quaternion());
                    let t =
                        nalgebra::Vector3::new(rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), rng.uniform(-1.0, 1.0));
                    matrix_from_parts(&r, &t)
                })
                .collect(),
        }
    }

    #[test]
    fn log_round_trip_keeps_every_pose() {
        let t = random_trajectory(1, 7);
        let text = t.to_log_text();
        assert!(text.starts_with("0\t0\t7\n"), "{text}");
        let back = Trajectory::parse_log(&text, Path::new("t.log")).unwrap();
        assert_eq!(back.len(), 7);
        for (a, b) in t.world_from_scan.iter().zip(&back.world_from_scan) {
            // %15.8e keeps 9 significant digits.
            assert!((a - b).abs().max() < 1e-8 * a.abs().max().max(1.0), "{a} vs {b}");
        }
    }

    #[test]
    fn pairwise_or_incomplete_logs_are_refused_with_the_file_name() {
        let t = random_trajectory(2, 3);
        let pairwise = t.to_log_text().replacen("1\t1\t3", "0\t1\t3", 1);
        let e = Trajectory::parse_log(&pairwise, Path::new("x/traj.log")).unwrap_err().to_string();
        assert!(e.contains("x/traj.log") && e.contains("pairwise"), "{e}");
        let wrong_n = t.to_log_text().replace("\t3\n", "\t4\n");
        assert!(Trajectory::parse_log(&wrong_n, Path::new("t.log")).is_err());
    }

    #[test]
    fn poses_file_parses_in_any_order_and_names_missing_poses() {
        let t = random_trajectory(3, 3);
        let line = |k: usize| {
            let m = &t.world_from_scan[k];
            format!("{k} {}\n", (0..16).map(|c| format!("{:e}", m[(c / 4, c % 4)])).collect::<Vec<_>>().join(" "))
        };
        let text = format!("# comment\n{}{}{}", line(2), line(0), line(1));
        let back = Trajectory::parse_poses(&text, Path::new("poses.txt")).unwrap();
        assert_eq!(back, t);
        let e = Trajectory::parse_poses(&format!("{}{}", line(0), line(2)), Path::new("p.txt")).unwrap_err();
        assert!(e.to_string().contains("pose 1 is missing"), "{e}");
        let e = Trajectory::parse_poses("0 1 2\n", Path::new("p.txt")).unwrap_err().to_string();
        assert!(e.contains("p.txt") && e.contains("line 1"), "{e}");
    }

    #[test]
    fn relative_to_first_keeps_relative_poses() {
        let t = random_trajectory(4, 4);
        let r = t.relative_to_first();
        assert!((r.world_from_scan[0] - Matrix4::identity()).abs().max() < 1e-12);
        assert!((r.i_from_j(1, 3) - t.i_from_j(1, 3)).abs().max() < 1e-9);
    }
}
