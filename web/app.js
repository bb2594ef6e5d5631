// The registration page: reads two scans from files (or the shipped example pair), registers them with the
// wasm package on WebGPU (or the CPU) and shows the verdict, the pose, the stage times and a snapshot.
// `window.dpr` mirrors the page's state for scripts that drive it (tests/web/check_page.py).
import init, { readCloud, Session, snapshot } from "./pkg/dpr_gpu_web.js";

const $ = (id) => document.getElementById(id);
const scans = { source: null, target: null };
const sessions = {};
window.dpr = { state: "loading", result: null, error: null, backend: null, seconds: null };

function status(text, kind = "") {
  $("status").textContent = text;
  $("status").className = kind;
}

function fail(message) {
  window.dpr.state = "error";
  window.dpr.error = message;
  status(message, "error");
  $("register").disabled = !(scans.source && scans.target);
}

function ready() {
  $("register").disabled = !(scans.source && scans.target);
}

function load(which, name, bytes) {
  try {
    const cloud = readCloud(name, new Uint8Array(bytes));
    scans[which] = { name, cloud };
    $(`${which}-info`).textContent = `${name}: ${cloud.length.toLocaleString()} points` +
      (cloud.normals ? " with normals" : "");
    window.dpr.state = "loaded";
    window.dpr.error = null;
    status("Ready to register.");
  } catch (e) {
    scans[which] = null;
    $(`${which}-info`).textContent = "";
    fail(`Could not read ${name}: ${e.message ?? e}`);
  }
  ready();
}

async function loadFile(which, file) {
  if (file) load(which, file.name, await file.arrayBuffer());
}

for (const which of ["source", "target"]) {
  $(`${which}-file`).addEventListener("change", (e) => loadFile(which, e.target.files[0]));
  const drop = $(`${which}-drop`);
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    loadFile(which, e.dataTransfer.files[0]);
  });
}

async function example() {
  status("Fetching the example pair...");
  // The shipped pair, registered as the README's command does: cloud_bin_1 onto cloud_bin_0.
  for (const [which, name] of [["source", "cloud_bin_1.ply"], ["target", "cloud_bin_0.ply"]]) {
    const response = await fetch(`../examples/pair/${name}`);
    if (!response.ok) return fail(`Could not fetch the example ${name}: HTTP ${response.status}`);
    load(which, name, await response.arrayBuffer());
  }
}

function showResult(result, seconds) {
  const t = result.targetFromSource;
  const rows = [0, 1, 2, 3].map((r) => t.slice(4 * r, 4 * r + 4).map((v) => v.toFixed(6).padStart(11)).join(" "));
  $("pose").textContent = rows.join("\n");
  $("support").textContent = `${result.inliers} inliers of ${result.correspondences} correspondences ` +
    `(fitness ${result.fitness.toFixed(3)}), ${result.keypoints} keypoints per scan, ` +
    `patch radius ${result.scale.radius.toPrecision(3)}.`;
  $("timings").replaceChildren(...result.timings.map((s) => {
    const row = document.createElement("tr");
    row.innerHTML = `<td>${s.stage}</td><td>${(1000 * s.seconds).toFixed(1)} ms</td>`;
    return row;
  }));
  $("result").hidden = false;
  const verdict = result.success ? "success" : `NOT TRUSTED: ${result.reason}`;
  const on = result.backend.startsWith("gpu") && window.dpr.adapter ?
    `WebGPU (${window.dpr.adapter}; ${result.backend})` : result.backend;
  status(`Verdict: ${verdict}. ${seconds.toFixed(2)} s on ${on}.`,
    result.success ? "success" : "untrusted");
  const picture = snapshot(scans.source.cloud, scans.target.cloud, t, 300);
  const canvas = $("picture");
  canvas.width = picture.width;
  canvas.height = picture.height;
  canvas.getContext("2d").putImageData(
    new ImageData(new Uint8ClampedArray(picture.rgba), picture.width, picture.height), 0, 0);
  canvas.hidden = false;
  $("picture-title").hidden = false;
}

// The WebGPU adapter as the browser names it (vendor / architecture), for the page; wgpu's name is often empty.
async function adapterName() {
  const adapter = navigator.gpu ? await navigator.gpu.requestAdapter() : null;
  const info = adapter?.info;
  return info ? [info.vendor, info.architecture, info.description].filter((s) => s).join(" / ") : null;
}

async function registerPair() {
  $("register").disabled = true;
  window.dpr.state = "running";
  window.dpr.error = null;
  try {
    status("Preparing the backend...");
    // One session per backend choice: a WebGPU session compiles every kernel once, not on each registration.
    const choice = $("backend").value;
    sessions[choice] ??= await Session.create({ backend: choice });
    const session = sessions[choice];
    window.dpr.backend = session.backend;
    window.dpr.adapter = await adapterName();
    const started = performance.now();
    const ticker = setInterval(() => {
      const stage = session.progress;
      status(`Registering on ${session.backend}: ${((performance.now() - started) / 1000).toFixed(1)} s` +
        (stage ? `, finished ${stage}` : ""));
    }, 100);
    let result;
    try {
      result = await session.register(scans.source.cloud, scans.target.cloud);
    } finally {
      clearInterval(ticker);
    }
    const seconds = (performance.now() - started) / 1000;
    showResult(result, seconds);
    window.dpr.result = result;
    window.dpr.seconds = seconds;
    window.dpr.state = "done";
  } catch (e) {
    fail(`Registration failed: ${e.message ?? e}`);
  }
  ready();
}

$("example").addEventListener("click", example);
$("register").addEventListener("click", registerPair);

try {
  await init();
  window.dpr.state = "idle";
  status(navigator.gpu ? "Pick two scans, or load the example pair." :
    "This browser has no WebGPU: registration runs on the CPU. Pick two scans, or load the example pair.");
} catch (e) {
  fail(`Could not load the module: ${e.message ?? e}`);
}
