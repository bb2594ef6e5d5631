//! Weights files: safetensors with the `ModelConfig` (JSON) in the metadata under `dpr_gpu.config`.
//! Loading checks every tensor's name, dtype and shape and reports all mismatches at once.

use super::config::{ModelConfig, PoseFrame, RotationOutput};
use super::params::{all_layers, tensor_specs};
use crate::error::{Error, Result};
use crate::rng::Rng;
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Bytes aligned for reading f32 in place.
#[repr(C, align(64))]
struct Aligned<B: ?Sized>(B);

/// The built-in weights' bytes, aligned so that their tensors are read in place ([`Weights::built_in_view`]).
static BUILT_IN_ALIGNED: &Aligned<[u8]> = &Aligned(*include_bytes!("../../weights/default.safetensors"));

/// The bytes of `weights/default.safetensors` as built: the weights used when no file is named.
pub static BUILT_IN_WEIGHTS: &[u8] = &BUILT_IN_ALIGNED.0;

/// Metadata key holding the model configuration as JSON.
pub const CONFIG_KEY: &str = "dpr_gpu.config";
/// Metadata key holding the format version.
pub const FORMAT_KEY: &str = "dpr_gpu.format";
/// Current format version.
pub const FORMAT_VERSION: &str = "1";

/// All parameters of a model, by tensor name, f32, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Weights {
    /// The configuration the tensors were made for.
    pub config: ModelConfig,
    /// Tensor data by name; shapes follow `params::tensor_specs(&config)`.
    pub tensors: BTreeMap<String, Vec<f32>>,
    /// Free-form metadata carried with the file (training command, steps...), besides the config.
    pub notes: BTreeMap<String, String>,
}

impl Weights {
    /// A seeded random initialisation: Xavier-normal weights, zero biases (as the reference implementation).
    pub fn init(config: &ModelConfig, seed: u64) -> Result<Weights> {
        config.validate()?;
        let mut tensors = BTreeMap::new();
        for (index, layer) in all_layers(config).into_iter().enumerate() {
            let mut rng = Rng::derived(seed, index as u64);
            let std = (2.0 / (layer.in_dim + layer.out_dim) as f64).sqrt();
            let w: Vec<f32> = (0..layer.in_dim * layer.out_dim).map(|_| (rng.normal() * std) as f32).collect();
            tensors.insert(format!("{}.weight", layer.name), w);
            tensors.insert(format!("{}.bias", layer.name), vec![0.0; layer.out_dim]);
        }
        Ok(Weights { config: config.clone(), tensors, notes: BTreeMap::new() })
    }

    /// Total number of scalar parameters.
    pub fn parameter_count(&self) -> usize {
        self.tensors.values().map(Vec::len).sum()
    }

    /// These weights with another pose head (`config.pose_frame`, `config.rotation_output`): both FoldNets keep
    /// their tensors, RelativeNet is initialised afresh from `seed` (its output width or input frame changes what
    /// it means). The other sizes must be equal.
    pub fn with_pose_head(&self, frame: PoseFrame, output: RotationOutput, seed: u64) -> Result<Weights> {
        let config = ModelConfig { pose_frame: frame, rotation_output: output, ..self.config.clone() };
        let fresh = Weights::init(&config, seed)?;
        let mut tensors = fresh.tensors;
        for (name, value) in tensors.iter_mut() {
            if !name.starts_with("relative.") {
                *value = self.get(name)?.to_vec();
            }
        }
        Ok(Weights { config, tensors, notes: self.notes.clone() })
    }

    /// Parameter count per tensor-name prefix ("ppf", "pc", "relative").
    pub fn parameter_counts_by_net(&self) -> BTreeMap<String, usize> {
        let mut out = BTreeMap::new();
        for (name, t) in &self.tensors {
            let net = name.split('.').next().unwrap_or("").to_string();
            *out.entry(net).or_insert(0) += t.len();
        }
        out
    }

    /// A tensor by name (panics never: missing names are caught when loading or building).
    pub fn get(&self, name: &str) -> Result<&[f32]> {
        self.tensors.get(name).map(Vec::as_slice).ok_or_else(|| Error::Weights {
            path: "<memory>".into(),
            problems: vec![format!("missing tensor '{name}'")],
        })
    }

