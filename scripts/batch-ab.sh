#!/usr/bin/env bash
# Two lfit builds back to back, alternated, timed per frame and end to end: the chord markers
# network (`markers-makehuman-chord`, `--runtime native`, `--neural-start given`, N = 5) at
# --batch 256 on one and on two threads over 2,000 procedural local frames, and LM (`--budget
# 4000`, one thread) on the MocapBank clip's 454 local frames (./scripts/fetch-mocapbank.sh; an
# evaluation clip, never training data; the seed of docs/results/learned-vs-classical.md). REPS
# rounds (default 3). Prints ms per frame (the result's mean_time_s) and the command's wall
# seconds of every run, V2V, and whether every pose came out equal to the bit.
#
#   scripts/batch-ab.sh BASE_BIN NEW_BIN [OUT]
#
# e.g. BASE_BIN a release build of an older commit (git checkout OLD && cargo build --release
# --workspace && cp target/release/lfit /tmp/lfit-base && git checkout -), NEW_BIN this tree's.
set -euo pipefail
cd "$(dirname "$0")/.."
SEED=9103745171752751104
source scripts/eval-common.sh
eval_ab_args batch-ab target/batch-ab "$@"
eval_setup batch-ab "$OUT"
REPS="${REPS:-3}"
eval_local_sets "$OUT"
[ -f "$OUT/proc2k.npz" ] || "$LFIT" -q synth --modality markers --scenario local --frames 2000 \
    --seed "$SEED" --template "$MODEL" --out "$OUT/proc2k.npz" >/dev/null
# timed NAME BIN THREADS ARG...: one `lfit fit`, its wall seconds in OUT/NAME.wall.
timed() {
    local name="$1" bin="$2" threads="$3"
    shift 3
    local start end
    start=$(date +%s.%N)
    RAYON_NUM_THREADS=$threads "$bin" -q fit --template "$MODEL" "$@" --out "$OUT/$name.json" >/dev/null 2>&1
    end=$(date +%s.%N)
    python3 -c "print($end - $start)" > "$OUT/$name.wall"
}
for rep in $(seq "$REPS"); do
    for which in base new; do
        bin="$BASE"; [ "$which" = new ] && bin="$NEW"
        for t in 1 2; do
            timed "r$rep-chord-t$t-$which" "$bin" "$t" --data "$OUT/proc2k.npz" --method neural \
                --checkpoint checkpoints/markers-makehuman-chord --neural-start given \
                --runtime native --budget 10 --batch 256
        done
        timed "r$rep-lm-t1-$which" "$bin" 1 --data "$OUT/clip.npz" --method lm --budget 4000
    done
done
python3 - "$OUT" "$REPS" <<'PY'
import json, sys
out, reps = sys.argv[1], int(sys.argv[2])
med = lambda v: sorted(v)[len(v) // 2]
fmt = lambda v, d: ", ".join(f"{x:.{d}f}" for x in v)
print("| run | base ms/frame | new ms/frame | new / base (medians) | base wall s | new wall s | wall ratio | V2V mm, base / new | poses equal |")
print("|---|---|---|---|---|---|---|---|---|")
for row in ["chord-t1", "chord-t2", "lm-t1"]:
    doc = {w: [json.load(open(f"{out}/r{r}-{row}-{w}.json")) for r in range(1, reps + 1)] for w in ["base", "new"]}
    t = {w: [d["summary"]["mean_time_s"] * 1e3 for d in doc[w]] for w in doc}
    wall = {w: [float(open(f"{out}/r{r}-{row}-{w}.wall").read()) for r in range(1, reps + 1)] for w in doc}
    same = all(a["pose"] == b["pose"] for a, b in zip(doc["base"][0]["frames"], doc["new"][0]["frames"]))
    v2v = " / ".join(f"{doc[w][0]['summary']['mean_v2v_mm']:.3f}" for w in ["base", "new"])
    print(f"| {row} | {fmt(t['base'], 3)} | {fmt(t['new'], 3)} | {med(t['new']) / med(t['base']):.2f} | "
          f"{fmt(wall['base'], 2)} | {fmt(wall['new'], 2)} | {med(wall['new']) / med(wall['base']):.2f} | {v2v} | {'yes' if same else 'NO'} |")
PY
