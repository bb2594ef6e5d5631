"""The registration page (web/index.html) in a real browser: headless Chromium driven through the DevTools
protocol, the page served from 127.0.0.1 (a secure context, as WebGPU needs).

Checks: the kernel parity page (web/parity.html: every case of `dpr_gpu::gpu::parity`, the native parity tests'
inputs, twins and tolerances, on the browser's WebGPU adapter) passes; and for each backend asked for (`--backends`, default `cpu gpu`: the CPU path, then WebGPU on the browser's
adapter, SwiftShader in CI):
- the example pair registers in the page with the verdict `success` and the pose of the native command line
  (`--native-pose`: the file `dpr-gpu register ... --out` wrote) within 0.1 degree and 1 mm;
- after registering, a screenshot of the page's picture holds both scans: at least `MIN_SCAN_PIXELS` pixels of the
  source colour and of the target colour (src/snapshot's SOURCE_RGB and TARGET_RGB), as tests/snapshot.rs counts;
- a corrupt file shows a clear error on the page, naming the file;
- the one-call API `register(sourceXyz, targetXyz, options)` undoes a known motion of the example target.
Prints one JSON line of figures (wasm size, the page's time per backend, the adapter) and exits non-zero on any
failure. Needs `websocket-client` (PyPI) and Debian's `chromium-headless-shell`; build the package first
(`bash web/build.sh`).
"""

import argparse
import base64
import http.server
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import zlib

import websocket

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SOURCE_RGB = (230, 159, 0)
TARGET_RGB = (0, 114, 178)
MIN_SCAN_PIXELS = 500
MAX_ROTATION_DEG = 0.1
MAX_TRANSLATION = 1e-3


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(root):
    """Serves `root` on 127.0.0.1 in a thread; returns the base URL."""
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=root, **k)
    http.server.SimpleHTTPRequestHandler.log_message = lambda *a: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return f"http://127.0.0.1:{server.server_address[1]}"


class Browser:
    """One headless Chromium with WebGPU on (SwiftShader unless the machine has a GPU) and one page."""

    def __init__(self, binary, adapter):
        self.profile = tempfile.mkdtemp(prefix="dpr-chromium-")
        port = free_port()
        args = [binary, "--headless", "--no-sandbox", "--disable-gpu-sandbox", f"--remote-debugging-port={port}",
                f"--user-data-dir={self.profile}", "--enable-unsafe-webgpu", "--window-size=1200,2000",
                "--no-first-run", "about:blank"]
        if adapter:
            args.insert(-1, f"--use-webgpu-adapter={adapter}")
        self.process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.time() + 60
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as r:
                    pages = [t for t in json.load(r) if t["type"] == "page"]
                if pages:
                    break
            except OSError:
                pass
            if time.time() > deadline or self.process.poll() is not None:
                raise SystemExit(f"chromium did not start: {self.process.stderr.read().decode()[-2000:]}")
            time.sleep(0.2)
        self.ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"], timeout=900)
        self.next_id = 0
        self.console = []
        self.call("Runtime.enable")
        self.call("Page.enable")

    def call(self, method, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.ws.recv())
            if message.get("method") == "Runtime.consoleAPICalled":
                args = message["params"]["args"]
                self.console.append(" ".join(str(a.get("value", a.get("description", ""))) for a in args))
            if message.get("method") == "Runtime.exceptionThrown":
                self.console.append(json.dumps(message["params"]["exceptionDetails"])[:500])
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def eval(self, expression):
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression[:80]}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression, timeout, what):
        deadline = time.time() + timeout
        while time.time() < deadline:
            value = self.eval(expression)
            if value:
                return value
            time.sleep(0.25)
        raise RuntimeError(f"timed out after {timeout} s waiting for {what}; console: {self.console[-10:]}")

    def close(self):
        try:
            self.ws.close()
        finally:
            self.process.kill()
            self.process.wait()
            shutil.rmtree(self.profile, ignore_errors=True)


