//! GPU-free checks of every WGSL kernel: each `shaders/*.wgsl` is registered in `gpu::registry::KERNELS`,
//! parses and validates with naga, and its reflected interface matches the host side: binding kinds and
//! order, `@workgroup_size`, entry point `main`, and the uniform struct's size and field offsets against
//! the `#[repr(C)]` Pod mirror.

use dpr_gpu::gpu::kernel::{BindKind, KernelSpec};
use dpr_gpu::gpu::registry::KERNELS;
use naga::valid::{Capabilities, ValidationFlags, Validator};
use std::collections::BTreeSet;

/// The naga capabilities the device features of a kernel grant its shader (what wgpu enables for them).
fn capabilities(features: wgpu::Features) -> Capabilities {
    let grants = [
        (wgpu::Features::SHADER_F16, Capabilities::SHADER_FLOAT16),
        (wgpu::Features::SUBGROUP, Capabilities::SUBGROUP),
        (wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX, Capabilities::COOPERATIVE_MATRIX),
    ];
    let known = grants.iter().fold(wgpu::Features::empty(), |acc, (f, _)| acc | *f);
    assert!(known.contains(features), "a kernel needs features this test does not map: {:?}", features - known);
    grants.iter().filter(|(f, _)| features.contains(*f)).fold(Capabilities::empty(), |acc, (_, c)| acc | *c)
}

/// Parses and validates `spec`'s source with the capabilities of its declared features (none for a portable
/// kernel), panicking with naga's rendered diagnostic.
fn module(spec: &KernelSpec) -> naga::Module {
    let module = naga::front::wgsl::parse_str(spec.source)
        .unwrap_or_else(|e| panic!("shaders/{}.wgsl does not parse:\n{}", spec.name, e.emit_to_string(spec.source)));
    Validator::new(ValidationFlags::all(), capabilities(spec.features))
        .validate(&module)
        .unwrap_or_else(|e| panic!("shaders/{}.wgsl does not validate:\n{}", spec.name, e.emit_to_string(spec.source)));
    module
}

#[test]
fn every_shader_file_is_registered_once() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let files: BTreeSet<String> = std::fs::read_dir(&dir)
        .expect("shaders/ exists")
        .filter_map(|e| {
            let p = e.ok()?.path();
            let stem = p.file_stem()?.to_string_lossy().into_owned();
            (p.extension()? == "wgsl").then_some(stem)
        })
        .collect();
    let registered: BTreeSet<String> = KERNELS.iter().map(|k| k.name.to_string()).collect();
    assert_eq!(registered.len(), KERNELS.len(), "a kernel is registered twice");
    assert_eq!(files, registered, "shaders/*.wgsl and gpu::registry::KERNELS differ");
    for spec in KERNELS {
        let on_disk = std::fs::read_to_string(dir.join(format!("{}.wgsl", spec.name))).expect("readable");
        assert_eq!(on_disk, spec.source, "{}: registered source is not shaders/{}.wgsl", spec.name, spec.name);
    }
}

#[test]
fn every_shader_parses_and_validates() {
    for spec in KERNELS {
        module(spec);
    }
}

/// A kernel that declares no feature validates with no capability, and one that declares features needs each
/// of them: without any one of its capabilities it does not validate (so the declaration is what gates it).
#[test]
fn declared_features_are_exactly_what_each_shader_needs() {
    for spec in KERNELS {
        let module = naga::front::wgsl::parse_str(spec.source).expect("parses");
        for feature in spec.features.iter() {
            let without = capabilities(spec.features) - capabilities(feature);
            let result = Validator::new(ValidationFlags::all(), without).validate(&module);
            assert!(result.is_err(), "{}: validates without {feature:?}, which it declares", spec.name);
        }
    }
    let coop = KERNELS.iter().find(|k| k.name == "dense_coop_f16").expect("registered");
    assert!(coop.features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX | wgpu::Features::SHADER_F16));
}

