#!/usr/bin/env bash
# Installs the Python reference packages of the tests (scipy==1.17.1 and numpy from PyPI) into
# ${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/scipy-1.17.1 and prints that directory (use it as
# PYTHONPATH). Idempotent.
set -euo pipefail
VERSION=1.17.1
TOOLS="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}"
DEST="$TOOLS/scipy-$VERSION"
if ! python3 -m pip --version >/dev/null 2>&1; then
    echo "fetch-scipy: needs python3 with pip" >&2
    exit 1
fi
if [ ! -f "$DEST/.complete" ]; then
    mkdir -p "$TOOLS"
    tmp="$(mktemp -d "$TOOLS/.scipy.XXXXXX")"
    trap 'rm -rf "$tmp"' EXIT
    python3 -m pip install -q --target "$tmp" "scipy==$VERSION" numpy >&2
    rm -rf "$DEST"
    mv "$tmp" "$DEST"
    trap - EXIT
    touch "$DEST/.complete"
fi
echo "$DEST"
