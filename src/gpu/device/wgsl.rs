//! Composing a kernel's WGSL source when it is loaded: a line `// #include NAME` (alone on its line) is
//! replaced by the shared module `shaders/common/NAME.wgsl`, so that a helper several kernels use (the run-key
//! binary search, the fenced squared distance, reading a point) is written once. There is no nesting and no
//! other syntax: a shared module names in its header comment what it needs from the kernel that includes it.
//! `tests/shaders.rs` validates every kernel's composed source with naga.

use crate::error::{Error, Result};
use std::borrow::Cow;

/// The shared modules by name, embedded like the kernels' own sources.
pub const MODULES: &[(&str, &str)] = &[
    ("dense_layer", include_str!("../../../shaders/common/dense_layer.wgsl")),
    ("distance_squared", include_str!("../../../shaders/common/distance_squared.wgsl")),
    ("point", include_str!("../../../shaders/common/point.wgsl")),
    ("run_keys", include_str!("../../../shaders/common/run_keys.wgsl")),
];

/// The marker of an include line.
pub const INCLUDE: &str = "// #include ";

/// `source` with every include line replaced by its module (borrowed when it has none); an error names an
/// unknown module.
pub fn compose(source: &str) -> Result<Cow<'_, str>> {
    if !source.lines().any(|l| l.trim_start().starts_with(INCLUDE)) {
        return Ok(Cow::Borrowed(source));
    }
    let mut out = String::with_capacity(source.len() + 1024);
    for line in source.split_inclusive('\n') {
        match line.trim_start().strip_prefix(INCLUDE) {
            Some(name) => {
                let name = name.trim();
                let (_, module) = MODULES
                    .iter()
                    .find(|(n, _)| *n == name)
                    .ok_or_else(|| Error::Gpu(format!("WGSL `#include {name}`: no shaders/common/{name}.wgsl")))?;
                out.push_str(module);
            }
            None => out.push_str(line),
        }
    }
    Ok(Cow::Owned(out))
}

/// `source` (the shader `file`) with `u32` constants set: each `(NAME, default, value)` replaces the line
/// `const NAME: u32 = {default}u;`, which must occur exactly once, by `const NAME: u32 = {value}u;`. This is
/// how a kernel's tile shapes are generated from one shader written at its default shape
/// ([`crate::gpu::kernels::dense_fast::FastTile`], [`crate::gpu::kernels::dense_coop_f16::CoopTile`]); an error
/// names the line that is missing or repeated.
pub fn with_constants(file: &str, source: &str, constants: &[(&str, u32, u32)]) -> Result<String> {
    let mut out = source.to_string();
    for &(name, default, value) in constants {
        let line = format!("const {name}: u32 = {default}u;");
        if source.matches(&line).count() != 1 {
            return Err(Error::Gpu(format!("{file}: expected one line '{line}'")));
        }
        out = out.replace(&line, &format!("const {name}: u32 = {value}u;"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_include_line_becomes_its_module_and_an_unknown_one_is_an_error() {
        assert!(matches!(compose("fn main() {}\n").unwrap(), Cow::Borrowed(_)));
        let composed = compose("a\n// #include point\nb\n").unwrap();
        assert_eq!(composed, format!("a\n{}b\n", MODULES.iter().find(|m| m.0 == "point").unwrap().1));
        assert!(compose("// #include nothing\n").unwrap_err().to_string().contains("nothing"));
    }

    #[test]
    fn with_constants_replaces_each_default_line_once_and_names_a_missing_one() {
        let src = "const A: u32 = 2u;\nconst B: u32 = 2u;\nconst AB: u32 = A * B;\n";
        let out = with_constants("k.wgsl", src, &[("A", 2, 1), ("B", 2, 4)]).unwrap();
        assert_eq!(out, "const A: u32 = 1u;\nconst B: u32 = 4u;\nconst AB: u32 = A * B;\n");
        let err = with_constants("k.wgsl", src, &[("C", 2, 1)]).unwrap_err().to_string();
        assert!(err.contains("k.wgsl") && err.contains("const C: u32 = 2u;"), "{err}");
        let twice = format!("{src}{src}");
        assert!(with_constants("k.wgsl", &twice, &[("A", 2, 1)]).is_err());
    }
}
