#!/usr/bin/env bash
# Installs lfit for use outside the checkout: the release binary as PREFIX/bin/lfit (cargo
# install) and the data it ships — models/, configs/, checkpoints/ — under PREFIX/share/lfit,
# where the binary looks for them (src/shipped.rs; LFIT_DATA_DIR overrides). PREFIX defaults to
# ~/.local. Reuses the build directory ${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}.
#   ./scripts/install.sh [PREFIX]
set -euo pipefail
cd "$(dirname "$0")/.."
PREFIX="${1:-$HOME/.local}"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}"
cargo install --locked --path . --root "$PREFIX" --bin lfit
share="$PREFIX/share/lfit"
mkdir -p "$share"
for d in models configs checkpoints; do
    # Into a temporary folder first, then renamed: an interrupted install leaves the old copy.
    rm -rf "$share/.$d.new"
    cp -R "$d" "$share/.$d.new"
    rm -rf "$share/$d"
    mv "$share/.$d.new" "$share/$d"
done
echo "installed $PREFIX/bin/lfit; its models, configs and checkpoints are in $share"
