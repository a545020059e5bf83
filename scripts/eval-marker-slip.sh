#!/usr/bin/env bash
# Sensor points that do not sit where the model puts them (issue 25, "the user's own sensors"):
# the MocapBank evaluation clip (./scripts/fetch-mocapbank.sh; never training data) on the
# MakeHuman body, with default noise on top of either
# - markers (MODALITY=markers, the default) observed on vertices slipped by σ = SLIPS mm per axis
#   (`lfit synth --marker-slip-mm`: per marker the nearest vertex of the same body part to its
#   rest position plus a normal draw), or
# - 2D keypoints (MODALITY=keypoints2d) observed off the joint centres by σ = SLIPS mm per axis
#   (`lfit synth --keypoint-bias-mm`: per joint a normal draw in the joint's rest frame, carried
#   by the joint, as a detector's keypoints sit off a skeleton's joints);
# one placement per subject: per frame for single frames, once per sequence. Fitted as single
# frames (local scenario) and as a sequence by LM, the shipped network and neural+lm; sequences
# per frame, with one β (`joint:64`) and with one β and each point's offset solved
# (`joint:64+solve`: `--marker-placement solve`). Prints one Markdown table per σ and writes
# every result under OUT.
#
#   scripts/eval-marker-slip.sh [OUT] [CHECKPOINT]
#
# OUT defaults to target/eval-marker-slip (target/eval-keypoint-bias for keypoints2d);
# CHECKPOINT to checkpoints/MODALITY-makehuman; SLIPS (default "0 10 20") the σ in mm; LFIT
# (default: the release build) is the binary. Same seeds: the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
MODALITY="${MODALITY:-markers}"
case "$MODALITY" in
    markers) MOVE=--marker-slip-mm KIND="marker slip" DEFAULT_OUT=target/eval-marker-slip ;;
    keypoints2d) MOVE=--keypoint-bias-mm KIND="keypoint bias" DEFAULT_OUT=target/eval-keypoint-bias ;;
    *)
        echo "eval-marker-slip: MODALITY is markers or keypoints2d (got $MODALITY)" >&2
        exit 1
        ;;
esac
OUT="${1:-$DEFAULT_OUT}"
CK="${2:-checkpoints/$MODALITY-makehuman}"
# The clip frames' seed of docs/results/learned-vs-classical.md and eval-captured.sh.
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-marker-slip "$OUT"
eval_need_dir eval-marker-slip "$CK"
FRAMES="${EVAL_FRAMES:-454}"
for slip in ${SLIPS:-0 10 20}; do
    rows=()
    for scenario in local sequence; do
        data="$OUT/clip-$scenario-slip$slip.npz"
        "$LFIT" -q synth --modality "$MODALITY" --scenario "$scenario" --frames "$FRAMES" --seed "$SEED" \
            --template "$MODEL" --motions "$OUT/clip-motion.npz" "$MOVE" "$slip" --out "$data" >/dev/null
        p="slip$slip-$scenario"
        if [ "$scenario" = local ]; then
            eval_run "$p-lm" "$data" lm --budget 4000
            eval_run "$p-neural" "$data" neural --checkpoint "$CK" --neural-start given --budget 10
            eval_run "$p-neural+lm" "$data" neural+lm --checkpoint "$CK" --neural-start given --budget 4000
        else
            for shape in per-frame joint:64 joint:64+solve; do
                s="${shape/:/}"
                # joint:64+solve: the joint β pass with each point's offset solved.
                flags=(--sequence-shape "${shape%+solve}")
                [ "$shape" = "${shape%+solve}" ] || flags+=(--marker-placement solve)
                eval_run "$p-lm-$s" "$data" lm --budget 4000 "${flags[@]}"
                eval_run "$p-neural-both-$s" "$data" neural --checkpoint "$CK" --neural-start both --budget 24 \
                    "${flags[@]}"
                eval_run "$p-neural+lm-both-$s" "$data" neural+lm --checkpoint "$CK" --neural-start both \
                    --budget 4000 "${flags[@]}"
            done
        fi
    done
    echo "### $KIND σ = $slip mm"
    eval_table fits "$OUT" "${rows[@]}"
done
