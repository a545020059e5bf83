#!/usr/bin/env bash
# The native forward's 8-wide AVX path against its 4-wide portable path (LFIT_NATIVE_SIMD=portable),
# in one lfit binary, alternated: the shipped MakeHuman fitters (`--runtime native`, `--neural-start
# given`, N = 5) on the MocapBank clip's 454 local frames of each sensor (./scripts/fetch-mocapbank.sh;
# an evaluation clip, never training data; the seed of docs/results/learned-vs-classical.md) at
# batch 1 on one thread and at --batch 256 on two threads. REPS rounds (default 3). Prints ms per
# frame per run and whether every pose came out equal to the bit between the two paths.
#
#   scripts/eval-native-simd.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-native-simd}"
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-native-simd "$OUT"
REPS="${REPS:-3}"
for m in markers keypoints2d hmd; do
    [ -f "$OUT/clip-$m.npz" ] || "$LFIT" -q synth --modality "$m" --scenario local --frames 454 --seed "$SEED" \
        --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$OUT/clip-$m.npz" >/dev/null
done
for rep in $(seq "$REPS"); do
    for m in markers keypoints2d hmd; do
        k=(); [ "$m" = hmd ] && k=(--known-shape truth)
        for simd in auto portable; do
            for cfg in "1 1" "256 2"; do
                set -- $cfg
                LFIT_NATIVE_SIMD=$simd eval_native_fit "$LFIT" "$OUT/clip-$m.npz" "checkpoints/$m-makehuman" \
                    "$1" "$2" "$OUT/r$rep-$m-$simd-b$1.json" "${k[@]}"
            done
        done
    done
done
python3 - "$OUT" "$REPS" <<'PY'
import json, sys
out, reps = sys.argv[1], int(sys.argv[2])
def load(rep, m, s, b): return json.load(open(f"{out}/r{rep}-{m}-{s}-b{b}.json"))
print("| sensor, batch | AVX ms/frame | portable ms/frame | AVX / portable (sum) | V2V mm | poses equal |")
print("|---|---|---|---|---|---|")
for m in ["markers", "keypoints2d", "hmd"]:
    for b in [1, 256]:
        ta = [load(r, m, "auto", b)["summary"]["mean_time_s"] * 1e3 for r in range(1, reps + 1)]
        tp = [load(r, m, "portable", b)["summary"]["mean_time_s"] * 1e3 for r in range(1, reps + 1)]
        same = all(
            [f["pose"] for f in load(r, m, "auto", b)["frames"]] == [f["pose"] for f in load(r, m, "portable", b)["frames"]]
            for r in range(1, reps + 1))
        v2v = load(1, m, "auto", b)["summary"]["mean_v2v_mm"]
        f = lambda t: ", ".join(f"{x:.3f}" for x in t)
        print(f"| {m}, {b} | {f(ta)} | {f(tp)} | {sum(ta)/sum(tp):.2f} | {v2v:.2f} | {same} |")
PY
