//! Pruning dead channels (`dpr_gpu::model::prune`, `dpr-gpu prune`): the pruned model's codewords against the
//! whole model's (the oracle), on patches where the removed channels are dead; the channels that fire are kept;
//! the per-network widths survive a weights file.

mod common;

use dpr_gpu::model::config::NetWidths;
use dpr_gpu::model::params::{encoder_widths, head_widths, tensor_specs};
use dpr_gpu::model::prune::{Firing, Kept, codeword_channels, domain_patches, prune};
use dpr_gpu::model::{FoldNet, ModelConfig, Net, RelativeNet, Weights};
use std::process::Command;

fn small() -> ModelConfig {
    ModelConfig {
        points_per_patch: 16,
        encoder_widths: vec![12, 16, 24],
        head_widths: vec![40, 20],
        fold_widths: vec![8],
        grid: [2, 2],
        relative_widths: vec![16, 8],
        ..ModelConfig::default()
    }
}

/// Random weights in which some channels of every pruned layer can never fire: their bias is far below
/// anything their inputs reach (the inputs lie in [-1, 1] and every later layer's inputs are bounded).
fn with_dead_channels(seed: u64) -> (Weights, Vec<(String, usize)>) {
    let mut w = Weights::init(&small(), seed).unwrap();
    let mut dead = Vec::new();
    for net in ["ppf", "pc"] {
        // Codeword channel 2 is dead in both networks, 11 in PPF-FoldNet only (so it stays).
        let codeword = if net == "ppf" { [2, 11] } else { [2, 2] };
        let layers = [("encoder.0", [1, 5]), ("encoder.1", [0, 15]), ("encoder.2", [3, 4]), ("head.0", [7, 39])];
        for (layer, channels) in layers.into_iter().chain([("head.1", codeword)]) {
            let bias = w.tensors.get_mut(&format!("{net}.{layer}.bias")).unwrap();
            for c in channels {
                bias[c] = -1e4;
                dead.push((format!("{net}.{layer}"), c));
            }
        }
        // Biases that keep the other channels alive on most inputs.
        for layer in ["encoder.0", "encoder.1", "encoder.2", "head.0", "head.1"] {
            for b in w.tensors.get_mut(&format!("{net}.{layer}.bias")).unwrap() {
                if *b == 0.0 {
                    *b = 0.5;
                }
            }
        }
    }
    (w, dead)
}

/// Pruned codewords (`codeword.len()` wide) written into rows of the whole codeword's width, 0 elsewhere.
fn expand(cut: &[f32], codeword: &[usize], width: usize) -> Vec<f32> {
    let mut out = vec![0.0; cut.len() / codeword.len() * width];
    for (row, values) in out.chunks_exact_mut(width).zip(cut.chunks_exact(codeword.len())) {
        codeword.iter().zip(values).for_each(|(&c, &v)| row[c] = v);
    }
    out
}

fn assert_near(whole: &[f32], cut: &[f32], what: &str) {
    assert_eq!(whole.len(), cut.len(), "{what}");
    for (a, b) in whole.iter().zip(cut) {
        assert!((a - b).abs() <= 1e-5 * a.abs().max(1.0), "{what}: {a} vs {b}");
    }
}

