//! The library's files import only downward: the file-level import graph of src/ has no circle.
//!
//! An edge runs from a file to the file that defines the module a path names: every `crate::`, `super::` and
//! `self::` path, in `use` trees and inline (`crate::pose::rigid_inverse(..)`), resolved to the longest module
//! prefix that is a file (`src/a/b.rs` or `src/a/b/mod.rs`; the crate root is `src/lib.rs`). Not edges: a
//! parent's relative paths into its own children (`mod child; pub use child::X;` is the module tree, not an
//! import back up), and `#[cfg(test)]` items (a test may reach anywhere). src/bin/ is its own crate and not read.
//! On failure the test prints every circle it finds, one file per step.

#[path = "common/source_text.rs"]
mod source_text;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

type Graph = BTreeMap<String, BTreeSet<String>>;

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    Punct(char),
    /// `::`
    Path,
}

/// Tokens of `source` with comments, string and char literals dropped (lifetimes kept as punctuation + ident).
fn tokens(source: &str) -> Vec<Tok> {
    let c = source_text::blank_literals(source);
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        let ch = c[i];
        if ch.is_alphanumeric() || ch == '_' {
            let start = i;
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            out.push(Tok::Ident(c[start..i].iter().collect()));
        } else if ch == ':' && c.get(i + 1) == Some(&':') {
            out.push(Tok::Path);
            i += 2;
        } else {
            if !ch.is_whitespace() {
                out.push(Tok::Punct(ch));
            }
            i += 1;
        }
    }
    out
}

fn ident(t: Option<&Tok>) -> Option<&str> {
    match t {
        Some(Tok::Ident(s)) => Some(s),
        _ => None,
    }
}

/// Index just past the item starting at `i`: through its `;` or its balanced `{ .. }` block, whichever ends it.
fn skip_item(t: &[Tok], mut i: usize) -> usize {
    // Further attributes first.
    while t.get(i) == Some(&Tok::Punct('#')) {
        i = skip_balanced(t, i + 1, '[', ']');
    }
    while i < t.len() {
        match t[i] {
            Tok::Punct(';') => return i + 1,
            Tok::Punct('{') => return skip_balanced(t, i, '{', '}'),
            _ => i += 1,
        }
    }
    i
}

/// Index just past the group opened by `open` at `i`.
fn skip_balanced(t: &[Tok], i: usize, open: char, close: char) -> usize {
    let mut depth = 0usize;
    let mut j = i;
    while j < t.len() {
        if t[j] == Tok::Punct(open) {
            depth += 1;
        } else if t[j] == Tok::Punct(close) {
            depth -= 1;
            if depth == 0 {
                return j + 1;
            }
        }
        j += 1;
    }
    j
}

