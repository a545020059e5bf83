#!/usr/bin/env bash
# neural+lm against its budget on the held-out CMU subject 6 (validation frames, not the evaluation
# clip), next to the network and LM alone (docs/results/captured-motion.md round 4), for each of
# DOFS (`lfit fit --dofs`: default `observed`; round 14 chose the threshold of `observed` with
# DOFS="all observed:1 observed observed:3 observed:5" BUDGETS=4000; the twenty-ninth session
# chose `neural+lm`'s anchor with DOFS="anchored:2 anchored:3 …" BUDGETS=4000 per sensor).
# CHECKPOINT (default checkpoints/$M-makehuman) is the network; START (default given: the
# scenario's start, near the target) its start (`--neural-start`); hmd is fitted with β given.
#   M=markers BUDGETS="12 14 20 4000" DOFS="all observed" ./scripts/eval-neural-lm-budget.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-neural-lm-budget}"
M=${M:-markers}
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-neural-lm-budget "$OUT"
data="$OUT/cmu6-local-$M.npz"
[ -f "$data" ] || "$LFIT" -q synth --modality $M --scenario local --frames 300 --seed $SEED --template "$MODEL" --motions data/motions/cmu/validation/*.npz --out "$data" >/dev/null
rows=()
known=()
[ "$M" = hmd ] && known=(--known-shape truth)
run() { local name="$1"; shift; "$LFIT" -q fit --data "$data" --template "$MODEL" --out "$OUT/$name.json" "${known[@]}" "$@" >/dev/null; rows+=("$name"); }
ck=${CHECKPOINT:-checkpoints/$M-makehuman}
eval_need_dir eval-neural-lm-budget "$ck"
start=${START:-given}
tag=$(basename "$ck")-$start
run "$M-lm" --method lm --budget 4000
run "$tag-neural" --method neural --checkpoint $ck --neural-start $start --budget 10
for d in ${DOFS:-observed}; do
  for b in ${BUDGETS:-12 14 16 18 20 25 30 40 60 4000}; do
    run "$tag-neural+lm-$d-$b" --method neural+lm --checkpoint $ck --neural-start $start --budget $b --dofs $d
  done
done
eval_table fits "$OUT" "${rows[@]}"
