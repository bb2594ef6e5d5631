//! The directory dpr-gpu keeps its per-machine caches in ([`cache_dir`]): [`CACHE_DIR_ENV`], else
//! `$XDG_CACHE_HOME/dpr-gpu`, else `$HOME/.cache/dpr-gpu`. The recorded GEMM choice
//! ([`crate::gpu::kernels::gemm_choice`]) and the driver's pipeline cache ([`super::pipeline_cache`]) live there.

use std::path::PathBuf;

/// Environment variable naming the cache directory (before `$XDG_CACHE_HOME/dpr-gpu` and `$HOME/.cache/dpr-gpu`).
pub const CACHE_DIR_ENV: &str = "DPR_GPU_CACHE_DIR";

/// The cache directory from the environment lookup `var` ([`CACHE_DIR_ENV`], `XDG_CACHE_HOME`, `HOME`; empty
/// values skipped), or `None` when none is set.
pub fn cache_dir_from(var: impl Fn(&str) -> Option<std::ffi::OsString>) -> Option<PathBuf> {
    let set = |name: &str| var(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    set(CACHE_DIR_ENV)
        .or_else(|| set("XDG_CACHE_HOME").map(|d| d.join("dpr-gpu")))
        .or_else(|| set("HOME").map(|d| d.join(".cache").join("dpr-gpu")))
}

/// The cache directory of this process's environment, or `None` without any of the directories' variables.
pub fn cache_dir() -> Option<PathBuf> {
    cache_dir_from(|name| std::env::var_os(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_directory_follows_the_documented_order() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |name: &str| pairs.iter().find(|(k, _)| *k == name).map(|(_, v)| (*v).into())
        };
        let all = env(&[(CACHE_DIR_ENV, "/c"), ("XDG_CACHE_HOME", "/x"), ("HOME", "/h")]);
        assert_eq!(cache_dir_from(all), Some(PathBuf::from("/c")));
        let xdg = env(&[(CACHE_DIR_ENV, ""), ("XDG_CACHE_HOME", "/x"), ("HOME", "/h")]);
        assert_eq!(cache_dir_from(xdg), Some(PathBuf::from("/x/dpr-gpu")));
        assert_eq!(cache_dir_from(env(&[("HOME", "/h")])), Some(PathBuf::from("/h/.cache/dpr-gpu")));
        assert_eq!(cache_dir_from(env(&[])), None);
    }
}
