//! The pose-graph optimiser on generated graphs with known poses: Levenberg-Marquardt reaches a stationary point
//! of GTSAM's error (finite-difference gradient), recovers exact poses, chordal initialisation escapes the
//! drift of the odometry, the Geman-McClure line processes ignore injected false loop closures (against the
//! clean graph's optimum), and `dpr-gpu pose-graph` reads, solves and writes g2o, refusing bad input.

mod common;

use dpr_gpu::multiway::graph::{GraphEdge, PoseGraph};
use dpr_gpu::pose::so3;
use dpr_gpu::pose::{matrix_from_parts, rigid_inverse, translation_error};
use dpr_gpu::pose_graph::g2o::{encode_g2o, read_g2o};
use dpr_gpu::pose_graph::lm::cost;
use dpr_gpu::pose_graph::se3;
use dpr_gpu::pose_graph::{Init, Kernel, SolveOptions, solve};
use dpr_gpu::rng::Rng;
use nalgebra::{Matrix4, Matrix6, Vector3, Vector6};
use std::process::Command;

fn noise(rng: &mut Rng, angle: f64, reach: f64) -> Matrix4<f64> {
    let phi = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * angle;
    let t = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * reach;
    matrix_from_parts(&so3::exp(&phi), &t)
}

/// A helix of `turns` x 20 poses (radius 5 m, 1 m per turn, facing along the path), odometry edges and loop
/// closures to the pose one turn below, measurements with `sigma` metres / `sigma` x 0.5 rad of noise. Returns
/// the true poses and the graph started from the chained odometry.
fn helix(seed: u64, turns: usize, sigma: f64) -> (Vec<Matrix4<f64>>, PoseGraph) {
    let mut rng = Rng::new(seed);
    let n = turns * 20;
    let truth: Vec<Matrix4<f64>> = (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 20.0;
            let r = so3::exp(&Vector3::new(0.05 * a.sin(), 0.0, a));
            matrix_from_parts(&r, &Vector3::new(5.0 * a.cos(), 5.0 * a.sin(), a / std::f64::consts::TAU))
        })
        .collect();
    let information = Matrix6::from_diagonal(&Vector6::new(100.0, 100.0, 100.0, 400.0, 400.0, 400.0));
    let mut edges = Vec::new();
    for k in 0..n {
        for (j, uncertain) in [(k + 1, false), (k + 20, true)] {
            if j < n {
                let i_from_j = rigid_inverse(&truth[k]) * truth[j] * noise(&mut rng, sigma * 0.5, sigma);
                edges.push(GraphEdge { i: k, j, i_from_j, information, uncertain });
            }
        }
    }
    let mut start = vec![truth[0]];
    for e in edges.iter().filter(|e| !e.uncertain) {
        let next = start[e.i] * e.i_from_j;
        start.push(next);
    }
    (truth, PoseGraph { world_from_node: start, edges })
}