#[test]
fn the_pruned_model_gives_the_whole_models_codewords_and_keeps_every_channel_that_fired() {
    let (weights, dead) = with_dead_channels(3);
    let config = weights.config.clone();
    let points = config.points_per_patch;
    let view = weights.view();
    let (mut kept, mut inputs, mut firings) = (Vec::new(), Vec::new(), Vec::new());
    for net in [Net::Ppf, Net::Pc] {
        let input = domain_patches(net, 40, points, 9);
        let f = FoldNet::from_weights(&view, net).unwrap();
        let firing = Firing::of(&f, &config, &input, 40, points);
        // The forced-dead channels never fired; a brute-force scan of the tape agrees with the record.
        let tape = f.encode_tape(&input, 40, points);
        for (layer, flags) in firing.encoder.iter().enumerate() {
            let width = flags.len();
            for (c, &fired) in flags.iter().enumerate() {
                let any = tape.encoder[layer].chunks_exact(width).any(|row| row[c] > 0.0);
                assert_eq!(fired, any, "{net:?} encoder {layer} channel {c}");
                if dead.contains(&(format!("{}.encoder.{layer}", net.prefix()), c)) {
                    assert!(!fired);
                }
            }
        }
        assert!(!firing.head[0][7] && !firing.head[0][39] && !firing.head[1][2]);
        let k = Kept::of(&firing, 1);
        assert_eq!(k.head.len(), 1, "the codeword is kept apart");
        for (flags, keep) in firing.encoder.iter().chain(&firing.head).zip(k.encoder.iter().chain(&k.head)) {
            let fired: Vec<usize> = (0..flags.len()).filter(|&c| flags[c]).collect();
            assert_eq!(keep, &fired, "align 1 keeps exactly the channels that fired");
        }
        kept.push(k);
        inputs.push(input);
        firings.push(firing);
    }
    let codeword = codeword_channels(&[&firings[0], &firings[1]], 1);
    assert!(!codeword.contains(&2) && codeword.contains(&11), "{codeword:?}");
    let pruned = prune(&weights, [&kept[0], &kept[1]], &codeword).unwrap();
    assert!(pruned.parameter_count() < weights.parameter_count());
    let pc = pruned.config.pc_widths.clone().expect("the two networks lost different channels");
    assert_eq!(pc.head.last(), Some(&codeword.len()));
    // The same tensor table as the config describes, and through a file and back.
    let specs: Vec<(String, Vec<usize>)> = tensor_specs(&pruned.config);
    for (name, shape) in &specs {
        assert_eq!(pruned.tensors[name].len(), shape.iter().product::<usize>(), "{name}");
    }
    let back = Weights::from_bytes(&pruned.to_bytes().unwrap(), "pruned").unwrap();
    assert_eq!(back, pruned);
    let pruned_view = back.view();
    let mut codewords = Vec::new();
    for (net, input) in [Net::Ppf, Net::Pc].into_iter().zip(&inputs) {
        let (whole_net, cut_net) =
            (FoldNet::from_weights(&view, net).unwrap(), FoldNet::from_weights(&pruned_view, net).unwrap());
        let (whole, cut) = (whole_net.encode(input, 40, points), cut_net.encode(input, 40, points));
        assert_near(&whole, &expand(&cut, &codeword, 20), &format!("{net:?} codewords"));
        // The decoders read the pruned codeword as the whole one.
        assert_near(&whole_net.decode(&whole, 40), &cut_net.decode(&cut, 40), &format!("{net:?} decoder"));
        codewords.push((whole, cut));
    }
    // So does RelativeNet, on pose features (PC minus PPF codewords).
    let (whole_pose, cut_pose) = (
        dpr_gpu::model::pose_feature(&codewords[1].0, &codewords[0].0),
        dpr_gpu::model::pose_feature(&codewords[1].1, &codewords[0].1),
    );
    let (a, b) = (RelativeNet::from_weights(&view).unwrap(), RelativeNet::from_weights(&pruned_view).unwrap());
    let (rows, w) = (20, codeword.len());
    let whole_out = a.forward_raw(&whole_pose[..rows * 20], &whole_pose[rows * 20..], rows);
    let cut_out = b.forward_raw(&cut_pose[..rows * w], &cut_pose[rows * w..], rows);
    assert_near(&whole_out, &cut_out, "RelativeNet");
    assert_eq!(back.tensors["relative.1.weight"], weights.tensors["relative.1.weight"]);
}

#[test]
fn alignment_pads_each_layer_with_dead_channels_and_the_codewords_stay_the_same() {
    let (weights, _) = with_dead_channels(4);
    let config = weights.config.clone();
    let points = config.points_per_patch;
    let view = weights.view();
    let firings: Vec<Firing> = [Net::Ppf, Net::Pc]
        .into_iter()
        .map(|net| {
            let input = domain_patches(net, 20, points, 1);
            Firing::of(&FoldNet::from_weights(&view, net).unwrap(), &config, &input, 20, points)
        })
        .collect();
    let kept: Vec<Kept> = firings.iter().map(|f| Kept::of(f, 8)).collect();
    let codeword = codeword_channels(&[&firings[0], &firings[1]], 8);
    assert!(codeword.len().is_multiple_of(8) || codeword.len() == 20, "{codeword:?}");
    let pruned = prune(&weights, [&kept[0], &kept[1]], &codeword).unwrap();
    for net in [Net::Ppf, Net::Pc] {
        let (enc, head) = (encoder_widths(&pruned.config, net), head_widths(&pruned.config, net));
        let whole = [&small().encoder_widths[..], &small().head_widths[..1]].concat();
        for (w, full) in enc.iter().chain(&head[..1]).zip(whole) {
            assert!(w.is_multiple_of(8) || *w == full, "{net:?}: width {w} of {full}");
        }
        let input = domain_patches(net, 12, points, 77);
        let a = FoldNet::from_weights(&view, net).unwrap().encode(&input, 12, points);
        let b = FoldNet::from_weights(&pruned.view(), net).unwrap().encode(&input, 12, points);
        assert_near(&a, &expand(&b, &codeword, 20), &format!("{net:?}"));
    }
}

