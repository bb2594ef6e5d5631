//! GPU-free checks of every WGSL kernel: each `shaders/*.wgsl` is registered in `gpu::registry::KERNELS`,
//! parses and validates with naga, and its reflected interface matches the host side: binding kinds and
//! order, `@workgroup_size`, entry point `main`, and the uniform struct's size and field offsets against
//! the `#[repr(C)]` Pod mirror; and each translates to a well-formed SPIR-V module under the options wgpu's
//! Vulkan backend uses (so the cooperative-matrix kernel, which no local adapter can compile, is translated).

use dpr_gpu::gpu::kernel::{BindKind, KernelSpec};
use dpr_gpu::gpu::registry::KERNELS;
use naga::back::spv::{self, Capability};
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

/// The SPIR-V capabilities wgpu's Vulkan backend (wgpu-hal `naga_options`) lets naga emit on a device with
/// `features`: those every Vulkan device has, plus the ones it adds for each feature a kernel may declare.
/// `SHADER_F16` also grants the two 16-bit storage capabilities: wgpu exposes the feature only on devices with
/// `storageBuffer16BitAccess` and `uniformAndStorageBuffer16BitAccess`, and naga declares both with any f16
/// type (`StorageInputOutput16` is optional there, so the translation below turns it off as wgpu does without it).
fn spirv_capabilities(features: wgpu::Features) -> naga::FastHashSet<Capability> {
    use Capability as C;
    let mut allowed = vec![
        C::Shader,
        C::Matrix,
        C::Sampled1D,
        C::Image1D,
        C::ImageQuery,
        C::DerivativeControl,
        C::StorageImageExtendedFormats,
    ];
    if features.contains(wgpu::Features::SHADER_F16) {
        allowed.extend([C::Float16, C::StorageBuffer16BitAccess, C::UniformAndStorageBuffer16BitAccess]);
    }
    if features.contains(wgpu::Features::SUBGROUP) {
        allowed.extend([
            C::GroupNonUniform,
            C::GroupNonUniformVote,
            C::GroupNonUniformArithmetic,
            C::GroupNonUniformBallot,
            C::GroupNonUniformShuffle,
            C::GroupNonUniformShuffleRelative,
            C::GroupNonUniformQuad,
        ]);
    }
    if features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
        allowed.extend([C::CooperativeMatrixKHR, C::VulkanMemoryModel]);
    }
    allowed.into_iter().collect()
}

/// The SPIR-V versions wgpu's Vulkan backend targets for a kernel needing `features`: by device API version
/// 1.0, 1.1, 1.2, 1.3+ it targets 1.0, 1.3, 1.5, 1.6, and it offers `SUBGROUP` only on Vulkan 1.1+ devices.
fn spirv_versions(features: wgpu::Features) -> impl Iterator<Item = (u8, u8)> {
    let lowest = if features.contains(wgpu::Features::SUBGROUP) { (1, 3) } else { (1, 0) };
    [(1, 0), (1, 3), (1, 5), (1, 6)].into_iter().filter(move |&v| v >= lowest)
}

/// SPIR-V opcodes (SPIR-V specification, section 3.52) that the module checks look for.
mod op {
    pub const EXTENSION: u16 = 10;
    pub const ENTRY_POINT: u16 = 15;
    pub const EXECUTION_MODE: u16 = 16;
    pub const CAPABILITY: u16 = 17;
    pub const TYPE_COOPERATIVE_MATRIX_KHR: u16 = 4456;
    pub const COOPERATIVE_MATRIX_LOAD_KHR: u16 = 4457;
    pub const COOPERATIVE_MATRIX_STORE_KHR: u16 = 4458;
    pub const COOPERATIVE_MATRIX_MUL_ADD_KHR: u16 = 4459;
}
/// `ExecutionModel GLCompute` and `ExecutionMode LocalSize` (SPIR-V specification, sections 3.4 and 3.6).
const GL_COMPUTE: u32 = 5;
const LOCAL_SIZE: u32 = 17;