/// The finite-difference gradient of the cost with respect to right perturbations of every free node.
fn numeric_gradient(graph: &PoseGraph, poses: &[Matrix4<f64>]) -> Vec<f64> {
    let h = 1e-6;
    let mut gradient = Vec::new();
    for k in 1..poses.len() {
        for c in 0..6 {
            let mut d = Vector6::zeros();
            d[c] = h;
            let mut plus = poses.to_vec();
            plus[k] = poses[k] * se3::exp(&d);
            let mut minus = poses.to_vec();
            minus[k] = poses[k] * se3::exp(&(-d));
            gradient.push((cost(&graph.edges, &plus) - cost(&graph.edges, &minus)) / (2.0 * h));
        }
    }
    gradient
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

fn ate(a: &[Matrix4<f64>], b: &[Matrix4<f64>]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| translation_error(x, y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

fn plain(init: Init) -> SolveOptions {
    SolveOptions { init, kernel: Kernel::None, ..SolveOptions::default() }
}

#[test]
fn levenberg_marquardt_reaches_a_stationary_point_of_the_gtsam_error() {
    let (_, graph) = helix(1, 4, 0.02);
    let start_gradient = max_abs(&numeric_gradient(&graph, &graph.world_from_node));
    for init in [Init::File, Init::Chordal] {
        let s = solve(&graph, &plain(init)).unwrap();
        assert_eq!(s.world_from_node[0], graph.world_from_node[0], "node 0 is fixed");
        assert!((s.final_error - cost(&graph.edges, &s.world_from_node)).abs() < 1e-9 * s.final_error);
        assert!(s.final_error < 0.01 * s.given_error, "{init:?}: {} -> {}", s.given_error, s.final_error);
        let gradient = max_abs(&numeric_gradient(&graph, &s.world_from_node));
        assert!(gradient < 1e-6 * start_gradient, "{init:?}: gradient {gradient} (start {start_gradient})");
    }
    // Both starts reach the same minimum.
    let (a, b) = (solve(&graph, &plain(Init::File)).unwrap(), solve(&graph, &plain(Init::Chordal)).unwrap());
    assert!(ate(&a.world_from_node, &b.world_from_node) < 1e-6);
}

#[test]
fn exact_measurements_give_back_the_true_poses() {
    let (truth, mut graph) = helix(2, 3, 0.0);
    // Start far from the truth: every pose but the first moved by up to a metre and 0.3 rad.
    let mut rng = Rng::new(9);
    for pose in graph.world_from_node.iter_mut().skip(1) {
        *pose *= noise(&mut rng, 0.15, 0.5);
    }
    let s = solve(&graph, &plain(Init::File)).unwrap();
    assert!(ate(&s.world_from_node, &truth) < 1e-7, "{}", ate(&s.world_from_node, &truth));
    assert!(s.final_error < 1e-12, "{}", s.final_error);
}

#[test]
fn chordal_start_escapes_the_drift_that_traps_the_odometry_start() {
    // Large rotation noise makes the chained odometry wrap far from the truth; the chordal start does not.
    let (truth, graph) = helix(3, 6, 0.05);
    let chordal = solve(&graph, &plain(Init::Chordal)).unwrap();
    let file = solve(&graph, &plain(Init::File)).unwrap();
    assert!(chordal.initial_error < 0.1 * chordal.given_error, "{} vs {}", chordal.initial_error, chordal.given_error);
    assert!(chordal.final_error <= file.final_error * (1.0 + 1e-9), "{} vs {}", chordal.final_error, file.final_error);
    let (solved, drifted) = (ate(&chordal.world_from_node, &truth), ate(&graph.world_from_node, &truth));
    assert!(solved < 0.25 * drifted, "{solved} m from the truth; the odometry chain is {drifted} m off");
}

#[test]
fn chordal_start_keeps_poses_that_already_start_lower() {
    // Poses at the optimum start lower than any relaxation: the chordal start falls back to them, says so, and
    // LM stays at the optimum; from the drifted odometry the relaxation is taken.
    let (_, graph) = helix(3, 6, 0.05);
    let first = solve(&graph, &plain(Init::Chordal)).unwrap();
    assert_eq!((first.start, first.start_note.as_deref()), (Init::Chordal, None));
    let optimised = PoseGraph { world_from_node: first.world_from_node.clone(), edges: graph.edges.clone() };
    let again = solve(&optimised, &plain(Init::Chordal)).unwrap();
    assert_eq!(again.start, Init::File);
    assert!(again.start_note.as_deref().is_some_and(|n| n.contains("start lower")), "{:?}", again.start_note);
    assert!((again.initial_error - first.final_error).abs() <= 1e-12 * first.final_error.max(1.0));
    assert!(again.final_error <= first.final_error * (1.0 + 1e-9), "{} vs {}", again.final_error, first.final_error);
}

/// `graph` with round(`fraction` x edges) false loop closures: random non-adjacent pairs, random relative poses
/// up to 5 m and any rotation, information copied from real edges.
fn with_false_loops(graph: &PoseGraph, fraction: f64, seed: u64) -> (PoseGraph, usize) {
    let mut rng = Rng::new(seed);
    let n = graph.world_from_node.len();
    let count = (fraction * graph.edges.len() as f64).round() as usize;
    let mut edges = graph.edges.clone();
    while edges.len() < graph.edges.len() + count {
        let (i, j) = (rng.below(n), rng.below(n));
        if i.abs_diff(j) <= 1 {
            continue;
        }
        let rotation = so3::exp(
            &(Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize()
                * rng.uniform(0.0, std::f64::consts::PI)),
        );
        let t = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * rng.uniform(0.0, 5.0);
        let information = graph.edges[rng.below(graph.edges.len())].information;
        edges.push(GraphEdge { i, j, i_from_j: matrix_from_parts(&rotation, &t), information, uncertain: true });
    }
    (PoseGraph { world_from_node: graph.world_from_node.clone(), edges }, count)
}

#[test]
fn geman_mcclure_ignores_injected_false_loops() {
    let (_, clean) = helix(4, 8, 0.01);
    let clean_optimum = solve(&clean, &plain(Init::File)).unwrap();
    for seed in [1, 2] {
        let (noisy, count) = with_false_loops(&clean, 0.1, seed);
        assert!(count > 20);
        let robust = SolveOptions {
            init: Init::File,
            kernel: Kernel::GemanMcClure { scale: 1.0, prune_below: 0.25 },
            ..SolveOptions::default()
        };
        let s = solve(&noisy, &robust).unwrap();
        let ate_robust = ate(&s.world_from_node, &clean_optimum.world_from_node);
        let plain_solution = solve(&noisy, &plain(Init::File)).unwrap();
        let ate_plain = ate(&plain_solution.world_from_node, &clean_optimum.world_from_node);
        assert!(ate_plain > 0.5, "seed {seed}: the false loops must matter without the kernel ({ate_plain} m)");
        assert!(ate_robust < 0.01, "seed {seed}: {ate_robust} m from the clean optimum (plain LM: {ate_plain} m)");
        let false_kept = s.weights[clean.edges.len()..].iter().filter(|&&w| w > 0.0).count();
        assert_eq!(false_kept, 0, "seed {seed}: false loops kept");
        assert!(s.weights[..clean.edges.len()].iter().all(|&w| w > 0.25), "seed {seed}: a true edge was pruned");
    }
}

fn dpr(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_dpr-gpu")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

#[test]
fn cli_solves_a_g2o_file_and_refuses_bad_input() {
    let dir = common::temp_dir("pose-graph-cli");
    let (truth, graph) = helix(5, 3, 0.01);
    let ids: Vec<u64> = (0..graph.world_from_node.len() as u64).map(|k| 10 + k).collect();
    let input = dir.join("in.g2o");
    std::fs::write(&input, encode_g2o(&graph, &ids, None)).unwrap();
    let out = dir.join("out.g2o");
    let (ok, stdout, stderr) = dpr(&["pose-graph", input.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{stdout}{stderr}");
    assert!(
        stdout.contains("60 poses, 99 edges") && stdout.contains("iterations") && stdout.contains(" s;"),
        "{stdout}"
    );
    let solved = read_g2o(&out).unwrap();
    assert_eq!(solved.ids, ids);
    let library = solve(&graph, &SolveOptions::default()).unwrap();
    assert!(ate(&solved.graph.world_from_node, &library.world_from_node) < 1e-12);
    let (before, after) =
        (cost(&graph.edges, &graph.world_from_node), cost(&graph.edges, &solved.graph.world_from_node));
    assert!(after < 0.1 * before, "error {before} -> {after}");
    assert!(ate(&solved.graph.world_from_node, &truth) < ate(&graph.world_from_node, &truth));
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(text.matches("# EDGE_WEIGHT").count(), 99);
    // Robust run: the weights of loop closures are line processes in (0, 1].
    let (ok, stdout, _) =
        dpr(&["pose-graph", input.to_str().unwrap(), "--out", out.to_str().unwrap(), "--robust", "geman-mcclure"]);
    assert!(ok && stdout.contains("file initialisation"), "{stdout}");

    // The output is never the input, even through a hard link.
    let link = dir.join("link.g2o");
    std::fs::hard_link(&input, &link).unwrap();
    let (ok, _, stderr) = dpr(&["pose-graph", input.to_str().unwrap(), "--out", link.to_str().unwrap()]);
    assert!(!ok && stderr.contains("refusing to overwrite input"), "{stderr}");
    // Bad input names the file, the line and the token.
    let bad = dir.join("bad.g2o");
    std::fs::write(&bad, "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_XYZ 1 2 3\n").unwrap();
    let (ok, _, stderr) = dpr(&["pose-graph", bad.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!ok && stderr.contains("bad.g2o: line 2: unsupported element 'VERTEX_XYZ'"), "{stderr}");
    let (ok, _, stderr) = dpr(&["pose-graph", input.to_str().unwrap(), "--out", out.to_str().unwrap(), "--init", "x"]);
    assert!(!ok && stderr.contains("unknown initialisation 'x'"), "{stderr}");
}
