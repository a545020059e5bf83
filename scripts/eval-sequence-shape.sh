#!/usr/bin/env bash
# The beta policies of a sequence (--sequence-shape per-frame, first-pass, joint, joint:64) on the
# MocapBank clip as a sequence, for the network and LM (docs/results/captured-motion.md rounds 4,
# 6 and 15).
#   ./scripts/eval-sequence-shape.sh [OUT]     (MODALITIES="keypoints2d markers" by default)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-sequence-shape}"
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-sequence-shape "$OUT"
rows=()
run() { local name="$1" data="$2" method="$3"; shift 3
  "$LFIT" -q fit --data "$data" --template "$MODEL" --method "$method" --out "$OUT/$name.json" "$@" >/dev/null
  rows+=("$name"); }
for m in ${MODALITIES:-keypoints2d markers}; do
  ck="checkpoints/$m-makehuman"
  data="$OUT/clip-sequence-$m.npz"
  [ -f "$data" ] || "$LFIT" -q synth --modality "$m" --scenario sequence --frames 454 --seed "$SEED" --template "$MODEL" --motions "$OUT/clip-motion.npz" --out "$data" >/dev/null
  run "$m-seq-neural-per-frame" "$data" neural --checkpoint "$ck" --neural-start given --budget 10
  run "$m-seq-neural-first-pass" "$data" neural --checkpoint "$ck" --neural-start best --budget 12 --sequence-shape first-pass
  run "$m-seq-neural-joint" "$data" neural --checkpoint "$ck" --neural-start given --budget 10 --sequence-shape joint
  run "$m-seq-lm" "$data" lm --budget 4000
  run "$m-seq-lm-joint" "$data" lm --budget 4000 --sequence-shape joint
  run "$m-seq-neural-joint64" "$data" neural --checkpoint "$ck" --neural-start given --budget 10 --sequence-shape joint:64
  run "$m-seq-lm-joint64" "$data" lm --budget 4000 --sequence-shape joint:64
done
eval_table fits "$OUT" "${rows[@]}"
