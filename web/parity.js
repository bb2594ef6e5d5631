// Runs every kernel parity case (dpr_gpu::gpu::parity) on the browser's WebGPU adapter, one after another, and
// shows each outcome. `window.parity` mirrors the state for tests/web/check_page.py: `state` is "running",
// "passed" (every case passed or was skipped for a missing feature) or "failed"; `results` lists
// {name, outcome, ms}; `failure` holds the failing case's panic message.
import init, { parityCases, runParityCase } from "./pkg/dpr_gpu_web.js";

window.parity = { state: "loading", results: [], failure: null };
const summary = document.getElementById("summary");
const table = document.getElementById("cases");

function row(name, outcome, ms) {
  const tr = document.createElement("tr");
  const kind = outcome.startsWith("passed") ? "passed" : outcome.startsWith("skipped") ? "skipped" : "failed";
  tr.innerHTML = `<td>${name}</td><td class="${kind}"></td><td>${ms.toFixed(0)} ms</td>`;
  tr.children[1].textContent = outcome;
  table.appendChild(tr);
}

try {
  await init();
  if (!navigator.gpu) throw new Error("this browser has no WebGPU");
  const names = parityCases();
  window.parity.state = "running";
  for (const [i, name] of names.entries()) {
    summary.textContent = `Running ${i + 1} of ${names.length}: ${name}`;
    const started = performance.now();
    let outcome;
    try {
      outcome = await runParityCase(name);
    } catch (e) {
      const message = globalThis.dprPanic ?? String(e?.message ?? e);
      row(name, `FAILED: ${message}`, performance.now() - started);
      window.parity.results.push({ name, outcome: "failed", ms: performance.now() - started });
      window.parity.failure = `${name}: ${message}`;
      window.parity.state = "failed";
      summary.textContent = `FAILED at ${name} (the module stops at a failed case)`;
      break;
    }
    const ms = performance.now() - started;
    row(name, outcome, ms);
    window.parity.results.push({ name, outcome, ms });
  }
  if (window.parity.state === "running") {
    const skipped = window.parity.results.filter((r) => r.outcome.startsWith("skipped")).length;
    window.parity.state = "passed";
    summary.textContent = `All ${names.length} cases passed` + (skipped ? ` (${skipped} skipped: the adapter lacks a feature)` : "") + ".";
  }
} catch (e) {
  window.parity.state = "failed";
  window.parity.failure = String(e?.message ?? e);
  summary.textContent = `Could not run: ${window.parity.failure}`;
}
