//! dpr-gpu in the browser: the library built for `wasm32-unknown-unknown`, its GPU stages on the visitor's GPU
//! through WebGPU (wgpu's WebGPU backend), the CPU reference path when the browser has no WebGPU.
//!
//! The JavaScript API (`web/pkg/dpr_gpu_web.js`, written by `web/build.sh`):
//! - `readCloud(name, bytes)`: a [`Cloud`] from a PLY, PCD or XYZ file's bytes (an `ArrayBuffer` as a
//!   `Uint8Array`), the format from `name`'s extension, with the native reader's limits and checks; a corrupt file
//!   throws an `Error` naming the file and the problem.
//! - `Cloud.fromXyz(Float32Array)`: a cloud from packed x y z values.
//! - `await Session.create({backend, radius, seed})`: a registrar; `backend` is `"auto"` (WebGPU when the browser
//!   has an adapter, else the CPU), `"gpu"` (WebGPU or an error) or `"cpu"`.
//! - `await session.register(source, target)`: the result as a plain object: `targetFromSource` (16 numbers,
//!   row-major, p_target = T p_source), `success`, `reason`, `inliers`, `fitness`, `correspondences`, `keypoints`,
//!   `timings` (stage, seconds), `backend`, `scale`; `session.progress` names the last stage finished.
//! - `await register(sourceXyz, targetXyz, options)`: both in one call, for packed x y z arrays.
//! - `snapshot(source, target, targetFromSource, panelPx)`: the command line's snapshot (top, front and side
//!   views before and after) as RGBA pixels for a canvas.
//! - `parityCases()` and `await runParityCase(name)`: the kernel parity cases of `tests/gpu_parity.rs`
//!   (`dpr_gpu::gpu::parity`) on the browser's WebGPU adapter, for `web/parity.html`; a mismatch panics, and
//!   the panic's message is left in `globalThis.dprPanic`.
//!
//! Nothing leaves the page: files are read from the bytes the page hands over, the weights are built in.

use dpr_gpu::backend::Backend;
use dpr_gpu::gpu::{Gpu, GpuBackend, GpuContext, context::AdapterPolicy};
use dpr_gpu::snapshot::{SnapshotOptions, render_snapshot};
use dpr_gpu::{PointCloud, Registrar, RegistrationSettings};
use nalgebra::Matrix4;
use std::cell::Cell;
use std::rc::Rc;
use std::sync::{Arc, Mutex};
use wasm_bindgen::prelude::*;

/// A point cloud held in the module's memory (points, and normals when the file gave them).
#[wasm_bindgen]
pub struct Cloud {
    cloud: Rc<PointCloud>,
}

#[wasm_bindgen]
impl Cloud {
    /// A cloud from packed `x y z` values; non-finite points are an error.
    #[wasm_bindgen(js_name = fromXyz)]
    pub fn from_xyz(xyz: Vec<f32>) -> Result<Cloud, JsError> {
        if !xyz.len().is_multiple_of(3) {
            return Err(JsError::new(&format!("{} values are not x y z triples", xyz.len())));
        }
        let cloud = PointCloud::from_points(xyz.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect());
        cloud.validate("cloud").map_err(to_js)?;
        Ok(Cloud { cloud: Rc::new(cloud) })
    }

    /// Points.
    #[wasm_bindgen(getter)]
    pub fn length(&self) -> usize {
        self.cloud.len()
    }

    /// Packed `x y z` values.
    #[wasm_bindgen(getter)]
    pub fn points(&self) -> Vec<f32> {
        self.cloud.points.iter().flatten().copied().collect()
    }

    /// Packed normals, or `undefined` when the cloud has none.
    #[wasm_bindgen(getter)]
    pub fn normals(&self) -> Option<Vec<f32>> {
        self.cloud.normals.as_ref().map(|n| n.iter().flatten().copied().collect())
    }
}

/// Reads a PLY, PCD or XYZ file's bytes; `name` (the file's name) picks the format and names it in errors.
#[wasm_bindgen(js_name = readCloud)]
pub fn read_cloud(name: &str, bytes: &[u8]) -> Result<Cloud, JsError> {
    let (cloud, _) = dpr_gpu::io::read_cloud_bytes(name, bytes, &Default::default()).map_err(to_js)?;
    if cloud.is_empty() {
        return Err(JsError::new(&format!("{name}: the file has no points")));
    }
    Ok(Cloud { cloud: Rc::new(cloud) })
}

/// The options a page passes (any of them may be left out).
struct Options {
    backend: String,
    radius: Option<f32>,
    seed: Option<u64>,
}