#[test]
fn per_network_widths_must_share_layer_counts_and_the_codeword() {
    let ok = ModelConfig { pc_widths: Some(NetWidths { encoder: vec![8, 8, 16], head: vec![24, 20] }), ..small() };
    ok.validate().unwrap();
    assert_eq!(encoder_widths(&ok, Net::Pc), &[8, 8, 16]);
    assert_eq!(encoder_widths(&ok, Net::Ppf), &[12, 16, 24]);
    let w = Weights::init(&ok, 1).unwrap();
    assert_eq!(w.tensors["pc.head.0.weight"].len(), 24 * (8 + 8 + 16 + 16));
    assert_eq!(w.tensors["ppf.head.0.weight"].len(), 40 * (12 + 16 + 24 + 24));
    for bad in [
        NetWidths { encoder: vec![8, 16], head: vec![24, 20] },
        NetWidths { encoder: vec![8, 8, 16], head: vec![24, 21] },
        NetWidths { encoder: vec![8, 0, 16], head: vec![24, 20] },
    ] {
        let config = ModelConfig { pc_widths: Some(bad.clone()), ..small() };
        let e = config.validate().unwrap_err().to_string();
        assert!(e.contains("pc_widths"), "{bad:?}: {e}");
    }
    // Files written before the field existed (no `pc_widths`) read as one set of widths for both networks.
    let json = serde_json::to_string(&small()).unwrap();
    assert!(!json.contains("pc_widths"));
    assert_eq!(serde_json::from_str::<ModelConfig>(&json).unwrap(), small());
}

#[test]
fn the_prune_command_writes_a_smaller_model_with_the_same_codewords_and_never_over_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::tiny_dataset(dir.path());
    let (weights, _) = with_dead_channels(5);
    let input = dir.path().join("whole.safetensors");
    weights.save(&input).unwrap();
    let out = dir.path().join("pruned.safetensors");
    let run = |out: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
            .args(["prune", "--data", data.to_str().unwrap(), "--weights", input.to_str().unwrap()])
            .args([
                "--out",
                out.to_str().unwrap(),
                "--batches",
                "2",
                "--batch",
                "4",
                "--domain-patches",
                "16",
                "--align",
                "1",
            ])
            .output()
            .unwrap()
    };
    let o = run(&out);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("0 values differ"), "{stdout}");
    let pruned = Weights::load(&out).unwrap();
    assert!(pruned.parameter_count() < weights.parameter_count());
    assert!(pruned.notes["dpr_gpu.pruned"].contains("\"domain_patches\":16"), "{:?}", pruned.notes);
    // Calibrated here with domain patches the previous test never drew: the codewords still agree.
    let points = weights.config.points_per_patch;
    for net in [Net::Ppf, Net::Pc] {
        let x = domain_patches(net, 8, points, 123);
        let a = FoldNet::from_weights(&weights.view(), net).unwrap().encode(&x, 8, points);
        let b = FoldNet::from_weights(&pruned.view(), net).unwrap().encode(&x, 8, points);
        // Matching sees the same: every distance between two codewords (the removed channels were 0 in both).
        let distances = |c: &[f32], w: usize| -> Vec<f32> {
            let rows: Vec<&[f32]> = c.chunks_exact(w).collect();
            let d = |p: &[f32], q: &[f32]| p.iter().zip(q).map(|(u, v)| (u - v) * (u - v)).sum::<f32>().sqrt();
            rows.iter().flat_map(|p| rows.iter().map(|q| d(p, q))).collect()
        };
        let cut = pruned.config.codeword();
        assert!(cut <= 20);
        assert_near(&distances(&a, 20), &distances(&b, cut), &format!("{net:?} codeword distances"));
    }
    // Its input is never its output, whatever the name (a hard link is the same file).
    let link = dir.path().join("link.safetensors");
    std::fs::hard_link(&input, &link).unwrap();
    let before = std::fs::read(&input).unwrap();
    let o = run(&link);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("same file"), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(&input).unwrap(), before);
}
