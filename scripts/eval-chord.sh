#!/usr/bin/env bash
# The chord direction's markers fitter against the shipped Gauss-Newton one and LM, alternated in
# one lfit binary: the MocapBank clip's 454 local frames (./scripts/fetch-mocapbank.sh; an
# evaluation clip, never training data; the seed of docs/results/learned-vs-classical.md) and
# 500 procedural held-out local frames (the seed of scripts/speed-ab.sh), start near the target
# (`--neural-start given`, N = 5, budget 10; LM budget 4000), `--runtime native` at batch 1 on
# one thread and at --batch 256 on two threads; REPS rounds (default 3). Prints V2V, final
# energy, evaluations and ms per frame of every run. RUNTIMES=1 adds the clip at --batch 256 on
# two threads through Burn flex and ONNX Runtime (--ort-threads 2; ./scripts/fetch-onnxruntime.sh).
#
#   CHORD=checkpoints/markers-makehuman-chord scripts/eval-chord.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-chord}"
SEED=9103745171752751104
CHORD="${CHORD:-checkpoints/markers-makehuman-chord}"
BASE="${BASE:-checkpoints/markers-makehuman}"
source scripts/eval-common.sh
eval_setup eval-chord "$OUT"
eval_need_dir eval-chord "$CHORD"
eval_need_dir eval-chord "$BASE"
REPS="${REPS:-3}"
eval_local_sets "$OUT"
for rep in $(seq "$REPS"); do
    for d in clip proc; do
        for cfg in "1 1" "256 2"; do
            set -- $cfg
            for name in gn chord; do
                ck="$BASE"; [ "$name" = chord ] && ck="$CHORD"
                eval_native_fit "$LFIT" "$OUT/$d.npz" "$ck" "$1" "$2" "$OUT/r$rep-$d-$name-b$1.json"
            done
        done
        RAYON_NUM_THREADS=1 "$LFIT" -q fit --data "$OUT/$d.npz" --template "$MODEL" --method lm --budget 4000 \
            --out "$OUT/r$rep-$d-lm-b1.json" >/dev/null
    done
    if [ "${RUNTIMES:-0}" = 1 ]; then
        export ORT_DYLIB_PATH="${ORT_DYLIB_PATH:-$(./scripts/fetch-onnxruntime.sh)}"
        for name in gn chord; do
            ck="$BASE"; [ "$name" = chord ] && ck="$CHORD"
            for rt in burn ort; do
                a=(--runtime burn --device flex); [ "$rt" = ort ] && a=(--runtime ort --ort-threads 2)
                RAYON_NUM_THREADS=2 "$LFIT" -q fit --data "$OUT/clip.npz" --template "$MODEL" --method neural \
                    --checkpoint "$ck" --neural-start given "${a[@]}" --budget 10 --batch 256 \
                    --out "$OUT/r$rep-clip-$name-$rt.json" >/dev/null
            done
        done
    fi
done
python3 - "$OUT" "$REPS" <<'PY'
import json, sys
out, reps = sys.argv[1], int(sys.argv[2])
def load(rep, d, n, b): return json.load(open(f"{out}/r{rep}-{d}-{n}-b{b}.json"))
print("| frames | fitter, batch | V2V mm | energy | evaluations per frame | ms per frame (each run) |")
print("|---|---|---|---|---|---|")
for d in ["clip", "proc"]:
    for n, b in [("gn", 1), ("chord", 1), ("lm", 1), ("gn", 256), ("chord", 256)]:
        runs = [load(r, d, n, b) for r in range(1, reps + 1)]
        s = runs[0]["summary"]
        ev = sum(f["evaluations"] for f in runs[0]["frames"]) / len(runs[0]["frames"])
        t = ", ".join(f"{r['summary']['mean_time_s'] * 1e3:.3f}" for r in runs)
        print(f"| {d} | {n}, {b} | {s['mean_v2v_mm']:.2f} | {s['mean_energy']:.4f} | {ev:.1f} | {t} |")
import os
if os.environ.get("RUNTIMES") == "1":
    print()
    print("| clip, --batch 256, two threads | V2V mm | frames per second (each run) |")
    print("|---|---|---|")
    for n in ["gn", "chord"]:
        for rt in ["native", "burn", "ort"]:
            name = f"{n}-b256" if rt == "native" else f"{n}-{rt}"
            runs = [json.load(open(f"{out}/r{r}-clip-{name}.json"))["summary"] for r in range(1, reps + 1)]
            fps = ", ".join(f"{1e-3 / s['mean_time_s']:.2f} k" for s in runs)
            print(f"| {n}, {rt} | {runs[0]['mean_v2v_mm']:.2f} | {fps} |")
PY
