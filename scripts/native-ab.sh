#!/usr/bin/env bash
# The native forward (`--runtime native`) of two lfit builds back to back, alternated: the markers
# networks `markers-makehuman` (Gauss-Newton direction) and `markers-makehuman-chord` on the
# MocapBank clip's 454 local frames (./scripts/fetch-mocapbank.sh; an evaluation clip, never
# training data; the seed of docs/results/learned-vs-classical.md) and 500 procedural held-out local
# frames, `--neural-start given`, N = 5, at batch 1 on one thread and at --batch 256 on two
# threads; REPS rounds (default 3). Prints ms per frame of every run and each build's V2V.
#
#   scripts/native-ab.sh BASE_BIN NEW_BIN [OUT]
#
# e.g. BASE_BIN a release build of an older commit (git checkout OLD && cargo build --release
# --workspace && cp target/release/lfit /tmp/lfit-base && git checkout -), NEW_BIN this tree's.
set -euo pipefail
cd "$(dirname "$0")/.."
SEED=9103745171752751104
source scripts/eval-common.sh
eval_ab_args native-ab target/native-ab "$@"
eval_setup native-ab "$OUT"
REPS="${REPS:-3}"
eval_local_sets "$OUT"
for rep in $(seq "$REPS"); do
    for d in clip proc; do
        for cfg in "1 1" "256 2"; do
            set -- $cfg
            for ck in markers-makehuman markers-makehuman-chord; do
                for which in base new; do
                    bin="$BASE"; [ "$which" = new ] && bin="$NEW"
                    eval_native_fit "$bin" "$OUT/$d.npz" "checkpoints/$ck" "$1" "$2" \
                        "$OUT/r$rep-$d-$ck-b$1-$which.json" 2>/dev/null
                done
            done
        done
    done
done
python3 - "$OUT" "$REPS" <<'PY'
import json, sys
out, reps = sys.argv[1], int(sys.argv[2])
print("| frames | network, batch | V2V mm, base / new | ms per frame, base (each run) | new (each run) | new / base (medians) |")
print("|---|---|---|---|---|---|")
for d in ["clip", "proc"]:
    for ck in ["markers-makehuman", "markers-makehuman-chord"]:
        for b in [1, 256]:
            s = {w: [json.load(open(f"{out}/r{r}-{d}-{ck}-b{b}-{w}.json"))["summary"] for r in range(1, reps + 1)]
                 for w in ["base", "new"]}
            t = {w: [x["mean_time_s"] * 1e3 for x in s[w]] for w in s}
            med = {w: sorted(v)[len(v) // 2] for w, v in t.items()}
            v2v = " / ".join(f"{s[w][0]['mean_v2v_mm']:.3f}" for w in ["base", "new"])
            fmt = lambda v: ", ".join(f"{x:.3f}" for x in v)
            print(f"| {d} | {ck}, {b} | {v2v} | {fmt(t['base'])} | {fmt(t['new'])} | {med['new'] / med['base']:.2f} |")
PY