fn options(value: &JsValue) -> Result<Options, JsError> {
    let field = |name: &str| -> JsValue {
        if value.is_object() {
            js_sys::Reflect::get(value, &name.into()).unwrap_or(JsValue::UNDEFINED)
        } else {
            JsValue::UNDEFINED
        }
    };
    let backend = field("backend").as_string().unwrap_or_else(|| "auto".into());
    if !["auto", "gpu", "cpu"].contains(&backend.as_str()) {
        return Err(JsError::new(&format!("backend '{backend}': expected auto, gpu or cpu")));
    }
    let number = |name: &str| -> Result<Option<f64>, JsError> {
        let v = field(name);
        if v.is_undefined() || v.is_null() {
            return Ok(None);
        }
        v.as_f64().filter(|x| x.is_finite()).map(Some).ok_or_else(|| JsError::new(&format!("{name} must be a number")))
    };
    let radius = number("radius")?.map(|r| r as f32);
    if radius.is_some_and(|r| r <= 0.0) {
        return Err(JsError::new("radius must be positive"));
    }
    let seed = match number("seed")? {
        Some(s) if s >= 0.0 && s.fract() == 0.0 && s <= 2f64.powi(53) => Some(s as u64),
        Some(_) => return Err(JsError::new("seed must be a whole number from 0 to 2^53")),
        None => None,
    };
    Ok(Options { backend, radius, seed })
}

/// A registrar in the page: its backend is chosen once (WebGPU or the CPU), and one registration runs at a time.
#[wasm_bindgen]
pub struct Session {
    registrar: Rc<Registrar>,
    busy: Rc<Cell<bool>>,
    last_stage: Arc<Mutex<String>>,
}

#[wasm_bindgen]
impl Session {
    /// A session with `options` (`{backend, radius, seed}`); see the module docs.
    pub async fn create(options_value: JsValue) -> Result<Session, JsError> {
        let o = options(&options_value)?;
        let mut settings = RegistrationSettings { radius: o.radius, ..RegistrationSettings::default() };
        if let Some(seed) = o.seed {
            settings.seed = seed;
        }
        let weights = dpr_gpu::pipeline::load_weights(&settings).map_err(to_js)?;
        let model = dpr_gpu::model::Model::from_weights(&weights).map_err(to_js)?;
        let backend: Box<dyn Backend> = match o.backend.as_str() {
            "cpu" => Box::new(dpr_gpu::backend::CpuBackend::new(model)),
            wanted => match webgpu().await {
                Ok(gpu) => Box::new(GpuBackend::with_gpu(Arc::new(gpu), model).map_err(to_js)?),
                Err(e) if wanted == "gpu" => return Err(JsError::new(&format!("no WebGPU adapter: {e}"))),
                Err(_) => Box::new(dpr_gpu::backend::CpuBackend::new(model)),
            },
        };
        let last_stage = Arc::new(Mutex::new(String::new()));
        let sink = Arc::clone(&last_stage);
        let registrar = Registrar::with_backend(&settings, backend).map_err(to_js)?.with_progress(Box::new(
            move |stage: &str, _seconds: f64| {
                if let Ok(mut s) = sink.lock() {
                    *s = stage.to_string();
                }
            },
        ));
        Ok(Session { registrar: Rc::new(registrar), busy: Rc::new(Cell::new(false)), last_stage })
    }

    /// The backend: `gpu (adapter; gemm variant)` or `cpu (...)`.
    #[wasm_bindgen(getter)]
    pub fn backend(&self) -> String {
        self.registrar.backend_name()
    }

