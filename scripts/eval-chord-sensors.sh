#!/usr/bin/env bash
# A chord-direction network of sensor M (keypoints2d or hmd; markers works too) against the shipped
# Gauss-Newton network of that sensor and LM, alone and as `neural+lm` within an exact budget of
# BUDGET evaluations (default 14: the network's 10 by its count, four of LM's;
# docs/results/captured-motion.md, round 40), alternated in one lfit binary: the MocapBank clip's 454 local frames
# (./scripts/fetch-mocapbank.sh; an evaluation clip, never training data; the seed of
# docs/results/learned-vs-classical.md) and 500 procedural held-out local frames, start near the
# target (`--neural-start given`, N = 5), `--runtime native`, batch 1, one thread; hmd with β
# given. REPS rounds (default 3). Prints V2V, evaluations and ms per frame of every run, and each
# method's median time over LM's. EARLY="K:B …" adds `neural+lm` from the chord network's first K
# iterations within B evaluations (`--neural-iterations K --budget B`, rows chord+lm-K@B) and LM
# pulled toward the scenario's start by `neural+lm`'s own σ (`--dofs anchored:σ`, σ = 5° markers,
# 3° keypoints2d, 1° hmd; row lm-anchored): what the start alone gives without the network.
#
#   M=keypoints2d CHORD=checkpoints/keypoints2d-makehuman-chord scripts/eval-chord-sensors.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
M="${M:-keypoints2d}"
OUT="${1:-target/eval-chord-sensors-$M}"
SEED=9103745171752751104
CHORD="${CHORD:-checkpoints/$M-makehuman-chord}"
BASE="${BASE:-checkpoints/$M-makehuman}"
source scripts/eval-common.sh
eval_setup eval-chord-sensors "$OUT"
eval_need_dir eval-chord-sensors "$CHORD"
eval_need_dir eval-chord-sensors "$BASE"
REPS="${REPS:-3}"
BUDGET="${BUDGET:-14}"
known=()
[ "$M" = hmd ] && known=(--known-shape truth)
case "$M" in markers) sigma=5 ;; keypoints2d) sigma=3 ;; *) sigma=1 ;; esac
rows="lm gn chord gn+lm chord+lm"
for e in ${EARLY:-}; do rows="$rows chord+lm-${e%%:*}@${e##*:}"; done
if [ -n "${EARLY:-}" ]; then rows="$rows lm-anchored"; fi
eval_local_sets "$OUT" "$M"
fit() {
    local data="$1" out="$2"
    shift 2
    RAYON_NUM_THREADS=1 "$LFIT" -q fit --data "$data" --template "$MODEL" "${known[@]}" --out "$out" "$@" >/dev/null
}
for rep in $(seq "$REPS"); do
    for d in clip proc; do
        fit "$OUT/$d.npz" "$OUT/r$rep-$d-lm.json" --method lm --budget 4000
        for name in gn chord; do
            ck="$BASE"; [ "$name" = chord ] && ck="$CHORD"
            fit "$OUT/$d.npz" "$OUT/r$rep-$d-$name.json" --method neural --checkpoint "$ck" \
                --neural-start given --runtime native --budget 10
            fit "$OUT/$d.npz" "$OUT/r$rep-$d-$name+lm.json" --method neural+lm --checkpoint "$ck" \
                --neural-start given --runtime native --budget "$BUDGET"
        done
        for e in ${EARLY:-}; do
            fit "$OUT/$d.npz" "$OUT/r$rep-$d-chord+lm-${e%%:*}@${e##*:}.json" --method neural+lm \
                --checkpoint "$CHORD" --neural-start given --runtime native \
                --neural-iterations "${e%%:*}" --budget "${e##*:}"
        done
        if [ -n "${EARLY:-}" ]; then
            fit "$OUT/$d.npz" "$OUT/r$rep-$d-lm-anchored.json" --method lm --dofs "anchored:$sigma" --budget 4000
        fi
    done
done
python3 - "$OUT" "$REPS" $rows <<'PY'
import json, sys
out, reps, rows = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
def runs(d, n): return [json.load(open(f"{out}/r{r}-{d}-{n}.json")) for r in range(1, reps + 1)]
def median(v): return sorted(v)[len(v) // 2]
print("| frames | method | V2V mm | evaluations per frame | ms per frame (each run) | / LM (medians) |")
print("|---|---|---|---|---|---|")
for d in ["clip", "proc"]:
    lm = median([r["summary"]["mean_time_s"] for r in runs(d, "lm")])
    for n in rows:
        rs = runs(d, n)
        s = rs[0]["summary"]
        ev = sum(f["evaluations"] for f in rs[0]["frames"]) / len(rs[0]["frames"])
        t = [r["summary"]["mean_time_s"] for r in rs]
        each = ", ".join(f"{x * 1e3:.3f}" for x in t)
        print(f"| {d} | {n} | {s['mean_v2v_mm']:.2f} | {ev:.1f} | {each} | {median(t) / lm:.2f} |")
PY
