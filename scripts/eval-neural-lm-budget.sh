#!/usr/bin/env bash
# neural+lm against its budget on the held-out CMU subject 6 (validation frames, not the evaluation
# clip), next to the network and LM alone (docs/results/captured-motion.md round 4), for each of
# DOFS (`lfit fit --dofs`: default `observed`; round 14 chose the threshold of `observed` with
# DOFS="all observed:1 observed observed:3 observed:5" BUDGETS=4000).
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
run() { local name="$1"; shift; "$LFIT" -q fit --data "$data" --template "$MODEL" --out "$OUT/$name.json" "$@" >/dev/null; rows+=("$name"); }
ck=checkpoints/$M-makehuman
run "$M-neural" --method neural --checkpoint $ck --neural-start given --budget 10
run "$M-lm" --method lm --budget 4000
for d in ${DOFS:-observed}; do
  for b in ${BUDGETS:-12 14 16 18 20 25 30 40 60 4000}; do
    run "$M-neural+lm-$d-$b" --method neural+lm --checkpoint $ck --neural-start given --budget $b --dofs $d
  done
done
eval_table fits "$OUT" "${rows[@]}"