    /// The last stage finished by the running registration (empty before the first).
    #[wasm_bindgen(getter)]
    pub fn progress(&self) -> String {
        self.last_stage.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// Registers `source` onto `target`; resolves to the result object (see the module docs). A second call
    /// while one runs is refused: the session's device buffers are in use.
    pub fn register(&self, source: &Cloud, target: &Cloud) -> js_sys::Promise {
        let (registrar, busy) = (Rc::clone(&self.registrar), Rc::clone(&self.busy));
        let (source, target) = (Rc::clone(&source.cloud), Rc::clone(&target.cloud));
        wasm_bindgen_futures::future_to_promise(async move {
            if busy.replace(true) {
                return Err(JsError::new("a registration is already running in this session").into());
            }
            let result = registrar.register_async(&source, &target).await;
            busy.set(false);
            let result = result.map_err(|e| JsValue::from(to_js(e)))?;
            result_object(&result)
        })
    }
}

/// Registers packed `x y z` arrays in one call (a session made with `options`).
#[wasm_bindgen]
pub async fn register(source_xyz: Vec<f32>, target_xyz: Vec<f32>, options: JsValue) -> Result<JsValue, JsValue> {
    let session = Session::create(options).await?;
    let (source, target) = (Cloud::from_xyz(source_xyz)?, Cloud::from_xyz(target_xyz)?);
    wasm_bindgen_futures::JsFuture::from(session.register(&source, &target)).await
}

/// The registration result as a plain object: the command line's JSON fields plus `targetFromSource`.
fn result_object(result: &dpr_gpu::RegistrationResult) -> Result<JsValue, JsValue> {
    let mut json = serde_json::to_value(result).map_err(|e| JsError::new(&e.to_string()))?;
    let t = &result.estimate.target_from_source;
    let rows: Vec<f64> = (0..4).flat_map(|r| (0..4).map(move |c| t[(r, c)])).collect();
    json["targetFromSource"] = serde_json::json!(rows);
    js_sys::JSON::parse(&json.to_string())
}

/// A rendered picture: `width x height` RGBA pixels.
#[wasm_bindgen]
pub struct Picture {
    width: u32,
    height: u32,
    rgba: Vec<u8>,
}

#[wasm_bindgen]
impl Picture {
    /// Pixels across.
    #[wasm_bindgen(getter)]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Pixels down.
    #[wasm_bindgen(getter)]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// RGBA bytes, row by row (for `new ImageData(new Uint8ClampedArray(rgba), width)`).
    #[wasm_bindgen(getter)]
    pub fn rgba(&self) -> Vec<u8> {
        self.rgba.clone()
    }
}

/// The snapshot of `source` and `target` before and after `target_from_source` (16 numbers, row-major), panels
/// of `panel_px` pixels.
#[wasm_bindgen]
pub fn snapshot(
    source: &Cloud,
    target: &Cloud,
    target_from_source: Vec<f64>,
    panel_px: u32,
) -> Result<Picture, JsError> {
    if target_from_source.len() != 16 {
        return Err(JsError::new("targetFromSource must have 16 numbers (row-major 4 x 4)"));
    }
    let t = Matrix4::from_row_slice(&target_from_source);
    let options = SnapshotOptions { panel_px, ..SnapshotOptions::default() };
    let shot = render_snapshot(&source.cloud, &target.cloud, &t, &options).map_err(to_js)?;
    Ok(Picture { width: shot.width(), height: shot.height(), rgba: shot.rgba().to_vec() })
}

/// The names of the kernel parity cases, in order.
#[wasm_bindgen(js_name = parityCases)]
pub fn parity_cases() -> Vec<String> {
    dpr_gpu::gpu::parity::CASES.iter().map(|c| c.name.to_string()).collect()
}

thread_local! {
    /// The device the parity cases share (made on the first case).
    static PARITY_GPU: std::cell::RefCell<Option<Rc<Gpu>>> = const { std::cell::RefCell::new(None) };
}

/// Runs the parity case `name` on the browser's WebGPU adapter: resolves to `"passed"` or `"skipped: reason"`;
/// a mismatch panics (the module traps; the message is in `globalThis.dprPanic`).
#[wasm_bindgen(js_name = runParityCase)]
pub async fn run_parity_case(name: String) -> Result<String, JsError> {
    record_panics();
    let case = dpr_gpu::gpu::parity::CASES
        .iter()
        .find(|c| c.name == name)
        .ok_or_else(|| JsError::new(&format!("no parity case named {name}")))?;
    let gpu = match PARITY_GPU.with(|g| g.borrow().clone()) {
        Some(gpu) => gpu,
        None => {
            let gpu = Rc::new(webgpu().await.map_err(to_js)?);
            PARITY_GPU.with(|g| *g.borrow_mut() = Some(Rc::clone(&gpu)));
            gpu
        }
    };
    Ok(match (case.run)(&gpu).await {
        dpr_gpu::gpu::parity::Outcome::Passed => "passed".into(),
        dpr_gpu::gpu::parity::Outcome::Skipped(reason) => format!("skipped: {reason}"),
    })
}

/// Leaves every panic's message in `globalThis.dprPanic` (and the console) before the module traps.
fn record_panics() {
    static HOOKED: std::sync::Once = std::sync::Once::new();
    HOOKED.call_once(|| {
        std::panic::set_hook(Box::new(|info| {
            let message = info.to_string();
            let _ = js_sys::Reflect::set(&js_sys::global(), &"dprPanic".into(), &message.clone().into());
            web_sys_console_error(&message);
        }))
    });
}

#[wasm_bindgen]
extern "C" {
    #[wasm_bindgen(js_namespace = console, js_name = error)]
    fn web_sys_console_error(message: &str);
}

/// A device on the browser's WebGPU adapter.
async fn webgpu() -> dpr_gpu::Result<Gpu> {
    let context = GpuContext::request(wgpu::Backends::BROWSER_WEBGPU, AdapterPolicy::Any).await?;
    Gpu::from_context(context)
}

fn to_js(e: dpr_gpu::Error) -> JsError {
    JsError::new(&e.to_string())
}
