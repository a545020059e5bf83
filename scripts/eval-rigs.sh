#!/usr/bin/env bash
# A camera-agnostic keypoints2d fitter on rigs it never saw: 200 frames of the MocapBank clip
# (./scripts/fetch-mocapbank.sh; evaluation only) retargeted onto the MakeHuman body, seen by one
# camera and by three cameras of `lfit synth --cameras N` (the default ring: 4 m around the
# subject, 1.3 m high, 640x480, fx = 550; training draws its rigs at random, so no training rig is
# this one), local scenario, default noise; fitted by the network (from the given start and from
# Φ(D)) and by LM. Prints one Markdown table (V2V, MPJPE, β RMS, evaluations, time per frame).
#
#   scripts/eval-rigs.sh CHECKPOINT [OUT]
#
# CHECKPOINT: a pooled keypoints2d checkpoint (network.views = "pooled"). OUT defaults to
# target/eval-rigs. LFIT (default: the release build) is the binary. POSE_PRIOR (an energy file
# of `lfit motion prior --modality keypoints2d`) adds the rows of LM with that prior.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 1 ] || [ $# -gt 2 ]; then
    echo "usage: scripts/eval-rigs.sh CHECKPOINT [OUT]" >&2
    exit 2
fi
CK="$1"
OUT="${2:-target/eval-rigs}"
FRAMES="${EVAL_FRAMES:-200}"
SEED=9103745171752751104
source scripts/eval-common.sh
eval_need_dir eval-rigs "$CK"
if [ -n "${POSE_PRIOR:-}" ] && [ ! -f "$POSE_PRIOR" ]; then
    echo "eval-rigs: POSE_PRIOR $POSE_PRIOR is not a file" >&2
    exit 1
fi
eval_setup eval-rigs "$OUT"
rows=()
for cams in 1 3; do
    data="$OUT/clip-$cams-cam.npz"
    "$LFIT" -q synth --modality keypoints2d --cameras "$cams" --scenario local --frames "$FRAMES" \
        --seed "$SEED" --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$data" >/dev/null
    "$LFIT" -q fit --data "$data" --template "$MODEL" --method lm --budget 4000 \
        --out "$OUT/$cams-cam-lm.json" >/dev/null
    rows+=("$cams-cam-lm")
    if [ -n "${POSE_PRIOR:-}" ]; then
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method lm --budget 4000 \
            --energy "$POSE_PRIOR" --out "$OUT/$cams-cam-lm+prior.json" >/dev/null
        rows+=("$cams-cam-lm+prior")
    fi
    for start in given phi; do
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method neural --checkpoint "$CK" \
            --neural-start "$start" --budget 10 --out "$OUT/$cams-cam-neural-$start.json" >/dev/null
        rows+=("$cams-cam-neural-$start")
    done
done
eval_table fits "$OUT" "${rows[@]}"
