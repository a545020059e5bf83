#!/usr/bin/env bash
# A first look at papers/000's local-fitting finding on lfit data: scan modality, local scenario,
# 20 frames, budget 2000, every zeroth-order optimizer on the same energy (papers/000 eq. 3 with
# the §4.1 weights). Prints mean final energy, V2V and time per optimizer, best first.
#   docs/results/first_look.sh target/release/lfit out/first_look
set -euo pipefail
LFIT=${1:-lfit}
OUT=${2:-out/first_look}
mkdir -p "$OUT"
"$LFIT" synth --modality scan --scenario local --frames 20 --seed 2026 --out "$OUT/scan_local.npz" -q > /dev/null
for m in random one-plus-one de pso cma tbpsa powell cma-powell ngo apf psapf; do
  "$LFIT" fit --data "$OUT/scan_local.npz" --method "$m" --budget 2000 --seed 1 --out "$OUT/$m.json" -q > /dev/null
done
python3 - "$OUT" <<'PY'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
rows = []
for f in sorted(out.glob("*.json")):
    r = json.loads(f.read_text())
    s = r["summary"]
    start = sum(fr["start_energy"] for fr in r["frames"]) / len(r["frames"])
    rows.append((s["mean_energy"], r["method"], s["mean_v2v_mm"], s["mean_time_s"], start))
print("| optimizer | mean final energy | mean V2V (mm) | time/frame (s) |")
print("|---|---|---|---|")
for e, m, v, t, start in sorted(rows):
    print(f"| {m} | {e:.5f} | {v:.1f} | {t:.2f} |")
print(f"\nmean start energy: {rows[0][4]:.5f}")
PY
