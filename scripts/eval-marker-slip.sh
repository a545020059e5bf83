#!/usr/bin/env bash
# Markers that do not sit where the model's marker set puts them (issue 25, "the user's own
# sensors"): the MocapBank evaluation clip (./scripts/fetch-mocapbank.sh; never training data)
# on the MakeHuman body, its markers observed on vertices slipped by σ = SLIPS mm per axis
# (`lfit synth --marker-slip-mm`: per marker the nearest vertex of the same body part to its rest
# position plus a normal draw; one placement per subject: per frame for single frames, once per
# sequence), default noise on top. Fitted as single frames (local scenario) and as a sequence by
# LM, the shipped network and neural+lm; sequences per frame, with one β (`joint:64`) and with one
# β and each marker's offset solved (`joint:64+solve`: `--marker-placement solve`). Prints one
# Markdown table per slip and writes every result under OUT.
#
#   scripts/eval-marker-slip.sh [OUT] [CHECKPOINT]
#
# OUT defaults to target/eval-marker-slip; CHECKPOINT to checkpoints/markers-makehuman; SLIPS
# (default "0 10 20") the σ in mm; LFIT (default: the release build) is the binary. Same seeds:
# the same numbers, but for the times.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-target/eval-marker-slip}"
CK="${2:-checkpoints/markers-makehuman}"
# The clip frames' seed of docs/results/learned-vs-classical.md and eval-captured.sh.
SEED=9103745171752751104
source scripts/eval-common.sh
eval_setup eval-marker-slip "$OUT"
eval_need_dir eval-marker-slip "$CK"
FRAMES="${EVAL_FRAMES:-454}"
for slip in ${SLIPS:-0 10 20}; do
    rows=()
    run() { # name data method extra...
        local name="$1" data="$2" method="$3"
        shift 3
        "$LFIT" -q fit --data "$data" --template "$MODEL" --method "$method" --out "$OUT/$name.json" "$@" >/dev/null
        rows+=("$name")
    }
    for scenario in local sequence; do
        data="$OUT/clip-$scenario-slip$slip.npz"
        "$LFIT" -q synth --modality markers --scenario "$scenario" --frames "$FRAMES" --seed "$SEED" \
            --template "$MODEL" --motions "$OUT/clip-motion.npz" --marker-slip-mm "$slip" --out "$data" >/dev/null
        p="slip$slip-$scenario"
        if [ "$scenario" = local ]; then
            run "$p-lm" "$data" lm --budget 4000
            run "$p-neural" "$data" neural --checkpoint "$CK" --neural-start given --budget 10
            run "$p-neural+lm" "$data" neural+lm --checkpoint "$CK" --neural-start given --budget 4000
        else
            for shape in per-frame joint:64 joint:64+solve; do
                s="${shape/:/}"
                # joint:64+solve: the joint β pass with each marker's offset solved.
                flags=(--sequence-shape "${shape%+solve}")
                [ "$shape" = "${shape%+solve}" ] || flags+=(--marker-placement solve)
                run "$p-lm-$s" "$data" lm --budget 4000 "${flags[@]}"
                run "$p-neural-both-$s" "$data" neural --checkpoint "$CK" --neural-start both --budget 24 \
                    "${flags[@]}"
                run "$p-neural+lm-both-$s" "$data" neural+lm --checkpoint "$CK" --neural-start both \
                    --budget 4000 "${flags[@]}"
            done
        fi
    done
    echo "### marker slip σ = $slip mm"
    eval_table fits "$OUT" "${rows[@]}"
done
