//! No function of the library (src/) or the Python bindings (python/src/) is longer than
//! [`MAX_LINES`] lines, tests aside: a long function does several things, and is split by what each part does.
//!
//! A function's length runs from the line of its `fn` keyword to the line of its closing brace. Comments,
//! string and char literals are blanked first (so braces in them do not count); items under `#[cfg(test)]`
//! are skipped; declarations without a body (trait methods) have no length. On failure the test lists every
//! function over the limit, longest first.

#[path = "common/source_text.rs"]
mod source_text;

use source_text::blank_literals;
use std::path::{Path, PathBuf};

/// The most lines a function may span.
const MAX_LINES: usize = 100;

/// Functions over the limit that are being split right now (path, function); empty since issue 40 item 5. A
/// function leaves it when it is split (the test fails while an entry is no longer over the limit, so the list
/// only shrinks).
const BEING_SPLIT: &[(&str, &str)] = &[];

/// The index of the brace that closes the one at `open`.
fn matching_brace(c: &[char], open: usize) -> usize {
    let mut depth = 0usize;
    for (k, &ch) in c.iter().enumerate().skip(open) {
        match ch {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return k;
                }
            }
            _ => {}
        }
    }
    c.len()
}

/// The end of the item starting at or after `from`: its closing brace, or its `;` when it has no body.
fn item_end(c: &[char], from: usize) -> usize {
    let mut k = from;
    while k < c.len() && c[k] != '{' && c[k] != ';' {
        k += 1;
    }
    if k < c.len() && c[k] == '{' { matching_brace(c, k) } else { k }
}

fn is_ident(ch: char) -> bool {
    ch.is_alphanumeric() || ch == '_'
}

/// Every function with a body outside `#[cfg(test)]` items in `source`: (name, first line, lines spanned).
fn functions(source: &str) -> Vec<(String, usize, usize)> {
    let c = blank_literals(source);
    let line_of = |k: usize| c[..k].iter().filter(|&&ch| ch == '\n').count() + 1;
    let test_attr: Vec<char> = "#[cfg(test)]".chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        if c[i..].starts_with(&test_attr) {
            i = item_end(&c, i + test_attr.len()) + 1;
            continue;
        }
        let starts_fn = c[i..].starts_with(&['f', 'n'])
            && (i == 0 || !is_ident(c[i - 1]))
            && c.get(i + 2).is_some_and(|ch| ch.is_whitespace());
        if starts_fn {
            let mut k = i + 2;
            while k < c.len() && c[k].is_whitespace() {
                k += 1;
            }
            let name: String = c[k..].iter().take_while(|&&ch| is_ident(ch)).collect();
            let end = item_end(&c, k);
            if !name.is_empty() && end < c.len() && c[end] == '}' {
                let first = line_of(i);
                out.push((name, first, line_of(end) - first + 1));
            }
        }
        i += 1;
    }
    out
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn no_function_outside_tests_is_over_100_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in ["src", "python/src"] {
        rust_files(&root.join(dir), &mut files);
    }
    assert!(files.len() > 50, "found only {} source files under {}", files.len(), root.display());
    let mut long = Vec::new();
    let mut allowed_seen = Vec::new();
    for path in &files {
        let rel = path.strip_prefix(root).unwrap().to_string_lossy().replace('\\', "/");
        let source = std::fs::read_to_string(path).unwrap();
        for (name, line, lines) in functions(&source) {
            if lines <= MAX_LINES {
                continue;
            }
            if BEING_SPLIT.contains(&(rel.as_str(), name.as_str())) {
                allowed_seen.push((rel.clone(), name));
            } else {
                long.push((lines, format!("{rel}:{line} {name}")));
            }
        }
    }
    long.sort_by(|a, b| b.cmp(a));
    let report: Vec<String> = long.iter().map(|(n, at)| format!("  {n} lines: {at}")).collect();
    assert!(
        long.is_empty(),
        "functions over {MAX_LINES} lines (split them by what each part does):\n{}",
        report.join("\n")
    );
    for (file, name) in BEING_SPLIT {
        assert!(
            allowed_seen.iter().any(|(f, n)| f == file && n == name),
            "{file} {name} is no longer over {MAX_LINES} lines: remove it from BEING_SPLIT"
        );
    }
}

#[test]
fn the_scanner_measures_functions_as_written() {
    let source = "fn short() {\n    let s = \"}}}\"; // }\n}\n\n/* fn hidden() { */\nimpl X {\n    fn \
                  decl(&self);\n    fn body<'a>(&'a self) -> char {\n        '}'\n    }\n}\n#[cfg(test)]\nmod tests \
                  {\n    fn in_tests() {\n    }\n}\nfn last() { let r = r#\"{\"#; }\n";
    let found = functions(source);
    assert_eq!(
        found,
        vec![("short".to_string(), 1, 3), ("body".to_string(), 8, 3), ("last".to_string(), 17, 1)],
        "{found:?}"
    );
}
