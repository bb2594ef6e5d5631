//! Composing a kernel's WGSL source when it is loaded: a line `// #include NAME` (alone on its line) is
//! replaced by the shared module `shaders/common/NAME.wgsl`, so that a helper several kernels use (the run-key
//! binary search, the fenced squared distance, reading a point) is written once. There is no nesting and no
//! other syntax: a shared module names in its header comment what it needs from the kernel that includes it.
//! `tests/shaders.rs` validates every kernel's composed source with naga.

use crate::error::{Error, Result};
use std::borrow::Cow;

/// The shared modules by name, embedded like the kernels' own sources.
pub const MODULES: &[(&str, &str)] = &[
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
}
