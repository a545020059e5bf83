#!/usr/bin/env bash
# Captures through `lfit data import`: noise-free markers frames with a known ground truth, 50 of
# the procedural library and 50 of the MocapBank clip (./scripts/fetch-mocapbank.sh; evaluation
# only), written as C3D files (`lfit data export-c3d`), imported back (`lfit data import`: no
# ground truth, each frame starts from the rest pose moved rigidly onto its markers, global
# scenario: every frame fitted on its own; `far`: the captured frames written 3.6 m from the
# lab's origin, which must fit as they do at it), then fitted by LM (on every entry, and `lm-observed`
# on the entries the markers determine), the neural fitter (from Φ(D)),
# neural+lm (LM on the entries the markers determine, the default) and neural+lm with
# `--dofs all` (LM on every entry: row `neural+lm-all`). Prints one Markdown table: per source
# and method, the share of frames whose fit ends within 5 mm marker RMS, the mean and median
# marker RMS, evaluations and time per frame; then, where the lfit Python module is installed,
# each fit's V2V against the frames the C3D files were written from (scripts/c3d-v2v.py).
#
#   scripts/eval-c3d.sh [OUT] [CHECKPOINT]
#
# OUT defaults to target/eval-c3d; CHECKPOINT to checkpoints/markers-makehuman. LFIT (default: the
# release build) is the binary. Same inputs, same seeds: the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-c3d}"
CK="${2:-checkpoints/markers-makehuman}"
FRAMES="${EVAL_FRAMES:-50}"
SEED=2511
source scripts/eval-common.sh
eval_need_dir eval-c3d "$CK"
eval_setup eval-c3d "$OUT"
rows=()
for src in library captured far; do
    motions=()
    [ "$src" != library ] && motions=(--motions "$OUT/clip-motion.npz")
    moved=()
    # `far`: the captured frames written 3.6 m from the lab's origin (scripts/c3d-v2v.py moves
    # the fits back before comparing them with the captured truth).
    [ "$src" = far ] && moved=(--translate 3,0,-2)
    if [ "$src" != far ]; then
        "$LFIT" -q synth --modality markers --scenario local --frames "$FRAMES" --seed "$SEED" --noise 0 \
            --template "$MODEL" "${motions[@]}" --out "$OUT/$src-truth.npz" >/dev/null
    fi
    truth="$OUT/${src/far/captured}-truth.npz"
    "$LFIT" -q data export-c3d --data "$truth" --out "$OUT/$src.c3d" "${moved[@]}" >/dev/null
    "$LFIT" -q data import --c3d "$OUT/$src.c3d" --model "$MODEL" --scenario global \
        --out "$OUT/$src.npz" >/dev/null
    for row in lm lm-observed neural neural+lm neural+lm-all; do
        method="${row%-all}"
        method="${method%-observed}"
        budget=4000
        args=()
        [ "$method" != lm ] && args=(--checkpoint "$CK")
        [ "$method" = neural ] && budget=10
        [ "$row" = neural+lm-all ] && args+=(--dofs all)
        [ "$row" = lm-observed ] && args+=(--dofs observed)
        "$LFIT" -q fit --data "$OUT/$src.npz" --template "$MODEL" --method "$method" \
            --budget "$budget" "${args[@]}" --out "$OUT/$src-$row.json" >/dev/null
        rows+=("$src-$row")
    done
done
eval_table c3d "$OUT" "${rows[@]}"
# V2V against the frames the C3D files were written from, where the lfit Python module is
# installed (PYTHON: default python3; ./scripts/test.sh's venv has it).
PY="${PYTHON:-python3}"
if "$PY" -c "import lfit, numpy" 2>/dev/null; then
    echo
    "$PY" scripts/c3d-v2v.py "$OUT" "${rows[@]}"
else
    echo "(no V2V table: $PY cannot import lfit and numpy; set PYTHON to one that can)" >&2
fi