    /// Serialises to safetensors bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let mut metadata: HashMap<String, String> = self.notes.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        metadata.insert(CONFIG_KEY.into(), serde_json::to_string(&self.config).expect("config serialises"));
        metadata.insert(FORMAT_KEY.into(), FORMAT_VERSION.into());
        let specs: BTreeMap<String, Vec<usize>> = tensor_specs(&self.config).into_iter().collect();
        let mut views = Vec::new();
        for (name, data) in &self.tensors {
            // Tensors keep their table shape; anything else (only possible through direct edits of `tensors`) is
            // written flat so that loading reports it.
            let shape = specs
                .get(name)
                .filter(|s| s.iter().product::<usize>() == data.len())
                .cloned()
                .unwrap_or_else(|| vec![data.len()]);
            let view = TensorView::new(Dtype::F32, shape, bytemuck::cast_slice(data))
                .map_err(|e| Error::invalid(format!("tensor '{name}': {e}")))?;
            views.push((name.clone(), view));
        }
        safetensors::serialize(views, Some(metadata)).map_err(|e| Error::invalid(format!("serialising weights: {e}")))
    }

    /// Writes a safetensors file atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::io::write_atomic(path, &self.to_bytes()?)
    }

    /// The shipped default weights (`weights/default.safetensors`), compiled into the library.
    pub fn built_in() -> Result<Weights> {
        Ok(Weights::built_in_view()?.into_owned())
    }

    /// [`Weights::built_in`] read in place: the tensors borrow the library's own bytes (no copy), for building
    /// a model ([`crate::model::Model::from_view`]).
    pub fn built_in_view() -> Result<WeightsView<'static>> {
        WeightsView::from_bytes(BUILT_IN_WEIGHTS, "built-in default weights")
    }

    /// These weights as a view (borrowed), for building a model.
    pub fn view(&self) -> WeightsView<'_> {
        let tensors = self.tensors.iter().map(|(n, t)| (n.clone(), Cow::Borrowed(t.as_slice()))).collect();
        WeightsView { config: self.config.clone(), tensors, notes: self.notes.clone() }
    }

    /// Reads and checks a weights file (at most 1 GiB).
    pub fn load(path: &Path) -> Result<Weights> {
        let bytes = crate::io::read_file_bounded(path, 1 << 30)?;
        Weights::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses and checks safetensors bytes; `origin` names them in errors.
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Weights> {
        Ok(WeightsView::from_bytes(bytes, origin)?.into_owned())
    }
}

/// Checked weights whose tensors borrow the safetensors bytes they were read from where those hold aligned
/// little-endian f32 (the built-in weights), else own a copy: what building a model needs, with no copy of
/// the bytes ([`Weights::built_in_view`], [`Weights::view`]).
#[derive(Clone, Debug)]
pub struct WeightsView<'a> {
    /// The configuration the tensors were made for.
    pub config: ModelConfig,
    tensors: BTreeMap<String, Cow<'a, [f32]>>,
    notes: BTreeMap<String, String>,
}

impl<'a> WeightsView<'a> {
    /// A tensor by name (as [`Weights::get`]).
    pub fn get(&self, name: &str) -> Result<&[f32]> {
        self.tensors.get(name).map(|t| &**t).ok_or_else(|| Error::Weights {
            path: "<memory>".into(),
            problems: vec![format!("missing tensor '{name}'")],
        })
    }

    /// The weights, owned.
    pub fn into_owned(self) -> Weights {
        let tensors = self.tensors.into_iter().map(|(n, t)| (n, t.into_owned())).collect();
        Weights { config: self.config, tensors, notes: self.notes }
    }

