#!/usr/bin/env bash
# A 2D detector's keypoints off the joint centres, calibrated once (issue 25, "the user's own
# sensors"): the synthetic detector of `lfit synth --keypoint-detector DET --keypoint-bias-mm S`
# puts every subject's keypoints at the same offsets from the joints (per joint a normal draw of
# σ = S mm per axis in the rest frame, carried by the segment that ends at the joint). A
# calibration recording — 300 frames of the held-out CMU subject 6 with their ground-truth
# poses, as motion capture filmed alongside the cameras gives — is solved with `lfit calibrate`;
# the same frames' poses from an LM fit of their motion capture (`lfit synth --modality markers`
# of the same seed and motion, default noise; `lfit calibrate --poses`) is the second
# calibration. The MocapBank evaluation clip (./scripts/fetch-mocapbank.sh; another subject, never training
# data), seen through the same detector with default noise, is then fitted without the
# offsets and with each calibration (`lfit fit --offsets`): single frames (local scenario) by LM, the
# shipped network and neural+lm, sequences with one β (`--sequence-shape joint:64`) by LM and
# neural+lm. Prints one Markdown table per σ and writes every result under OUT.
#
#   scripts/eval-detector-calibration.sh [OUT] [CHECKPOINT]
#
# OUT defaults to target/eval-detector-calibration; CHECKPOINT to
# checkpoints/keypoints2d-makehuman; BIASES (default "10 20") the σ in mm; DET (default 1) the
# detector's seed; LFIT (default: the release build) the binary. Same seeds: the same numbers,
# but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-detector-calibration}"
CK="${2:-checkpoints/keypoints2d-makehuman}"
DET="${DET:-1}"
# The clip frames' seed of docs/results/learned-vs-classical.md and eval-captured.sh.
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-detector-calibration "$OUT"
eval_need_dir eval-detector-calibration "$CK"
FRAMES="${EVAL_FRAMES:-454}"
# The calibration recording's motion capture, fitted by LM: the poses a user would have.
"$LFIT" -q synth --modality markers --scenario local --frames 300 --seed 6006 --template "$MODEL" \
    --motions data/motions/cmu/validation/006_*.npz --out "$OUT/cal-mocap.npz" >/dev/null
"$LFIT" -q fit --data "$OUT/cal-mocap.npz" --template "$MODEL" --method lm --budget 4000 \
    --out "$OUT/cal-mocap-lm.json" >/dev/null
for bias in ${BIASES:-10 20}; do
    detector=(--keypoint-bias-mm "$bias" --keypoint-detector "$DET")
    cal="$OUT/cal-$bias.npz"
    "$LFIT" -q synth --modality keypoints2d --scenario local --frames 300 --seed 6006 \
        --template "$MODEL" --motions data/motions/cmu/validation/006_*.npz "${detector[@]}" \
        --out "$cal" >/dev/null
    "$LFIT" -q calibrate --data "$cal" --model "$MODEL" --out "$OUT/cal-$bias-truth.json" >/dev/null
    "$LFIT" -q calibrate --data "$cal" --poses "$OUT/cal-mocap-lm.json" --model "$MODEL" \
        --out "$OUT/cal-$bias-mocap.json" >/dev/null
    rows=()
    for scenario in local sequence; do
        data="$OUT/clip-$scenario-$bias.npz"
        "$LFIT" -q synth --modality keypoints2d --scenario "$scenario" --frames "$FRAMES" --seed "$SEED" \
            --template "$MODEL" --motions "$OUT/clip-motion.npz" "${detector[@]}" --out "$data" >/dev/null
        for offsets in none truth mocap; do
            flags=()
            [ "$offsets" = none ] || flags=(--offsets "$OUT/cal-$bias-$offsets.json")
            p="bias$bias-$scenario-$offsets"
            if [ "$scenario" = local ]; then
                eval_run "$p-lm" "$data" lm --budget 4000 "${flags[@]}"
                eval_run "$p-neural" "$data" neural --checkpoint "$CK" --neural-start given --budget 10 "${flags[@]}"
                eval_run "$p-neural+lm" "$data" neural+lm --checkpoint "$CK" --neural-start given --budget 4000 \
                    "${flags[@]}"
            else
                eval_run "$p-lm-joint64" "$data" lm --budget 4000 --sequence-shape joint:64 "${flags[@]}"
                eval_run "$p-neural+lm-both-joint64" "$data" neural+lm --checkpoint "$CK" --neural-start both \
                    --budget 4000 --sequence-shape joint:64 "${flags[@]}"
            fi
        done
    done
    echo "### detector $DET, σ = $bias mm"
    for c in truth mocap; do
        python3 -c "import json,sys; c=json.load(open(sys.argv[1]))['calibration']; print('- calibration at the %s poses: %d frames, data term %.3f -> %.3f, offsets RMS %.1f mm' % (sys.argv[2], c['frames'], c['data_term_before'], c['data_term_after'], c['offset_rms_mm']))" "$OUT/cal-$bias-$c.json" "$c"
    done
    eval_table fits "$OUT" "${rows[@]}"
done
