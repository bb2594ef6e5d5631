//! Every figure the README and the model card state about the shipped model comes from one place,
//! `weights/figures.json`: a quote is the value followed by `<!--fig:KEY-->`, and must equal the file's value;
//! inside README.md's `<!-- figures ... -->` ... `<!-- /figures -->` regions no figure-like number (a decimal, or
//! `N / M`, or `N of M`) may appear unquoted, so the README cannot drift from the model card again.

use std::collections::BTreeMap;
use std::path::Path;

/// The documents that quote figures.
const QUOTING: &[&str] = &["README.md", "weights/README.md", "python/README.md"];

/// KEY -> value from weights/figures.json.
fn figures() -> BTreeMap<String, String> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/figures.json");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let entries = json["figures"].as_object().expect("a \"figures\" object");
    entries.iter().map(|(k, v)| (k.clone(), v["value"].as_str().expect("a string value").to_string())).collect()
}

fn read(name: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(name)).unwrap()
}

/// Every quote in `text`: (byte offset of the marker, key, the text before the marker on its line).
fn quotes(text: &str) -> Vec<(usize, String, String)> {
    let mut found = Vec::new();
    for (at, _) in text.match_indices("<!--fig:") {
        let rest = &text[at + "<!--fig:".len()..];
        let key = rest[..rest.find("-->").expect("a closed marker")].to_string();
        let line_start = text[..at].rfind('\n').map_or(0, |i| i + 1);
        found.push((at, key, text[line_start..at].to_string()));
    }
    found
}

/// `text` without its code spans and link targets (commands and paths are not figures).
fn prose(text: &str) -> String {
    let mut out = String::new();
    for (i, part) in text.split('`').enumerate() {
        if i % 2 == 0 {
            out.push_str(part);
        }
    }
    let mut cleaned = String::new();
    let mut rest = out.as_str();
    while let Some(at) = rest.find("](") {
        cleaned.push_str(&rest[..=at]);
        rest = &rest[at + 1..];
        rest = &rest[rest.find(')').map_or(rest.len(), |i| i + 1)..];
    }
    cleaned.push_str(rest);
    cleaned
}

/// Figure-like numbers in `text`: decimals (0.97; 2,150 counts too) and `N / M` or `N of M` fractions. A word
/// counts as a number when, without surrounding brackets and punctuation, it is digits, dots and commas only
/// (so `v0.20`, `2-core` or `x1000` are not figures).
fn figure_like(text: &str) -> Vec<String> {
    let words: Vec<&str> =
        text.split_whitespace().map(|w| w.trim_matches(|c: char| "()[]*,.;:!?".contains(c))).collect();
    let number = |w: &str| !w.is_empty() && w.chars().all(|c| c.is_ascii_digit() || c == '.' || c == ',');
    let mut found = Vec::new();
    for (i, w) in words.iter().enumerate() {
        if number(w) && w.contains(['.', ',']) {
            found.push(w.to_string());
        }
        if i + 2 < words.len() && number(w) && ["/", "of"].contains(&words[i + 1]) && number(words[i + 2]) {
            found.push(format!("{w} {} {}", words[i + 1], words[i + 2]));
        }
    }
    found
}

#[test]
fn every_quote_equals_the_figures_file() {
    let figures = figures();
    let mut quoted = std::collections::BTreeSet::new();
    for name in QUOTING {
        for (_, key, before) in quotes(&read(name)) {
            let value = figures.get(&key).unwrap_or_else(|| panic!("{name}: unknown figure '{key}'"));
            let before = before.trim_end_matches(['*', ' ']);
            assert!(before.ends_with(value.as_str()), "{name}: '{key}' is {value} in weights/figures.json: {before}");
            quoted.insert(key);
        }
    }
    let unquoted: Vec<_> = figures.keys().filter(|k| !quoted.contains(*k)).collect();
    assert!(unquoted.is_empty(), "figures no document quotes (remove them or quote them): {unquoted:?}");
}

#[test]
fn the_readme_states_no_figure_it_does_not_quote() {
    let readme = read("README.md");
    let regions: Vec<&str> =
        readme.split("<!-- figures").skip(1).map(|r| &r[..r.find("<!-- /figures -->").unwrap()]).collect();
    assert!(regions.len() >= 2, "README.md marks its figure regions");
    for region in regions {
        // Drop each quote (its value and marker), then look for figures left over.
        let mut text = prose(region.split_once("-->").map_or(region, |(_, body)| body));
        for (key, value) in figures() {
            text = text.replace(&format!("{value}<!--fig:{key}-->"), " ");
        }
        let left = figure_like(&text);
        assert!(left.is_empty(), "README.md states figures not quoted from weights/figures.json: {left:?}");
    }
}

#[test]
fn the_figure_finder_finds_figures() {
    assert_eq!(
        figure_like("recall 0.65 (25 / 44) and 2,150 hypotheses, 3 of 4"),
        ["0.65", "25 / 44", "2,150", "3 of 4"]
    );
    assert!(figure_like("22 pairs up to 180 degrees, 15 cm, Open3D v0.20 on a 2-core machine.").is_empty());
    assert_eq!(prose("see `--radius 0.6` and [x](docs/a1.5.md) 0.3"), "see  and [x] 0.3");
}