/// What a walk over a SPIR-V word stream found: its header version, capabilities, extensions, the opcodes it
/// uses, and its entry points as (execution model, id, name) with their `LocalSize` execution modes by id.
#[derive(Default)]
struct SpirvSummary {
    version: (u8, u8),
    capabilities: BTreeSet<u32>,
    extensions: BTreeSet<String>,
    opcodes: BTreeSet<u16>,
    entry_points: Vec<(u32, u32, String)>,
    local_sizes: Vec<(u32, [u32; 3])>,
}

/// Decodes a SPIR-V literal string (UTF-8, nul-terminated, packed little-end first into words).
fn literal_string(words: &[u32]) -> String {
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).take_while(|&b| b != 0).collect();
    String::from_utf8(bytes).expect("SPIR-V literal string is UTF-8")
}

/// Checks the physical layout of a SPIR-V module (specification section 2.3: the five-word header with magic
/// number 0x07230203, a nonzero id bound and schema 0, then instructions whose word counts tile the rest of the
/// stream exactly) and summarises it; `what` names the module in failure messages.
fn walk_spirv(words: &[u32], what: &str) -> SpirvSummary {
    assert!(words.len() > 5, "{what}: {} words is no SPIR-V module", words.len());
    assert_eq!(words[0], 0x0723_0203, "{what}: magic number");
    let version = words[1];
    assert_eq!(version & 0xff00_00ff, 0, "{what}: malformed version word {version:#010x}");
    assert!(words[3] > 1, "{what}: id bound {} declares no ids", words[3]);
    assert_eq!(words[4], 0, "{what}: schema");
    let mut summary = SpirvSummary { version: ((version >> 16) as u8, (version >> 8) as u8), ..Default::default() };
    let mut at = 5;
    while at < words.len() {
        let (count, opcode) = ((words[at] >> 16) as usize, (words[at] & 0xffff) as u16);
        assert!(count > 0, "{what}: instruction at word {at} has word count 0");
        assert!(at + count <= words.len(), "{what}: instruction at word {at} runs past the end");
        let operands = &words[at + 1..at + count];
        summary.opcodes.insert(opcode);
        match opcode {
            op::CAPABILITY => {
                summary.capabilities.insert(operands[0]);
            }
            op::EXTENSION => {
                summary.extensions.insert(literal_string(operands));
            }
            op::ENTRY_POINT => summary.entry_points.push((operands[0], operands[1], literal_string(&operands[2..]))),
            op::EXECUTION_MODE if operands[1] == LOCAL_SIZE => {
                summary.local_sizes.push((operands[0], [operands[2], operands[3], operands[4]]))
            }
            _ => {}
        }
        at += count;
    }
    summary
}

/// Every kernel translates with naga's SPIR-V backend, for every SPIR-V version wgpu's Vulkan backend may target
/// for it and with only the capabilities wgpu grants for the kernel's declared features, to a well-formed module:
/// one GLCompute entry point `main` with the registry's `LocalSize`, no capability beyond those granted, and
/// the capability each declared feature stands for, each capability at a version or with the extension it needs
/// (group operations from SPIR-V 1.3, the Vulkan memory model from 1.5 or by extension). The cooperative-matrix kernel emits the
/// `CooperativeMatrixKHR` capability, the `SPV_KHR_cooperative_matrix` extension and its type, load, store
/// and multiply-add instructions; a kernel declaring no feature emits none of the feature capabilities.
#[test]
fn every_shader_translates_to_well_formed_spirv() {
    for spec in KERNELS {
        translates_to_well_formed_spirv(spec, spec.name, &module(spec), spec.workgroup_size);
    }
}

