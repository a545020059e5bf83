#!/usr/bin/env bash
# A/B speed of the Burn-free body model: the `lfit-model` crate at an older revision (default
# e3a0f60, the last commit before models became data) against this checkout's, in ONE criterion
# run (benches/ab/ab.rs.in: LBS of the default template, its markers energy with and without the
# gradient, residuals + Jacobian when the old revision has them, and the 24-joint SMPL-like model
# of this checkout with and without pose correctives).
# The old crate is taken with `git archive`, its Burn modules (network/, tensor.rs) removed.
# Builds in a scratch workspace (default /tmp/lfit-model-ab) with its own target directory.
#
#   ./scripts/bench-model-ab.sh [OLD_REV] [-- criterion args]
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$PWD"
OLD_REV="${1:-e3a0f60}"
[ $# -gt 0 ] && shift
[ "${1:-}" = "--" ] && shift
WORK="${LFIT_AB_DIR:-/tmp/lfit-model-ab}"
rm -rf "$WORK/old_src" "$WORK/new_src" "$WORK/ab"
mkdir -p "$WORK/old_src" "$WORK/new_src/model" "$WORK/ab/benches"
git archive "$OLD_REV" model | tar -x -C "$WORK/old_src"
rm -rf "$WORK/old_src/model/src/network" "$WORK/old_src/model/src/tensor.rs" "$WORK/old_src/model/nn"
sed -i '/^pub mod network;$/d; /^pub mod tensor;$/d' "$WORK/old_src/model/src/lib.rs"
sed -i 's/^name = "lfit-model"$/name = "lfit-model-old"/; /^burn.workspace = true$/d' "$WORK/old_src/model/Cargo.toml"
(cd model && tar -c --exclude=./nn . ) | tar -x -C "$WORK/new_src/model"
cp benches/ab/ab.rs.in "$WORK/ab/benches/ab.rs"
# Revisions with the energy's least-squares form (issue 14) also race residuals + Jacobian.
if grep -q "pub fn least_squares" "$WORK/old_src/model/src/energy/least_squares.rs" 2>/dev/null; then
    sed -i -e "/@JACOBIAN@/r benches/ab/jacobian.rs.in" -e "/@JACOBIAN@/d" "$WORK/ab/benches/ab.rs"
fi
cp Cargo.lock "$WORK/Cargo.lock"
# The workspace: this checkout's package settings, lints, profiles and the model crates' deps.
{
    echo '[workspace]'
    echo 'members = ["old_src/model", "new_src/model", "ab"]'
    echo 'resolver = "3"'
    echo
    sed -n '/^\[workspace.package\]/,/^\[package\]/p' Cargo.toml | sed '$d' | grep -v '^lfit-\|^burn\|^ort\|^prost\|^plotters\|^dejavu\|^clap\|^indicatif\|^tracing-subscriber\|^argmin\|^statrs\|^toml\|^anyhow\|^tobj'
    sed -n '/^\[profile/,$p' Cargo.toml | sed '/^\[\[bench\]\]/,$d'
} > "$WORK/Cargo.toml"
cat > "$WORK/ab/Cargo.toml" <<'TOML'
[package]
name = "ab"
version = "0.1.0"
edition = "2024"
publish = false

[dependencies]
old = { package = "lfit-model-old", path = "../old_src/model" }
new = { package = "lfit-model", path = "../new_src/model" }
rayon.workspace = true
rand.workspace = true
rand_chacha.workspace = true

[dev-dependencies]
criterion.workspace = true

[[bench]]
name = "ab"
harness = false
TOML
cd "$WORK"
CARGO_TARGET_DIR="$WORK/target" cargo bench -p ab --bench ab -- --noplot "$@"
echo "criterion estimates: $WORK/target/criterion (run from $ROOT at $(git -C "$ROOT" rev-parse --short HEAD) against $OLD_REV)"