#[test]
fn bindings_match_the_registry() {
    for spec in KERNELS {
        let m = module(spec);
        let mut found: Vec<(u32, BindKind, String)> = m
            .global_variables
            .iter()
            .filter_map(|(_, v)| {
                let b = v.binding.as_ref()?;
                assert_eq!(b.group, 0, "{}: {:?} is not in group 0", spec.name, v.name);
                let kind = match v.space {
                    naga::AddressSpace::Uniform => BindKind::Uniform,
                    naga::AddressSpace::Storage { access } if access.contains(naga::StorageAccess::STORE) => {
                        BindKind::ReadWrite
                    }
                    naga::AddressSpace::Storage { .. } => BindKind::ReadOnly,
                    other => panic!("{}: unexpected address space {other:?}", spec.name),
                };
                Some((b.binding, kind, v.name.clone().unwrap_or_default()))
            })
            .collect();
        found.sort_by_key(|f| f.0);
        let bindings: Vec<u32> = found.iter().map(|f| f.0).collect();
        assert_eq!(bindings, (0..spec.binds.len() as u32).collect::<Vec<_>>(), "{}: bindings are not 0..n", spec.name);
        let kinds: Vec<BindKind> = found.iter().map(|f| f.1).collect();
        assert_eq!(kinds, spec.binds, "{}: binding kinds differ from the registry ({found:?})", spec.name);
        assert_eq!(found[0].2, "params", "{}: binding 0 must be `params`", spec.name);
        assert!(spec.binds.len() - 1 <= 8, "{}: more than 8 storage buffers (the WebGPU default limit)", spec.name);
    }
}

#[test]
fn entry_point_and_workgroup_size_match() {
    for spec in KERNELS {
        let m = module(spec);
        assert_eq!(m.entry_points.len(), 1, "{}: one entry point", spec.name);
        let ep = &m.entry_points[0];
        assert_eq!(ep.name, "main", "{}", spec.name);
        assert_eq!(ep.stage, naga::ShaderStage::Compute, "{}", spec.name);
        assert_eq!(ep.workgroup_size, [spec.workgroup_size, 1, 1], "{}: @workgroup_size", spec.name);
        assert!(spec.workgroup_size <= 256, "{}: more than 256 invocations", spec.name);
    }
}

#[test]
fn params_structs_match_the_wgsl_layout() {
    for spec in KERNELS {
        let m = module(spec);
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(m.to_ctx()).expect("layout");
        let p = &spec.params;
        let (handle, ty) = m
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(p.wgsl_name))
            .unwrap_or_else(|| panic!("{}: no struct {} in the shader", spec.name, p.wgsl_name));
        let naga::TypeInner::Struct { members, span } = &ty.inner else {
            panic!("{}: {} is not a struct", spec.name, p.wgsl_name)
        };
        assert_eq!(*span as usize, p.size, "{}: size of {}", spec.name, p.wgsl_name);
        assert_eq!(layouter[handle].size as usize, p.size, "{}: layout size of {}", spec.name, p.wgsl_name);
        let wgsl: Vec<(String, usize, usize)> = members
            .iter()
            .map(|mb| (mb.name.clone().unwrap_or_default(), mb.offset as usize, layouter[mb.ty].size as usize))
            .collect();
        let rust: Vec<(String, usize, usize)> =
            (p.fields)().into_iter().map(|(n, o, s)| (n.to_string(), o, s)).collect();
        assert_eq!(rust, wgsl, "{}: {} fields (name, offset, size) differ", spec.name, p.wgsl_name);
        // The uniform at binding 0 has this type.
        let params_ty = m
            .global_variables
            .iter()
            .find(|(_, v)| v.name.as_deref() == Some("params"))
            .map(|(_, v)| v.ty)
            .expect("params global");
        assert_eq!(params_ty, handle, "{}: `params` is not a {}", spec.name, p.wgsl_name);
    }
}

#[test]
fn every_kernel_is_declared_in_its_host_module_with_its_twin_in_cpu_named_after_it() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    for spec in KERNELS {
        let host_path = root.join("gpu").join(format!("{}.rs", spec.name));
        let host = std::fs::read_to_string(&host_path)
            .unwrap_or_else(|e| panic!("{}: no host module {} ({e})", spec.name, host_path.display()));
        let twin_path = root.join("cpu").join(format!("{}.rs", spec.name));
        assert!(twin_path.is_file(), "{}: no CPU twin module {}", spec.name, twin_path.display());
        assert!(
            host.contains(&format!("const NAME: &'static str = \"{}\";", spec.name)),
            "{}: src/gpu/{}.rs does not declare the kernel (`impl GpuKernel` with NAME = \"{}\")",
            spec.name,
            spec.name,
            spec.name
        );
        assert!(
            host.contains(&format!("const CPU_TWIN: Self::CpuTwin = crate::cpu::{}::", spec.name)),
            "{}: the declared CPU twin is not in crate::cpu::{}",
            spec.name,
            spec.name
        );
    }
}
