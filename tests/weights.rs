//! Weights files: round trip, self-description, and errors that list every mismatch.

use dpr_gpu::Error;
use dpr_gpu::model::{ModelConfig, Weights, params::tensor_specs};
use std::collections::HashMap;

fn small() -> ModelConfig {
    ModelConfig {
        points_per_patch: 8,
        encoder_widths: vec![4, 4, 8],
        head_widths: vec![8, 6],
        fold_widths: vec![4],
        grid: [2, 2],
        relative_widths: vec![8, 4],
        ..ModelConfig::default()
    }
}

#[test]
fn round_trip_keeps_config_tensors_and_notes() {
    let mut w = Weights::init(&small(), 5).unwrap();
    w.notes.insert("trained".into(), "no".into());
    let back = Weights::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap();
    assert_eq!(back, w);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    w.save(&path).unwrap();
    assert_eq!(Weights::load(&path).unwrap(), w);
    assert_ne!(Weights::init(&small(), 6).unwrap().tensors, w.tensors);
    assert_eq!(Weights::init(&small(), 5).unwrap().tensors, w.tensors);
}

#[test]
fn the_paper_config_has_the_published_widths() {
    let c = ModelConfig::paper();
    assert_eq!(c.concat_width(), 704);
    assert_eq!(c.codeword(), 512);
    assert_eq!(c.grid_points(), 2025);
    let specs: HashMap<String, Vec<usize>> = tensor_specs(&c).into_iter().collect();
    assert_eq!(specs["ppf.encoder.0.weight"], vec![64, 4]);
    assert_eq!(specs["pc.encoder.0.weight"], vec![64, 3]);
    assert_eq!(specs["ppf.head.0.weight"], vec![512, 704]);
    assert_eq!(specs["ppf.fold1.0.weight"], vec![256, 514]);
    assert_eq!(specs["ppf.fold2.0.weight"], vec![256, 516]);
    assert_eq!(specs["pc.fold2.0.weight"], vec![256, 515]);
    assert_eq!(specs["ppf.fold2.4.weight"], vec![4, 32]);
    assert_eq!(specs["relative.0.weight"], vec![512, 1024]);
    assert_eq!(specs["relative.3.weight"], vec![4, 128]);
}

#[test]
fn wrong_shapes_missing_and_extra_tensors_are_all_reported() {
    let w = Weights::init(&small(), 1).unwrap();
    let mut bad = w.clone();
    bad.tensors.remove("pc.head.1.bias");
    bad.tensors.insert("ppf.encoder.0.weight".into(), vec![0.0; 3]);
    bad.tensors.insert("mystery".into(), vec![1.0]);
    let err = Weights::from_bytes(&bad.to_bytes().unwrap(), "bad.safetensors").unwrap_err();
    let Error::Weights { path, problems } = &err else { panic!("{err}") };
    assert_eq!(path, "bad.safetensors");
    let text = problems.join("\n");
    assert!(text.contains("missing tensor 'pc.head.1.bias'"), "{text}");
    assert!(text.contains("'ppf.encoder.0.weight' has shape [3]"), "{text}");
    assert!(text.contains("unexpected tensor 'mystery'"), "{text}");
    assert_eq!(problems.len(), 3);
}

#[test]
fn garbage_and_foreign_files_are_rejected_with_a_reason() {
    assert!(Weights::from_bytes(b"not a safetensors file", "x").unwrap_err().to_string().contains("not a safetensors"));
    let foreign = safetensors::serialize(Vec::<(String, safetensors::tensor::TensorView)>::new(), None).unwrap();
    assert!(Weights::from_bytes(&foreign, "x").unwrap_err().to_string().contains("dpr_gpu.config"));
    let w = Weights::init(&small(), 1).unwrap();
    let bytes = w.to_bytes().unwrap();
    for cut in [8, bytes.len() / 2, bytes.len() - 1] {
        assert!(Weights::from_bytes(&bytes[..cut], "cut").is_err(), "truncated at {cut}");
    }
}

/// Every weights file the project ships loads, fits the 20 MB budget, records how it was trained; the default
/// and the angle-bin models carry the head that covers all of SO(3) (normal-frame patches, angle bins), and the
/// previous default, kept for the ablation, the paper's head (fragment-frame patches, quaternion).
#[test]
fn shipped_weights_files_load_and_describe_themselves() {
    use dpr_gpu::model::config::{PoseFrame, RotationOutput};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("weights");
    let mut seen = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("safetensors") {
            continue;
        }
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        assert!(std::fs::metadata(&path).unwrap().len() <= 20 << 20, "{name} exceeds 20 MB");
        let w = Weights::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(w.notes.contains_key("dpr_gpu.train.steps"), "{name} does not record its training");
        let bins = matches!(w.config.rotation_output, RotationOutput::AngleBins { .. });
        if name.starts_with("angle-bins") || name == "default.safetensors" {
            assert!(bins && w.config.pose_frame == PoseFrame::Normal, "{name}: {:?}", w.config);
        }
        if name == "paper-head.safetensors" {
            let paper = w.config.rotation_output == RotationOutput::Quaternion;
            assert!(paper && w.config.pose_frame == PoseFrame::Fragment, "{name}: {:?}", w.config);
        }
        seen.push(name);
    }
    seen.sort();
    assert!(seen.contains(&"default.safetensors".to_string()), "{seen:?}");
    assert!(seen.contains(&"paper-head.safetensors".to_string()), "{seen:?}");
    assert_eq!(Weights::load(&dir.join("default.safetensors")).unwrap(), Weights::built_in().unwrap());
}

#[test]
fn built_in_weights_are_read_in_place_and_other_bytes_copied_the_same() {
    use dpr_gpu::model::weights::BUILT_IN_WEIGHTS;
    let view = Weights::built_in_view().unwrap();
    let owned = Weights::built_in().unwrap();
    let bytes = BUILT_IN_WEIGHTS.as_ptr_range();
    for (name, values) in &owned.tensors {
        let borrowed = view.get(name).unwrap();
        assert_eq!(borrowed, values.as_slice(), "{name}");
        // Read in place: the tensor lies inside the library's own bytes (f32-aligned there).
        let at = borrowed.as_ptr() as *const u8;
        assert!(bytes.contains(&at), "{name} was copied");
    }
    // The same bytes one byte off alignment: copied, with the same values.
    let mut shifted = vec![0u8; BUILT_IN_WEIGHTS.len() + 1];
    shifted[1..].copy_from_slice(BUILT_IN_WEIGHTS);
    let unaligned = dpr_gpu::model::WeightsView::from_bytes(&shifted[1..], "shifted").unwrap();
    let copied = unaligned.get("ppf.head.0.weight").unwrap();
    assert!(!shifted.as_ptr_range().contains(&(copied.as_ptr() as *const u8)));
    assert_eq!(unaligned.into_owned(), owned);
    // A view of owned weights builds the same model as the weights.
    assert_eq!(owned.view().into_owned(), owned);
}
