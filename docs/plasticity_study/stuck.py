"""Does a network that never hovered in segment 0 hover later? Per agent and change, from the archive's runs.

    .venv/bin/python docs/plasticity_study/stuck.py > docs/plasticity_study/stuck.md

'Hovered' = some in-training evaluation with success > 0 (eval/success_rate, flights under the current condition);
segment 0 = evaluations at steps <= 3M; later = after 3M and before 18M (the last evaluation at 18M is left out:
reset_all's and the twins' flew a fresh draw before 6a13cd5). Reads the archive files directly (no store)."""
import collections
import glob
import json
from pathlib import Path

import numpy as np

ARCHIVE = Path(__file__).parent / "runs" / "plasticity"
SEGMENT, END = 3_000_000, 18_000_000
counts = collections.defaultdict(lambda: [0, 0, 0, 0])  # failed in seg 0, of them never later, hovered in seg 0, runs
for f in sorted(glob.glob(str(ARCHIVE / "*.npz"))):
    d = np.load(f, allow_pickle=True)
    meta = json.loads(str(d["meta"]))
    i = meta["metrics"].index("eval/success_rate")
    step, value = d[f"m{i}_step"], d[f"m{i}_value"]
    value, step = value[step < END], step[step < END]
    change = "flip" if meta["params"].get("wind.name", meta["tags"].get("wind")) == "flip" else "payload"
    c = counts[(change, meta["tags"]["agent"])]
    first, later = (value[step <= SEGMENT] > 0).any(), (value[step > SEGMENT] > 0).any()
    c[3] += 1
    if first:
        c[2] += 1
    else:
        c[0] += 1
        c[1] += not later
print("| change | agent | runs | hovered in segment 0 | never hovered in segment 0 | of those, hovered later |")
print("|---|---|---|---|---|---|")
for (change, agent), (failed, never, hovered, runs) in sorted(counts.items()):
    print(f"| {change} | {agent} | {runs} | {hovered} | {failed} | {failed - never} of {failed} |")
