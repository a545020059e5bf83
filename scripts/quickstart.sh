#!/usr/bin/env bash
# The README's main command, until `lfit quickstart` exists: the most complete pipeline so far.
# Exports the procedural template, poses it, synthesizes a small dataset per modality, fits 20
# frames of the markers set with CMA-ES, PSO and L-BFGS on the same energy, and fits every frame
# of the markers, keypoints2d and hmd sets with the shipped neural fitters (checkpoints/).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}"
OUT="${1:-out/quickstart}"
mkdir -p "$OUT"
cargo build --release --bin lfit
LFIT="$CARGO_TARGET_DIR/release/lfit"
"$LFIT" template export --out-dir "$OUT/template"
# A mid-stride pose: root turned 0.3 rad, right hip flexed, knee bent, arms swinging.
cat > "$OUT/walk_pose.json" <<'JSON'
{"pose": [0, 0, 0,  0, 0.3, 0,  0.2, 0, 0,  0, 0, 0,  0.3, 0, 0,
          -0.5, 0, 0,  0.7, 0, 0,  0, 0, 0,  0, 0, 0,
           0.35, 0, 0,  0.2, 0, 0,  0, 0, 0,  0, 0, 0,
           0, 0.5, 0,  0, 0.9, 0,  0, 0, 0,
           0, 0, 0.9,  0, -0.6, 0,  0, 0, 0]}
JSON
"$LFIT" template pose --pose "$OUT/walk_pose.json" --out "$OUT/posed.obj" --template "$OUT/template"
for m in markers keypoints2d hmd; do
    "$LFIT" synth --modality "$m" --scenario local --frames 200 --seed 1 --out "$OUT/$m.npz"
done
"$LFIT" synth --modality hmd --scenario sequence --frames 300 --seed 2 --out "$OUT/hmd_sequence.npz"
"$LFIT" synth --modality scan --scenario global --frames 4 --seed 3 --out "$OUT/scan.npz"
for spec in "cma 2000" "pso 2000" "lbfgs 200"; do
    set -- $spec
    echo "fitting markers.npz frames 0..20 with $1 (budget $2 per frame):"
    "$LFIT" fit --data "$OUT/markers.npz" --method "$1" --budget "$2" --frames 0..20 --out "$OUT/fit_$1.json" -q
done
for m in markers keypoints2d hmd; do
    echo "fitting $m.npz (200 frames) with the shipped neural fitter checkpoints/$m (5 iterations, from the start pose):"
    "$LFIT" fit --data "$OUT/$m.npz" --method neural --checkpoint "checkpoints/$m" --neural-start given --budget 10 --out "$OUT/fit_neural_$m.json" -q
done
echo "wrote $OUT: template/, posed.obj, datasets (open them with numpy.load) and fit_*.json results (fit_neural_*.json: neural fitter)"
