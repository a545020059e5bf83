#!/usr/bin/env bash
# A camera-agnostic keypoints2d fitter on rigs it never saw: 200 frames of the MocapBank clip
# (./scripts/fetch-mocapbank.sh; evaluation only) retargeted onto the MakeHuman body, seen by one
# camera and by three cameras of `lfit synth --cameras N` (the default ring: 4 m around the
# subject, 1.3 m high, 640x480, fx = 550) or by the rigs of RIGS; training draws its rigs at
# random, so no training rig is one of these; local scenario, default noise; fitted by the network (from the given start and from
# Φ(D)), by `neural+lm` (from the given start, its default `--dofs`) and by LM. Prints one
# Markdown table (V2V, MPJPE, PA-MPJPE — the monocular figure —, β RMS, evaluations, time per frame).
#
#   scripts/eval-rigs.sh CHECKPOINT [OUT]
#
# RIGS (default "1 3"): the rigs, each a number N (N cameras of the default ring, `--cameras N`,
# rows `N-cam-…`) or the name of a camera file under configs/rigs/ (`--camera
# configs/rigs/NAME.json`, rows `NAME-…`: phone-1, a phone in portrait at 2.8 m; tripods-2, two
# full-HD tripods, one high; studio-3, three 720p cameras at 0.6–2.4 m with 45–80° lenses).
#
# CHECKPOINT: a pooled keypoints2d checkpoint (network.views = "pooled"). OUT defaults to
# target/eval-rigs. LFIT (default: the release build) is the binary. POSE_PRIOR (an energy file
# of `lfit motion prior --modality keypoints2d`) adds the rows of LM with that prior. FLOOR (e.g.
# contact:truth) gives every fit `--floor FLOOR`: the ground plane as a measurement
# (docs/results/captured-motion.md, round 36).
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
floor=()
[ -n "${FLOOR:-}" ] && floor=(--floor "$FLOOR")
rows=()
for rig in ${RIGS:-1 3}; do
    if [[ "$rig" =~ ^[0-9]+$ ]]; then
        tag="$rig-cam"
        rig_args=(--cameras "$rig")
    else
        tag="$rig"
        rig_args=(--camera "configs/rigs/$rig.json")
        if [ ! -f "configs/rigs/$rig.json" ]; then
            echo "eval-rigs: no camera file configs/rigs/$rig.json (RIGS: numbers or names there)" >&2
            exit 1
        fi
    fi
    data="$OUT/clip-$tag.npz"
    "$LFIT" -q synth --modality keypoints2d "${rig_args[@]}" --scenario local --frames "$FRAMES" \
        --seed "$SEED" --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$data" >/dev/null
    "$LFIT" -q fit --data "$data" --template "$MODEL" --method lm --budget 4000 \
        "${floor[@]}" --out "$OUT/$tag-lm.json" >/dev/null
    rows+=("$tag-lm")
    if [ -n "${POSE_PRIOR:-}" ]; then
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method lm --budget 4000 \
            --energy "$POSE_PRIOR" "${floor[@]}" --out "$OUT/$tag-lm+prior.json" >/dev/null
        rows+=("$tag-lm+prior")
    fi
    for start in given phi; do
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method neural --checkpoint "$CK" \
            --neural-start "$start" --budget 10 "${floor[@]}" --out "$OUT/$tag-neural-$start.json" >/dev/null
        rows+=("$tag-neural-$start")
    done
    # The network from the given start, then LM on its default (anchored at the network's result).
    "$LFIT" -q fit --data "$data" --template "$MODEL" --method neural+lm --checkpoint "$CK" \
        --neural-start given --budget 4000 "${floor[@]}" --out "$OUT/$tag-neural+lm-given.json" >/dev/null
    rows+=("$tag-neural+lm-given")
done
eval_table fits "$OUT" "${rows[@]}"