def decode_png(data):
    """RGBA rows of an 8-bit, non-interlaced RGB or RGBA PNG (what Chromium's screenshots are)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, width, height, channels = 8, b"", 0, 0, 0
    while pos < len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            width, height = int.from_bytes(body[0:4], "big"), int.from_bytes(body[4:8], "big")
            depth, colour, interlace = body[8], body[9], body[12]
            assert depth == 8 and colour in (2, 6) and interlace == 0, f"unsupported PNG {depth}/{colour}/{interlace}"
            channels = 3 if colour == 2 else 4
        elif kind == b"IDAT":
            idat += body
    raw, stride = zlib.decompress(idat), width * channels
    rows, previous = [], bytearray(stride)
    for y in range(height):
        kind, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - channels] if i >= channels else 0
            b, c = previous[i], previous[i - channels] if i >= channels else 0
            if kind == 1:
                line[i] = (line[i] + a) & 255
            elif kind == 2:
                line[i] = (line[i] + b) & 255
            elif kind == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line))
        previous = line
    return width, height, channels, rows


def count_colours(png):
    width, height, channels, rows = decode_png(png)
    counts = {SOURCE_RGB: 0, TARGET_RGB: 0}
    for row in rows:
        for x in range(width):
            rgb = tuple(row[x * channels:x * channels + 3])
            if rgb in counts:
                counts[rgb] += 1
    return counts[SOURCE_RGB], counts[TARGET_RGB]


def pose_error(a, b):
    """Rotation angle (degrees) and translation distance between two row-major 4x4 poses."""
    ra = [[a[4 * r + c] for c in range(3)] for r in range(3)]
    rb = [[b[4 * r + c] for c in range(3)] for r in range(3)]
    trace = sum(ra[k][i] * rb[k][i] for i in range(3) for k in range(3))  # trace(Ra^T Rb)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (trace - 1) / 2))))
    shift = math.dist([a[3], a[7], a[11]], [b[3], b[7], b[11]])
    return angle, shift


def check_backend(browser, base, backend, native):
    browser.call("Page.navigate", url=f"{base}/web/index.html")
    browser.wait_for("window.dpr && window.dpr.state === 'idle'", 120, "the module to load")
    browser.eval("document.getElementById('backend').value = " + json.dumps(backend))
    browser.eval("document.getElementById('example').click()")
    browser.wait_for("!document.getElementById('register').disabled", 120, "the example pair to load")
    browser.eval("document.getElementById('register').click()")
    state = browser.wait_for("['done', 'error'].includes(window.dpr.state) && window.dpr.state", 1800,
                             f"the {backend} registration")
    if state != "done":
        raise RuntimeError(f"{backend}: the page reported: {browser.eval('window.dpr.error')}")
    result = browser.eval("window.dpr.result")
    seconds = browser.eval("window.dpr.seconds")
    adapter = browser.eval("window.dpr.backend + (window.dpr.backend.startsWith('gpu') && window.dpr.adapter ? "
                           "' on ' + window.dpr.adapter : '')")
    failures = []
    if not result["success"]:
        failures.append(f"{backend}: verdict not trusted: {result['reason']}")
    angle, shift = pose_error(result["targetFromSource"], native)
    if angle > MAX_ROTATION_DEG or shift > MAX_TRANSLATION:
        failures.append(f"{backend}: pose differs from the native one by {angle:.4f} deg, {shift:.6f} (limits "
                        f"{MAX_ROTATION_DEG} deg, {MAX_TRANSLATION})")
    box = browser.eval("(() => { const r = document.getElementById('picture').getBoundingClientRect(); "
                       "return {x: r.x + scrollX, y: r.y + scrollY, width: r.width, height: r.height}; })()")
    shot = browser.call("Page.captureScreenshot", format="png", captureBeyondViewport=True,
                        clip={**box, "scale": 1})
    png = base64.b64decode(shot["data"])
    source_pixels, target_pixels = count_colours(png)
    page = base64.b64decode(browser.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)["data"])
    if source_pixels < MIN_SCAN_PIXELS or target_pixels < MIN_SCAN_PIXELS:
        failures.append(f"{backend}: the picture shows {source_pixels} source and {target_pixels} target pixels "
                        f"(at least {MIN_SCAN_PIXELS} each expected)")
    return failures, {"backend": adapter, "seconds": round(seconds, 3), "rotation_error_deg": round(angle, 5),
                      "translation_error": round(shift, 7), "source_pixels": source_pixels,
                      "target_pixels": target_pixels}, page


def check_corrupt_file(browser, base):
    browser.call("Page.navigate", url=f"{base}/web/index.html")
    browser.wait_for("window.dpr && window.dpr.state === 'idle'", 120, "the module to load")
    browser.eval("""(() => {
        const bytes = new TextEncoder().encode('ply\\nformat ascii 1.0\\nelement vertex 3\\nproperty float x\\n' +
            'property float y\\nproperty float z\\nend_header\\n1 2 3\\n4 five 6\\n');
        const file = new File([bytes], 'broken.ply');
        const transfer = new DataTransfer();
        transfer.items.add(file);
        const input = document.getElementById('source-file');
        input.files = transfer.files;
        input.dispatchEvent(new Event('change'));
    })()""")
    browser.wait_for("window.dpr.state === 'error'", 60, "the corrupt file's error")
    text = browser.eval("document.getElementById('status').textContent")
    shown = browser.eval("getComputedStyle(document.getElementById('status')).display !== 'none'")
    if "broken.ply" not in text or not shown:
        return [f"corrupt file: the page shows '{text}' (expected an error naming broken.ply)"], text
    return [], text


def check_xyz_api(browser, base):
    """The one-call API `register(sourceXyz, targetXyz, options)` on the CPU path, against a known motion: the
    example target's points (every third) as the target, the same points moved by `KNOWN` as the source; the
    pose must undo the motion."""
    angle, axis, shift = math.radians(40.0), (0.36, 0.48, 0.8), (0.3, -0.2, 0.1)
    c, s_, (x, y, z) = math.cos(angle), math.sin(angle), axis
    rotation = [[c + x * x * (1 - c), x * y * (1 - c) - z * s_, x * z * (1 - c) + y * s_],
                [y * x * (1 - c) + z * s_, c + y * y * (1 - c), y * z * (1 - c) - x * s_],
                [z * x * (1 - c) - y * s_, z * y * (1 - c) + x * s_, c + z * z * (1 - c)]]
    known = [v for r in range(3) for v in rotation[r] + [shift[r]]] + [0, 0, 0, 1]
    result = browser.eval("""(async () => {
        const m = await import('/web/pkg/dpr_gpu_web.js');
        const bytes = new Uint8Array(await (await fetch('/examples/pair/cloud_bin_0.ply')).arrayBuffer());
        const all = m.readCloud('cloud_bin_0.ply', bytes).points;
        const T = %s;
        const n = Math.floor(all.length / 9);
        const target = new Float32Array(3 * n), source = new Float32Array(3 * n);
        for (let i = 0; i < n; i++) {
            const [x, y, z] = [all[9 * i], all[9 * i + 1], all[9 * i + 2]];
            target.set([x, y, z], 3 * i);
            for (let r = 0; r < 3; r++) source[3 * i + r] = T[4 * r] * x + T[4 * r + 1] * y + T[4 * r + 2] * z + T[4 * r + 3];
        }
        const r = await m.register(source, target, { backend: 'cpu' });
        return { pose: r.targetFromSource, success: r.success, reason: r.reason };
    })()""" % json.dumps(known))
    # target_from_source undoes KNOWN: its rotation is KNOWN's transposed, its translation -R^T t.
    inverse = [rotation[c][r] for r in range(3) for c in range(3)]
    t = [-sum(rotation[k][r] * shift[k] for k in range(3)) for r in range(3)]
    expected = inverse[0:3] + [t[0]] + inverse[3:6] + [t[1]] + inverse[6:9] + [t[2]] + [0, 0, 0, 1]
    angle_error, shift_error = pose_error(result["pose"], expected)
    figures = {"rotation_error_deg": round(angle_error, 5), "translation_error": round(shift_error, 7)}
    if not result["success"] or angle_error > 0.5 or shift_error > 0.01:
        return [f"register(xyz, xyz): success {result['success']} ({result['reason']}), {angle_error:.3f} deg, "
                f"{shift_error:.4f} from the known motion (limits 0.5 deg, 0.01)"], figures
    return [], figures


def check_parity(browser, base):
    """The kernel parity page: every case of dpr_gpu::gpu::parity on the browser's WebGPU adapter."""
    browser.call("Page.navigate", url=f"{base}/web/parity.html")
    state = browser.wait_for("window.parity && ['passed', 'failed'].includes(window.parity.state) && "
                             "window.parity.state", 3600, "the kernel parity page")
    results = browser.eval("window.parity.results")
    figures = {"cases": len(results), "skipped": [r["name"] for r in results if r["outcome"].startswith("skipped")],
               "seconds": round(sum(r["ms"] for r in results) / 1000, 1)}
    if state != "passed":
        return [f"kernel parity page: {browser.eval('window.parity.failure')}"], figures
    return [], figures


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--native-pose", required=True, help="target_from_source written by `register --out`")
    parser.add_argument("--backends", nargs="+", default=["cpu", "gpu"], choices=["cpu", "gpu", "auto"])
    parser.add_argument("--chromium", default=shutil.which("chromium-headless-shell") or "chromium-headless-shell")
    parser.add_argument("--adapter", default="swiftshader", help="--use-webgpu-adapter ('' for the default)")
    parser.add_argument("--skip-parity", action="store_true", help="leave out the kernel parity page")
    parser.add_argument("--screenshot", help="write a screenshot of the page after the last registration here (PNG)")
    args = parser.parse_args()
    with open(args.native_pose) as f:
        native = [float(v) for v in f.read().split()]
    if len(native) != 16:
        raise SystemExit(f"{args.native_pose}: expected 16 numbers, found {len(native)}")
    wasm = os.path.join(ROOT, "web", "pkg", "dpr_gpu_web_bg.wasm")
    if not os.path.exists(wasm):
        raise SystemExit(f"{wasm} is missing: run `bash web/build.sh` first")
    base = serve(ROOT)
    browser = Browser(args.chromium, args.adapter)
    failures, figures = [], {"wasm_bytes": os.path.getsize(wasm), "runs": []}
    try:
        for backend in args.backends:
            try:
                found, run, png = check_backend(browser, base, backend, native)
            except RuntimeError as e:
                failures.append(f"{backend}: {e}")
                continue
            failures += found
            figures["runs"].append(run)
            if args.screenshot:
                with open(args.screenshot, "wb") as f:
                    f.write(png)
        if not args.skip_parity:
            found, figures["kernel_parity"] = check_parity(browser, base)
            failures += found
        found, figures["corrupt_file_message"] = check_corrupt_file(browser, base)
        failures += found
        found, figures["xyz_api_known_motion"] = check_xyz_api(browser, base)
        failures += found
    finally:
        browser.close()
    print(json.dumps(figures))
    for f in failures:
        print(f"FAIL: {f}", file=sys.stderr)
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