    /// [`Weights::from_bytes`], borrowing `bytes` where it can.
    pub fn from_bytes(bytes: &'a [u8], origin: &str) -> Result<WeightsView<'a>> {
        let fail = |problems: Vec<String>| Error::Weights { path: origin.to_string(), problems };
        let declared = bytes.first_chunk::<8>().map(|n| u64::from_le_bytes(*n).saturating_add(8));
        if declared.is_some_and(|d| d > bytes.len() as u64 && d <= (100 << 20)) {
            return Err(fail(vec![format!("truncated: {} bytes end inside the safetensors header", bytes.len())]));
        }
        let (_, meta) = SafeTensors::read_metadata(bytes).map_err(|e| match e {
            safetensors::SafeTensorError::MetadataIncompleteBuffer => fail(vec![match described_len(bytes) {
                Some(n) if n > bytes.len() => format!("truncated: {} bytes, its header describes {n}", bytes.len()),
                Some(n) => format!("{} bytes after the {n} its header describes", bytes.len() - n),
                None => format!("not a safetensors file: {e}"),
            }]),
            e => fail(vec![format!("not a safetensors file: {e}")]),
        })?;
        let mut notes: BTreeMap<String, String> = meta.metadata().clone().unwrap_or_default().into_iter().collect();
        let config_json = notes
            .remove(CONFIG_KEY)
            .ok_or_else(|| fail(vec![format!("metadata has no '{CONFIG_KEY}' (not a dpr-gpu weights file)")]))?;
        notes.remove(FORMAT_KEY);
        let config: ModelConfig = serde_json::from_str(&config_json)
            .map_err(|e| fail(vec![format!("metadata '{CONFIG_KEY}' is not a valid model config: {e}")]))?;
        config.validate().map_err(|e| fail(vec![e.to_string()]))?;
        let st = SafeTensors::deserialize(bytes).map_err(|e| fail(vec![format!("corrupt safetensors: {e}")]))?;

        let expected: BTreeMap<String, Vec<usize>> = tensor_specs(&config).into_iter().collect();
        let mut problems = Vec::new();
        let mut tensors = BTreeMap::new();
        let mut present: Vec<String> = st.names().into_iter().map(str::to_string).collect();
        present.sort();
        for name in &present {
            let view = st.tensor(name).map_err(|e| fail(vec![format!("tensor '{name}': {e}")]))?;
            let Some(shape) = expected.get(name) else {
                problems.push(format!("unexpected tensor '{name}'"));
                continue;
            };
            if view.dtype() != Dtype::F32 {
                problems.push(format!("tensor '{name}' has dtype {:?}, expected F32", view.dtype()));
                continue;
            }
            if view.shape() != shape.as_slice() {
                problems.push(format!("tensor '{name}' has shape {:?}, expected {:?}", view.shape(), shape));
                continue;
            }
            let data = le_f32s(view.data());
            if let Some(i) = data.iter().position(|v| !v.is_finite()) {
                problems.push(format!("tensor '{name}' element {i} is not finite"));
                continue;
            }
            tensors.insert(name.clone(), data);
        }
        for name in expected.keys() {
            if !present.contains(name) {
                problems.push(format!("missing tensor '{name}'"));
            }
        }
        if !problems.is_empty() {
            return Err(fail(problems));
        }
        Ok(WeightsView { config, tensors, notes })
    }
}

/// Little-endian f32 bytes as values: read in place where they are aligned (and the CPU little-endian), else
/// one copy (and a byte swap on a big-endian CPU). A trailing partial value is ignored.
fn le_f32s(bytes: &[u8]) -> Cow<'_, [f32]> {
    let n = bytes.len() / 4;
    let bytes = &bytes[..n * 4];
    if cfg!(target_endian = "little")
        && let Ok(values) = bytemuck::try_cast_slice::<u8, f32>(bytes)
    {
        return Cow::Borrowed(values);
    }
    let mut data = vec![0f32; n];
    bytemuck::cast_slice_mut::<f32, u8>(&mut data).copy_from_slice(bytes);
    if cfg!(target_endian = "big") {
        data.iter_mut().for_each(|v| *v = f32::from_bits(v.to_bits().swap_bytes()));
    }
    Cow::Owned(data)
}

/// The file length a safetensors header describes (8 + header + the largest tensor end offset).
fn described_len(bytes: &[u8]) -> Option<usize> {
    let n = usize::try_from(u64::from_le_bytes(*bytes.first_chunk::<8>()?)).ok()?;
    let header: serde_json::Value = serde_json::from_slice(bytes.get(8..8usize.checked_add(n)?)?).ok()?;
    let end = header.as_object()?.values().filter_map(|t| t.get("data_offsets")?.get(1)?.as_u64()).max().unwrap_or(0);
    (8 + n).checked_add(usize::try_from(end).ok()?)
}
