//! `dpr-gpu pose-graph`: optimise a g2o pose graph (see [`crate::pose_graph`]).

use crate::io::check_outputs;
use crate::pose_graph::{Init, SolveOptions, read_g2o, solve, write_g2o};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `dpr-gpu pose-graph`.
#[derive(clap::Args, Debug)]
#[command(after_help = "Reads VERTEX_SE3:QUAT and EDGE_SE3:QUAT lines (information matrix: 21 upper-triangular \
entries, translation first); the lowest vertex id stays fixed. The error is GTSAM's: 0.5 sum e^T Omega e with \
e = Log(Z^-1 Xi^-1 Xj). OUT gets the optimised vertices (17 significant digits), the edges as read, and after each \
edge a '# EDGE_WEIGHT i j w' comment with its final weight. An edge between consecutive ids is odometry; any other \
is a loop closure, which --robust may down-weight or prune.")]
pub struct Args {
    /// The g2o file.
    pub input: PathBuf,
    /// Where to write the optimised graph (g2o; written atomically, never onto the input).
    #[arg(long, value_name = "OUT.g2o")]
    pub out: PathBuf,
    /// Robust kernel for loop closures: none or geman-mcclure (line processes).
    #[arg(long, default_value = "none", value_name = "KERNEL")]
    pub robust: String,
    /// Geman-McClure scale mu (in units of e^T Omega e): a loop closure's weight is (mu / (mu + e^T Omega e))^2.
    #[arg(long, default_value_t = 1.0, value_name = "MU")]
    pub robust_scale: f64,
    /// Loop closures whose final weight is below this are pruned (with --robust).
    #[arg(long, default_value_t = 0.25, value_name = "W")]
    pub prune_below: f64,
    /// Initial poses: chordal (rotations by chordal relaxation, then translations) or file (the vertices as
    /// read) [default: chordal; file with --robust, since wrong loop closures mislead the relaxation].
    #[arg(long, value_name = "INIT")]
    pub init: Option<String>,
}

/// The parsed options.
fn options(args: &Args) -> anyhow::Result<SolveOptions> {
    Ok(SolveOptions::from_names(&args.robust, args.robust_scale, args.prune_below, args.init.as_deref())?)
}

/// Runs `dpr-gpu pose-graph`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let started = Instant::now();
    let options = options(&args)?;
    check_outputs(&[&args.input], &[("--out", &args.out)])?;
    eprintln!("reading {}", args.input.display());
    let read = read_g2o(&args.input)?;
    let (nodes, edges) = (read.graph.world_from_node.len(), read.graph.edges.len());
    eprintln!("{nodes} poses, {edges} edges; optimising ({:?} start, kernel {})", options.init, args.robust);
    let solution = solve(&read.graph, &options)?;
    if let Some(note) = &solution.start_note {
        eprintln!("starting from the file's poses: {note}");
    }
    let graph = crate::pose_graph::PoseGraph { world_from_node: solution.world_from_node, edges: read.graph.edges };
    write_g2o(&args.out, &graph, &read.ids, Some(&solution.weights))?;
    let kept = solution.weights.iter().filter(|&&w| w > 0.0).count();
    println!(
        "pose-graph: {nodes} poses, {edges} edges ({kept} kept); {} iterations; error {:.6} at the file's poses, \
         {:.6} after {} initialisation, {:.6} final; {:.3} s; wrote {}",
        solution.iterations,
        solution.given_error,
        solution.initial_error,
        if solution.start == Init::Chordal { "chordal" } else { "file" },
        solution.final_error,
        started.elapsed().as_secs_f64(),
        args.out.display()
    );
    Ok(())
}
