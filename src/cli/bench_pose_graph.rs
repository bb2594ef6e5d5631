//! `dpr-gpu bench --pose-graph FILE`: times the pose-graph optimiser on a g2o graph, stage by stage (reading,
//! chordal initialisation, Levenberg-Marquardt from the chordal start and from the file's poses), best of
//! `--repeat` runs, with the errors reached (GTSAM's 0.5 sum e^T Omega e) and the process's peak memory.

use crate::pose_graph::chordal::chordal_poses;
use crate::pose_graph::{Init, PoseGraph, SolveOptions, read_g2o, solve};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The `schema` field of the JSON report.
pub const SCHEMA: &str = "dpr-gpu-bench-pose-graph/1";

/// What `bench --pose-graph` measured.
#[derive(Clone, Debug, Serialize)]
pub struct PoseGraphReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The graph file.
    pub file: String,
    /// Poses (vertices).
    pub poses: usize,
    /// Edges.
    pub edges: usize,
    /// Fastest parse of the file, ms.
    pub read_ms: f64,
    /// Fastest chordal initialisation, ms.
    pub chordal_ms: f64,
    /// Chordal initialisation then Levenberg-Marquardt.
    pub from_chordal: Run,
    /// Levenberg-Marquardt from the file's poses.
    pub from_file: Run,
    /// Peak resident memory of the process, MiB (Linux; `None` elsewhere).
    pub peak_rss_mib: Option<f64>,
}

/// One optimisation.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Run {
    /// Fastest wall time (initialisation included), ms.
    pub wall_ms: f64,
    /// Levenberg-Marquardt steps tried.
    pub iterations: usize,
    /// Error at the start.
    pub initial_error: f64,
    /// Error at the end.
    pub final_error: f64,
}

/// Runs the benchmark and prints a table, or the JSON report.
pub fn run(path: &Path, repeat: usize, json: bool) -> anyhow::Result<()> {
    let report = measure(path, repeat)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!(
        "pose graph {}: {} poses, {} edges, best of {} runs",
        report.file,
        report.poses,
        report.edges,
        repeat.max(1)
    );
    println!("  read            {:>10.2} ms", report.read_ms);
    println!("  chordal init    {:>10.2} ms", report.chordal_ms);
    for (name, r) in [("chordal + LM", report.from_chordal), ("file + LM", report.from_file)] {
        println!(
            "  {name:<15} {:>10.2} ms  {:>3} iterations  error {:.6} -> {:.6}",
            r.wall_ms, r.iterations, r.initial_error, r.final_error
        );
    }
    if let Some(mib) = report.peak_rss_mib {
        println!("  peak memory     {mib:>10.1} MiB");
    }
    Ok(())
}

/// Times each stage `repeat` times (at least once) and keeps the fastest.
pub fn measure(path: &Path, repeat: usize) -> anyhow::Result<PoseGraphReport> {
    let repeat = repeat.max(1);
    let mut read_ms = f64::INFINITY;
    let mut graph = None;
    for _ in 0..repeat {
        let start = Instant::now();
        graph = Some(read_g2o(path)?);
        read_ms = read_ms.min(ms(start));
    }
    let graph = graph.expect("at least one run").graph;
    let mut chordal_ms = f64::INFINITY;
    for _ in 0..repeat {
        let start = Instant::now();
        chordal_poses(&graph.world_from_node, &graph.edges, &vec![true; graph.edges.len()])?;
        chordal_ms = chordal_ms.min(ms(start));
    }
    let from_chordal = best_run(&graph, Init::Chordal, repeat)?;
    let from_file = best_run(&graph, Init::File, repeat)?;
    Ok(PoseGraphReport {
        schema: SCHEMA,
        file: path.display().to_string(),
        poses: graph.world_from_node.len(),
        edges: graph.edges.len(),
        read_ms,
        chordal_ms,
        from_chordal,
        from_file,
        peak_rss_mib: peak_rss_mib(),
    })
}

fn best_run(graph: &PoseGraph, init: Init, repeat: usize) -> anyhow::Result<Run> {
    let mut best: Option<Run> = None;
    for _ in 0..repeat {
        let start = Instant::now();
        let s = solve(graph, &SolveOptions { init, ..SolveOptions::default() })?;
        let run = Run {
            wall_ms: ms(start),
            iterations: s.iterations,
            initial_error: s.initial_error,
            final_error: s.final_error,
        };
        if best.is_none_or(|b| run.wall_ms < b.wall_ms) {
            best = Some(run);
        }
    }
    Ok(best.expect("at least one run"))
}

fn ms(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

/// VmHWM of /proc/self/status, MiB.
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}