/// The checks of [`every_shader_translates_to_well_formed_spirv`] on `module` (`spec`'s source or a generated
/// variant of it, named `label`, with `@workgroup_size(workgroup_size)`).
fn translates_to_well_formed_spirv(spec: &KernelSpec, label: &str, module: &naga::Module, workgroup_size: u32) {
    {
        let info = Validator::new(ValidationFlags::all(), capabilities(spec.features))
            .validate(module)
            .expect("validated by `module`");
        let allowed = spirv_capabilities(spec.features);
        // The bindings wgpu maps one to one into descriptor set 0; anything else is a translation error.
        let binding_map: spv::BindingMap = (0..spec.binds.len() as u32)
            .map(|binding| {
                let info = spv::BindingInfo { descriptor_set: 0, binding, binding_array_size: None };
                (naga::ResourceBinding { group: 0, binding }, info)
            })
            .collect();
        for lang_version in spirv_versions(spec.features) {
            let what = format!("{label} as SPIR-V {}.{}", lang_version.0, lang_version.1);
            let options = spv::Options {
                lang_version,
                flags: spv::WriterFlags::empty(),
                fake_missing_bindings: false,
                binding_map: binding_map.clone(),
                capabilities: Some(allowed.clone()),
                use_storage_input_output_16: false,
                ..spv::Options::default()
            };
            let pipeline =
                spv::PipelineOptions { shader_stage: naga::ShaderStage::Compute, entry_point: "main".to_string() };
            let words = spv::write_vec(module, &info, &options, Some(&pipeline))
                .unwrap_or_else(|e| panic!("{what}: naga's SPIR-V backend fails: {e} ({e:?})"));
            let spirv = walk_spirv(&words, &what);
            assert_eq!(spirv.version, lang_version, "{what}: header version");

            assert_eq!(spirv.entry_points.len(), 1, "{what}: one entry point");
            let (model, id, name) = &spirv.entry_points[0];
            assert_eq!((*model, name.as_str()), (GL_COMPUTE, "main"), "{what}: entry point");
            assert_eq!(spirv.local_sizes, [(*id, [workgroup_size, 1, 1])], "{what}: LocalSize");

            let emitted: BTreeSet<Capability> = spirv
                .capabilities
                .iter()
                .map(|&c| Capability::from_u32(c).unwrap_or_else(|| panic!("{what}: unknown capability {c}")))
                .collect();
            let beyond: Vec<_> = emitted.iter().filter(|c| !allowed.contains(*c)).collect();
            assert!(beyond.is_empty(), "{what}: capabilities beyond the declared features: {beyond:?}");
            assert!(emitted.contains(&Capability::Shader), "{what}: no Shader capability");
            let witnesses = [
                (wgpu::Features::SHADER_F16, Capability::Float16),
                (wgpu::Features::SUBGROUP, Capability::GroupNonUniform),
                (wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX, Capability::CooperativeMatrixKHR),
            ];
            for (feature, capability) in witnesses {
                assert_eq!(
                    emitted.contains(&capability),
                    spec.features.contains(feature),
                    "{what}: capability {capability:?} against declared feature {feature:?} ({emitted:?})"
                );
            }

            let group_ops = emitted.iter().filter(|c| format!("{c:?}").starts_with("GroupNonUniform")).count();
            assert!(group_ops == 0 || spirv.version >= (1, 3), "{what}: group operations need SPIR-V 1.3");
            assert!(
                !emitted.contains(&Capability::VulkanMemoryModel)
                    || spirv.version >= (1, 5)
                    || spirv.extensions.contains("SPV_KHR_vulkan_memory_model"),
                "{what}: VulkanMemoryModel before SPIR-V 1.5 without its extension"
            );

            let coop_ops = [
                op::TYPE_COOPERATIVE_MATRIX_KHR,
                op::COOPERATIVE_MATRIX_LOAD_KHR,
                op::COOPERATIVE_MATRIX_STORE_KHR,
                op::COOPERATIVE_MATRIX_MUL_ADD_KHR,
            ];
            let coop = spec.features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX);
            for opcode in coop_ops {
                assert_eq!(spirv.opcodes.contains(&opcode), coop, "{what}: cooperative-matrix opcode {opcode}");
            }
            assert_eq!(
                spirv.extensions.contains("SPV_KHR_cooperative_matrix"),
                coop,
                "{what}: extensions {:?}",
                spirv.extensions
            );
        }
    }
}