/// The paths of a `use` tree (`a::{b::c, d as e, self, *}`), each as its segments (`self` and `*` dropped).
fn use_paths(t: &[Tok], prefix: &[String], out: &mut Vec<Vec<String>>) {
    // Split `t` at top-level commas.
    let mut depth = 0;
    let mut start = 0;
    let mut parts = Vec::new();
    for (k, tok) in t.iter().enumerate() {
        match tok {
            Tok::Punct('{') => depth += 1,
            Tok::Punct('}') => depth -= 1,
            Tok::Punct(',') if depth == 0 => {
                parts.push(&t[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    parts.push(&t[start..]);
    for part in parts {
        let mut path = prefix.to_vec();
        let mut k = 0;
        let mut nested = false;
        while k < part.len() {
            match &part[k] {
                Tok::Ident(s) if s == "as" => break,
                Tok::Ident(s) => path.push(s.clone()),
                Tok::Punct('{') => {
                    let end = skip_balanced(part, k, '{', '}');
                    use_paths(&part[k + 1..end - 1], &path, out);
                    nested = true;
                    break;
                }
                _ => {}
            }
            k += 1;
        }
        if !nested && path.len() > prefix.len() {
            out.push(path.into_iter().filter(|s| s != "self").collect());
        }
    }
}

/// The module path of the file `rel` (relative to src/, `/`-separated).
fn module_of(rel: &str) -> Vec<String> {
    let stem = rel.trim_end_matches(".rs");
    let mut segs: Vec<String> = stem.split('/').map(str::to_string).collect();
    if matches!(segs.last().map(String::as_str), Some("mod" | "lib")) {
        segs.pop();
    }
    segs
}

/// The paths `source` names from the crate root, each as module segments (already made absolute).
fn absolute_paths(rel: &str, source: &str) -> Vec<Vec<String>> {
    let t = tokens(source);
    let here = module_of(rel);
    // Inline modules open at brace depths: (depth inside, name).
    let mut inline: Vec<(usize, String)> = Vec::new();
    let mut depth = 0usize;
    let mut raw: Vec<(Vec<String>, Vec<String>)> = Vec::new(); // (module it was named in, path)
    let mut i = 0;
    let current = |inline: &Vec<(usize, String)>| {
        let mut m = here.clone();
        m.extend(inline.iter().map(|(_, n)| n.clone()));
        m
    };
    while i < t.len() {
        match &t[i] {
            Tok::Punct('#') if t.get(i + 1) == Some(&Tok::Punct('[')) => {
                let end = skip_balanced(&t, i + 1, '[', ']');
                let attr = &t[i + 2..end - 1];
                let is_test =
                    attr == [Tok::Ident("cfg".into()), Tok::Punct('('), Tok::Ident("test".into()), Tok::Punct(')')];
                i = if is_test { skip_item(&t, end) } else { end };
            }
            Tok::Punct('{') => {
                depth += 1;
                i += 1;
            }
            Tok::Punct('}') => {
                if inline.last().is_some_and(|(d, _)| *d == depth) {
                    inline.pop();
                }
                depth = depth.saturating_sub(1);
                i += 1;
            }
            Tok::Ident(k) if k == "mod" && t.get(i + 2) == Some(&Tok::Punct('{')) => {
                inline.push((depth + 1, ident(t.get(i + 1)).unwrap_or_default().to_string()));
                i += 2;
            }
            Tok::Ident(k) if k == "use" && (i == 0 || t[i - 1] != Tok::Path) => {
                let end = (i..t.len()).find(|&j| t[j] == Tok::Punct(';')).unwrap_or(t.len());
                let mut paths = Vec::new();
                use_paths(&t[i + 1..end], &[], &mut paths);
                let m = current(&inline);
                raw.extend(paths.into_iter().map(|p| (m.clone(), p)));
                i = end + 1;
            }
            Tok::Ident(k) if matches!(k.as_str(), "crate" | "super" | "self") && t.get(i + 1) == Some(&Tok::Path) => {
                let mut path = vec![k.clone()];
                let mut j = i + 1;
                while t.get(j) == Some(&Tok::Path) {
                    match ident(t.get(j + 1)) {
                        Some(s) => path.push(s.to_string()),
                        None => break,
                    }
                    j += 2;
                }
                raw.push((current(&inline), path));
                i = j;
            }
            _ => i += 1,
        }
    }
    raw.into_iter()
        .filter_map(|(module, path)| {
            let mut abs = match path.first().map(String::as_str) {
                Some("crate") => Vec::new(),
                Some("super" | "self") => module,
                _ => return None,
            };
            let mut rest = path.iter().skip(1).peekable();
            if path[0] == "super" {
                abs.pop();
            }
            while let Some(s) = rest.peek() {
                match s.as_str() {
                    "super" => {
                        abs.pop();
                    }
                    "self" => {}
                    _ => break,
                }
                rest.next();
            }
            abs.extend(rest.cloned());
            Some(abs)
        })
        .collect()
}

/// The file defining the longest module prefix of `path` among `files` (paths relative to src/).
fn resolve(path: &[String], files: &BTreeSet<String>) -> Option<String> {
    (0..=path.len()).rev().find_map(|n| {
        if n == 0 {
            return Some("lib.rs".to_string());
        }
        let p = path[..n].join("/");
        [format!("{p}.rs"), format!("{p}/mod.rs")].into_iter().find(|f| files.contains(f))
    })
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The import graph of the library's files (keys and values relative to src/).
fn import_graph() -> Graph {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut paths = Vec::new();
    rust_files(&src, &mut paths);
    let rel = |p: &Path| p.strip_prefix(&src).unwrap().to_string_lossy().replace('\\', "/");
    let files: BTreeSet<String> = paths.iter().map(|p| rel(p)).filter(|r| !r.starts_with("bin/")).collect();
    let mut graph = Graph::new();
    for file in &files {
        let source = std::fs::read_to_string(src.join(file)).unwrap();
        let deps =
            absolute_paths(file, &source).iter().filter_map(|p| resolve(p, &files)).filter(|d| d != file).collect();
        graph.insert(file.clone(), deps);
    }
    graph
}

/// Every circle found by a depth-first search (one per back edge), each as its files in import order.
fn circles(graph: &Graph) -> Vec<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Open,
        Done,
    }
    fn visit(
        v: &str,
        graph: &Graph,
        mark: &mut BTreeMap<String, Mark>,
        stack: &mut Vec<String>,
        out: &mut Vec<Vec<String>>,
    ) {
        mark.insert(v.to_string(), Mark::Open);
        stack.push(v.to_string());
        for w in graph.get(v).into_iter().flatten() {
            match mark.get(w).copied().unwrap_or(Mark::New) {
                Mark::New => visit(w, graph, mark, stack, out),
                Mark::Open => {
                    let from = stack.iter().position(|s| s == w).unwrap();
                    out.push(stack[from..].to_vec());
                }
                Mark::Done => {}
            }
        }
        stack.pop();
        mark.insert(v.to_string(), Mark::Done);
    }
    let mut mark = BTreeMap::new();
    let mut out = Vec::new();
    for v in graph.keys() {
        if mark.get(v).copied().unwrap_or(Mark::New) == Mark::New {
            visit(v, graph, &mut mark, &mut Vec::new(), &mut out);
        }
    }
    out
}

#[test]
fn the_import_graph_of_src_has_no_circle() {
    let graph = import_graph();
    // The reader sees the imports it must: the pipeline uses the backends, the GPU backend the backend seam.
    assert!(graph["pipeline/mod.rs"].contains("backend.rs"), "{:?}", graph["pipeline/mod.rs"]);
    assert!(graph["gpu/mod.rs"].contains("backend.rs"), "{:?}", graph["gpu/mod.rs"]);
    let edges: usize = graph.values().map(BTreeSet::len).sum();
    assert!(edges > 3 * graph.len() / 2, "only {edges} imports among {} files: is the parser blind?", graph.len());
    let found = circles(&graph);
    let text: Vec<String> = found.iter().map(|c| format!("{} -> {}", c.join(" -> "), c[0])).collect();
    assert!(found.is_empty(), "{} import circle(s) among src/ files:\n{}", found.len(), text.join("\n"));
}

#[test]
fn the_parser_resolves_use_trees_super_inline_modules_and_skips_tests() {
    let source = r#"
        use super::{a::B, c as d, self};
        use crate::x::{y::{Z, self}, w};
        // use crate::commented::Out;
        const S: &str = "crate::in_a_string";
        fn f<'a>(c: char) { let _ = '{'; crate::deep::f(); }
        mod inner { use super::sibling::T; }
        #[cfg(test)]
        mod tests { use crate::only_tests::X; }
        #[cfg(test)]
        use crate::also_tests;
    "#;
    let got: BTreeSet<String> = absolute_paths("p/q.rs", source).iter().map(|p| p.join("::")).collect();
    let want: BTreeSet<String> =
        ["p::a::B", "p::c", "p", "x::y::Z", "x::y", "x::w", "deep::f", "p::q::sibling::T"].map(String::from).into();
    assert_eq!(got, want);
}

#[test]
fn a_circle_is_reported_with_its_files() {
    let graph: Graph = [("a.rs", "b.rs"), ("b.rs", "c/mod.rs"), ("c/mod.rs", "a.rs"), ("d.rs", "a.rs")]
        .into_iter()
        .map(|(f, t)| (f.to_string(), [t.to_string()].into()))
        .collect();
    assert_eq!(circles(&graph), vec![vec!["a.rs".to_string(), "b.rs".into(), "c/mod.rs".into()]]);
}
