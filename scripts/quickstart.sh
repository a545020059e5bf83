#!/usr/bin/env bash
# The README's main command: builds lfit in release mode and runs `lfit quickstart`, which
# synthesises a small held-out set per sparse modality (markers, keypoints2d, hmd), fits it with
# the shipped neural fitter (checkpoints/), L-BFGS, CMA-ES and PSO on the same energy, prints
# the comparison table and writes reports and plots under out/quickstart/<modality>/.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}"
cargo build --release --bin lfit
"$CARGO_TARGET_DIR/release/lfit" quickstart --out "${1:-out/quickstart}"
