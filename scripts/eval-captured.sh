#!/usr/bin/env bash
# The learned fitters on captured motion: the MocapBank clip (./scripts/fetch-mocapbank.sh; an
# evaluation clip, never training data) retargeted onto the MakeHuman body, fitted frame by frame
# (local scenario: a start near the target) and as a sequence (each frame from the previous
# result), by the neural fitter (with each start policy and sequence shape policy), LM and
# neural+lm (LM pulled toward the network's result, `--dofs anchored`, the default; on single
# frames also neural+lm on the entries the sensor determines, `-neural+lm-observed`, LM that way,
# `-lm-observed`, and neural+lm with LM on every entry, `-neural+lm-all`), on markers and
# keypoints2d (pose and β) and hmd (β given). Prints one Markdown table
# (mean V2V, MPJPE, β RMS, time per frame, evaluations) and writes every result under OUT. First
# per modality: 500 procedural held-out frames (PROC_FRAMES), neural and LM, for comparison with
# what the fitter was trained on. MODALITIES (default "markers keypoints2d hmd") picks modalities.
#
#   scripts/eval-captured.sh [OUT] [CHECKPOINT_SUFFIX]
#
# OUT defaults to target/eval-captured; the checkpoints are checkpoints/<modality>-makehuman
# (CHECKPOINT_SUFFIX appends to that name, e.g. "-v2"). LFIT (default: the release build) is the
# binary. Same inputs, same seeds: the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-captured}"
SUFFIX="${2:-}"
# The seed of the clip frames in docs/results/learned-vs-classical.md.
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-captured "$OUT"
FRAMES="${EVAL_FRAMES:-454}"
PROC_FRAMES="${PROC_FRAMES:-500}"
rows=()
for m in ${MODALITIES:-markers keypoints2d hmd}; do
    ck="checkpoints/$m-makehuman$SUFFIX"
    eval_need_dir eval-captured "$ck"
    known=()
    [ "$m" = hmd ] && known=(--known-shape truth)
    # Procedural held-out frames (the library, a test seed no training run uses), local scenario.
    data="$OUT/procedural-$m.npz"
    "$LFIT" -q synth --modality "$m" --scenario local --frames "$PROC_FRAMES" --seed "$SEED" \
        --template "$MODEL" --out "$data" >/dev/null
    eval_run "$m-procedural-neural" "$data" neural --checkpoint "$ck" --neural-start given --budget 10 "${known[@]}"
    eval_run "$m-procedural-lm" "$data" lm --budget 4000 "${known[@]}"
    eval_run "$m-procedural-neural+lm" "$data" neural+lm --checkpoint "$ck" --neural-start given --budget 4000 "${known[@]}"
    for scenario in local sequence; do
        data="$OUT/clip-$scenario-$m.npz"
        "$LFIT" -q synth --modality "$m" --scenario "$scenario" --frames "$FRAMES" --seed "$SEED" \
            --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$data" >/dev/null
        eval_run "$m-$scenario-lm" "$data" lm --budget 4000 "${known[@]}"
        if [ "$scenario" = local ]; then
            eval_run "$m-$scenario-neural" "$data" neural --checkpoint "$ck" --neural-start given --budget 10 "${known[@]}"
            eval_run "$m-$scenario-neural-best" "$data" neural --checkpoint "$ck" --neural-start best --budget 12 "${known[@]}"
            eval_run "$m-$scenario-neural+lm" "$data" neural+lm --checkpoint "$ck" --neural-start given --budget 4000 "${known[@]}"
            eval_run "$m-$scenario-neural+lm-observed" "$data" neural+lm --checkpoint "$ck" --neural-start given \
                --budget 4000 --dofs observed "${known[@]}"
            eval_run "$m-$scenario-neural+lm-all" "$data" neural+lm --checkpoint "$ck" --neural-start given --budget 4000 \
                --dofs all "${known[@]}"
            eval_run "$m-$scenario-lm-observed" "$data" lm --budget 4000 --dofs observed "${known[@]}"
        else
            eval_run "$m-$scenario-neural-previous" "$data" neural --checkpoint "$ck" --neural-start given --budget 10 "${known[@]}"
            eval_run "$m-$scenario-neural-best" "$data" neural --checkpoint "$ck" --neural-start best --budget 12 "${known[@]}"
            if [ "$m" != hmd ]; then
                eval_run "$m-$scenario-neural-best-first-pass" "$data" neural --checkpoint "$ck" --neural-start best \
                    --budget 12 --sequence-shape first-pass
                eval_run "$m-$scenario-neural+lm-best-first-pass" "$data" neural+lm --checkpoint "$ck" \
                    --neural-start best --budget 4000 --sequence-shape first-pass
            fi
            eval_run "$m-$scenario-neural+lm-best" "$data" neural+lm --checkpoint "$ck" --neural-start best \
                --budget 4000 "${known[@]}"
            # The best measured sequence policies (round 14): a fit from the previous result and
            # one from Φ(D) per frame, the lower-energy kept, then LM (markers, keypoints2d); each
            # frame from Φ(D), then LM (hmd, whose legs the trackers do not see).
            if [ "$m" != hmd ]; then
                eval_run "$m-$scenario-neural+lm-both" "$data" neural+lm --checkpoint "$ck" --neural-start both \
                    --budget 4000
                # One β for the sequence (round 15): the sequence fitted once, β solved jointly
                # over 64 of its frames, the sequence fitted again with it; every method alike.
                eval_run "$m-$scenario-lm-joint64" "$data" lm --budget 4000 --sequence-shape joint:64
                eval_run "$m-$scenario-neural-both-joint64" "$data" neural --checkpoint "$ck" \
                    --neural-start both --budget 24 --sequence-shape joint:64
                eval_run "$m-$scenario-neural+lm-both-joint64" "$data" neural+lm --checkpoint "$ck" \
                    --neural-start both --budget 4000 --sequence-shape joint:64
            else
                eval_run "$m-$scenario-neural+lm-phi" "$data" neural+lm --checkpoint "$ck" --neural-start phi \
                    --budget 4000 "${known[@]}"
            fi
        fi
    done
done
eval_table fits "$OUT" "${rows[@]}"
