#!/usr/bin/env bash
# The README's main command: builds lfit in release mode and runs `lfit quickstart`, which
# synthesises a small held-out set per sparse modality (markers, keypoints2d, hmd) on the CC0
# MakeHuman body (models/makehuman-cmu_mb.npz), fits it with the shipped neural fitters
# (checkpoints/*-makehuman), L-BFGS, Levenberg–Marquardt, CMA-ES and PSO on the same energy, then
# does the same for markers and keypoints2d on every frame of a captured clip, prints the
# comparison table and writes reports, plots and pictures under out/quickstart/<part>/.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}"
cargo build --release --bin lfit
# The captured clip of the comparison (MocapBank, via the bvh_anim crate; not committed, its
# licence is not stated). Without network access the study runs without it.
clip=()
if bvh="$(./scripts/fetch-mocapbank.sh)"; then
    clip=(--clip "$bvh")
else
    echo "quickstart: the MocapBank clip could not be fetched; the captured-motion rows are left out" >&2
fi
"$CARGO_TARGET_DIR/release/lfit" quickstart --out "${1:-out/quickstart}" "${clip[@]}"
