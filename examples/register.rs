//! Registers two scans with the built-in weights and prints `target_from_source` (p_target = T p_source).
//!
//! cargo run --release --example register -- examples/pair/cloud_bin_1.ply examples/pair/cloud_bin_0.ply
use dpr_gpu::io::{LoadOptions, read_cloud};
use dpr_gpu::{Matrix4, RegistrationSettings, register};
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    let [source_path, target_path] = paths.as_slice() else {
        return Err("usage: register SOURCE TARGET".into());
    };
    let (source, _) = read_cloud(Path::new(source_path), &LoadOptions::default())?;
    let (target, _) = read_cloud(Path::new(target_path), &LoadOptions::default())?;
    // The CLI's defaults: built-in weights, backend auto (a GPU if there is one), progressive keypoints, RelativeNet.
    let settings = RegistrationSettings::default();
    let result = register(&source, &target, &settings)?;
    let target_from_source: Matrix4<f64> = result.estimate.target_from_source;
    println!("translation: {:?}", target_from_source.fixed_view::<3, 1>(0, 3).as_slice());
    println!("{result}"); // the 4x4 matrix as plain rows, its support and the verdict
    Ok(())
}