/// Parses and validates `spec`'s composed source (its shared modules included, as the device compiles it) with
/// the capabilities of its declared features (none for a portable kernel), panicking with naga's rendered
/// diagnostic.
fn module(spec: &KernelSpec) -> naga::Module {
    let source = spec.composed_source().unwrap_or_else(|e| panic!("shaders/{}.wgsl: {e}", spec.name));
    let module = naga::front::wgsl::parse_str(&source)
        .unwrap_or_else(|e| panic!("shaders/{}.wgsl does not parse:\n{}", spec.name, e.emit_to_string(&source)));
    Validator::new(ValidationFlags::all(), capabilities(spec.features))
        .validate(&module)
        .unwrap_or_else(|e| panic!("shaders/{}.wgsl does not validate:\n{}", spec.name, e.emit_to_string(&source)));
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
    // shaders/tiles/k.wgsl: the source other tile shapes of the registered kernel k are generated from.
    for entry in std::fs::read_dir(dir.join("tiles")).expect("shaders/tiles/ exists") {
        let path = entry.expect("readable").path();
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        assert!(registered.contains(&stem), "{}: names no registered kernel", path.display());
    }
}

/// Each shared module in shaders/common/ is embedded and included by at least two kernels, and no kernel
/// defines a function a module it includes defines (the copy the module replaced).
#[test]
fn every_shared_module_is_used_and_replaces_its_copies() {
    use dpr_gpu::gpu::device::wgsl::{INCLUDE, MODULES};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders").join("common");
    let files: BTreeSet<String> = std::fs::read_dir(&dir)
        .expect("shaders/common/ exists")
        .filter_map(|e| Some(e.ok()?.path().file_stem()?.to_string_lossy().into_owned()))
        .collect();
    let embedded: BTreeSet<String> = MODULES.iter().map(|(n, _)| n.to_string()).collect();
    assert_eq!(files, embedded, "shaders/common/*.wgsl and gpu::device::wgsl::MODULES differ");
    for (name, text) in MODULES {
        let users: Vec<&str> = KERNELS
            .iter()
            .filter(|k| k.source.lines().any(|l| l.trim() == format!("{INCLUDE}{name}")))
            .map(|k| k.name)
            .collect();
        assert!(users.len() >= 2, "shaders/common/{name}.wgsl is included by {users:?} only");
        let defined: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix("fn ")?.split('(').next()).collect();
        for k in KERNELS {
            for f in &defined {
                assert!(
                    !k.source.contains(&format!("\nfn {f}(")),
                    "{}: defines {f} again beside shaders/common/{name}.wgsl",
                    k.name
                );
            }
        }
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
        let module = naga::front::wgsl::parse_str(&spec.composed_source().unwrap()).expect("parses");
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
        let host_path = root.join("gpu").join("kernels").join(format!("{}.rs", spec.name));
        let host = std::fs::read_to_string(&host_path)
            .unwrap_or_else(|e| panic!("{}: no host module {} ({e})", spec.name, host_path.display()));
        let twin_path = root.join("cpu").join(format!("{}.rs", spec.name));
        assert!(twin_path.is_file(), "{}: no CPU twin module {}", spec.name, twin_path.display());
        assert!(
            host.contains(&format!("const NAME: &'static str = \"{}\";", spec.name)),
            "{}: src/gpu/kernels/{}.rs does not declare the kernel (`impl GpuKernel` with NAME = \"{}\")",
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

/// A generated kernel variant (`label` in messages), its shared modules composed in, parsed and validated with `caps`, panicking with naga's
/// rendered diagnostic; with its validation info and the workgroup memory it declares (bytes).
fn validated_variant(label: &str, source: &str, caps: Capabilities) -> (naga::Module, naga::valid::ModuleInfo, u32) {
    let source = dpr_gpu::gpu::device::wgsl::compose(source).unwrap_or_else(|e| panic!("{label}: {e}"));
    let module = naga::front::wgsl::parse_str(&source)
        .unwrap_or_else(|e| panic!("{label} does not parse:\n{}", e.emit_to_string(&source)));
    let info = Validator::new(ValidationFlags::all(), caps)
        .validate(&module)
        .unwrap_or_else(|e| panic!("{label} does not validate:\n{}", e.emit_to_string(&source)));
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let workgroup_bytes = module
        .global_variables
        .iter()
        .filter(|(_, g)| g.space == naga::AddressSpace::WorkGroup)
        .map(|(_, g)| layouter[g.ty].size)
        .sum();
    (module, info, workgroup_bytes)
}

/// Every tile shape of the fast GEMM that `bench --gemm-sweep` compiles (generated from `shaders/dense_fast.wgsl`)
/// parses, validates with no capability, fits the default tile's workgroup memory, and translates to SPIR-V.
#[test]
fn every_generated_fast_gemm_tile_validates_and_translates() {
    use dpr_gpu::gpu::dense_fast::{FastTile, WORKGROUP_STORAGE_BYTES};
    for tile in FastTile::ALL {
        let (module, info, workgroup_bytes) =
            validated_variant(&format!("dense_fast {tile}"), &tile.source().unwrap(), Capabilities::empty());
        let (m, n) = tile.tile();
        assert_eq!(workgroup_bytes, 2 * 8 * 4 * (m + n) as u32, "dense_fast {tile}: double-buffered 8-deep k-tiles");
        assert!(workgroup_bytes <= WORKGROUP_STORAGE_BYTES, "dense_fast {tile}");
        let options = spv::Options { fake_missing_bindings: true, ..spv::Options::default() };
        let pipeline =
            spv::PipelineOptions { shader_stage: naga::ShaderStage::Compute, entry_point: "main".to_string() };
        spv::write_vec(&module, &info, &options, Some(&pipeline))
            .unwrap_or_else(|e| panic!("dense_fast {tile}: naga's SPIR-V backend fails: {e}"));
    }
}

/// Every tile shape of the cooperative-matrix GEMM that `bench --gemm-sweep` compiles (generated from
/// `shaders/tiles/dense_coop_f16.wgsl`, the default being `shaders/dense_coop_f16.wgsl`) parses and validates with the kernel's capabilities, declares the workgroup
/// memory its host side states (double-buffered operand tiles and one accumulator per subgroup, within 48 KiB)
/// and translates to well-formed SPIR-V with the cooperative-matrix instructions, as the registered kernel
/// does. No adapter here has cooperative matrices: whether the shapes run, and how fast, only a GPU shows.
#[test]
fn every_generated_coop_gemm_tile_validates_and_translates() {
    use dpr_gpu::gpu::dense_coop_f16::{CoopTile, DenseCoopF16};
    use dpr_gpu::gpu::kernel::GpuKernel;
    let spec = &DenseCoopF16::SPEC;
    for tile in CoopTile::ALL {
        let label = format!("dense_coop_f16 {tile}");
        let (module, _, workgroup_bytes) =
            validated_variant(&label, &tile.source().unwrap(), capabilities(spec.features));
        assert_eq!(workgroup_bytes, tile.workgroup_bytes(), "{label}: workgroup memory");
        assert!(workgroup_bytes <= 48 * 1024, "{label}: {workgroup_bytes} bytes of workgroup memory");
        translates_to_well_formed_spirv(spec, &label, &module, tile.workgroup_size());
    }
}
