#!/usr/bin/env bash
# Where a subject's markers or keypoints sit, with β given and reused across trials (issue 25,
# "the user's own sensors"; docs/results/captured-motion.md, round 18). Synthetic sequences of one
# seed share their subject (β, marker slip, keypoint bias), so the MocapBank evaluation clip's
# sequence and the held-out CMU subject 6's (300 frames) are two trials of one subject. Per
# modality (markers slipped, keypoints biased by σ = SLIPS mm per axis):
# - β given (`--known-shape truth`) on the clip: per frame, and `joint:64` with the placement
#   solved (`--marker-placement solve`: the poses alone beside the offsets), LM and neural+lm;
# - the placement solved on the clip (`neural+lm both`, `joint:64+solve`) reused on the CMU
#   trial (`--offsets`) per frame and with `joint:64`, against that trial without it and with its
#   own solve.
# Prints one Markdown table and writes every result under OUT.
#
#   scripts/eval-placement-reuse.sh [OUT]
#
# OUT defaults to target/eval-placement-reuse; SLIPS (default "10 20") the σ in mm; LFIT
# (default: the release build) is the binary. Same seeds: the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-placement-reuse}"
# The clip frames' seed of docs/results/learned-vs-classical.md and eval-captured.sh.
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-placement-reuse "$OUT"
rows=()
run() { # name data fit-arguments...
    local name="$1" data="$2"
    shift 2
    "$LFIT" -q fit --data "$data" --template "$MODEL" --out "$OUT/$name.json" "$@" >/dev/null
    rows+=("$name")
}
synth() { # out modality move sigma frames motions...
    local out="$1" modality="$2" move="$3" sigma="$4" frames="$5"
    shift 5
    "$LFIT" -q synth --modality "$modality" --scenario sequence --frames "$frames" --seed "$SEED" \
        --template "$MODEL" --motions "$@" "$move" "$sigma" --out "$out" >/dev/null
}
for m in markers keypoints2d; do
    ck="checkpoints/$m-makehuman"
    eval_need_dir eval-placement-reuse "$ck"
    move=--marker-slip-mm
    [ "$m" = keypoints2d ] && move=--keypoint-bias-mm
    lm=(--method lm --budget 4000)
    nlm=(--method neural+lm --checkpoint "$ck" --neural-start both --budget 4000)
    solve=(--sequence-shape joint:64 --marker-placement solve)
    for s in ${SLIPS:-10 20}; do
        clip="$OUT/$m-clip-$s.npz" cmu="$OUT/$m-cmu6-$s.npz"
        synth "$clip" "$m" "$move" "$s" "${EVAL_FRAMES:-454}" "$OUT/clip-motion.npz"
        synth "$cmu" "$m" "$move" "$s" 300 data/motions/cmu/validation/006_*.npz
        p="$m$s"
        run "$p-clip-lm-known" "$clip" "${lm[@]}" --known-shape truth
        run "$p-clip-lm-known-joint64+solve" "$clip" "${lm[@]}" --known-shape truth "${solve[@]}"
        run "$p-clip-neural+lm-known" "$clip" "${nlm[@]}" --known-shape truth
        run "$p-clip-neural+lm-known-joint64+solve" "$clip" "${nlm[@]}" --known-shape truth "${solve[@]}"
        run "$p-clip-neural+lm-joint64+solve" "$clip" "${nlm[@]}" "${solve[@]}"
        placed="$OUT/$p-clip-neural+lm-joint64+solve.json"
        for shape in per-frame joint:64; do
            run "$p-cmu6-neural+lm-${shape/:/}" "$cmu" "${nlm[@]}" --sequence-shape "$shape"
            run "$p-cmu6-neural+lm-${shape/:/}-offsets" "$cmu" "${nlm[@]}" --sequence-shape "$shape" \
                --offsets "$placed"
        done
        run "$p-cmu6-neural+lm-joint64+solve" "$cmu" "${nlm[@]}" "${solve[@]}"
    done
done
eval_table fits "$OUT" "${rows[@]}"
