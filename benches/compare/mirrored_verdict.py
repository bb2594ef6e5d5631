"""Issue 36 case 4: the verdict on every pair of the shared sets as given and with its source mirrored
(docs/experiments/mirrored-scans.md). Each registration is `dpr-gpu register SOURCE TARGET --json --backend cpu`
with no other flag; a row records the verdict, its reason, the rotation error against ground truth (real pairs)
and the wall time. One JSON line per registration on stdout, all rows in WORK/verdict.json.

    python benches/compare/mirrored_verdict.py target/release/dpr-gpu WORK [DATA]   (needs dpr_gpu, numpy)
"""
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from mirrored_pairs import default_data, mirrored_source, pairs, rot_err

CLI = sys.argv[1]
WORK = Path(sys.argv[2])
DATA = Path(sys.argv[3]) if len(sys.argv) > 3 else default_data()
WORK.mkdir(exist_ok=True)

rows = []
for k, (folder, src, tgt, truth) in enumerate(pairs(DATA)):
    mpath = WORK / f"mirrored_{k}.ply"
    mirrored_source(src, mpath)
    for kind, path in (("real", src), ("mirrored", mpath)):
        start = time.perf_counter()
        out = subprocess.run([CLI, "register", str(path), str(tgt), "--json", "--backend", "cpu"], capture_output=True, text=True)
        seconds = time.perf_counter() - start
        r = json.loads(out.stdout)
        pose = np.array(r["target_from_source"])
        row = dict(set=folder, source=src.name, target=tgt.name, kind=kind, trusted=r["success"], reason=r.get("reason"),
                   rot=rot_err(pose, truth) if kind == "real" else None, inliers=r["inliers"], seconds=round(seconds, 2))
        rows.append(row)
        print(json.dumps(row), flush=True)
(WORK / "verdict.json").write_text(json.dumps(rows, indent=1))
