#!/usr/bin/env bash
# Installs the Python reference packages of the tests from PyPI (scipy==1.17.1 with numpy, and
# c3d==0.6.0, an independent C3D writer) into ${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/scipy-1.17.1
# and prints that directory (use it as PYTHONPATH). Idempotent: reinstalls when the package list
# changes; callers at once wait for one another's install.
set -euo pipefail
VERSION=1.17.1
TOOLS="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}"
DEST="$TOOLS/scipy-$VERSION"
PACKAGES="scipy==$VERSION numpy c3d==0.6.0"
if ! python3 -m pip --version >/dev/null 2>&1; then
    echo "fetch-scipy: needs python3 with pip" >&2
    exit 1
fi
mkdir -p "$TOOLS"
# One install at a time: two callers at once (two eval scripts side by side) would otherwise both
# install, and the second one's swap would remove the directory the first one's Python is
# importing from ("No module named 'numpy.char'"). The second waits and finds the install done.
if command -v flock >/dev/null 2>&1; then
    exec 9>"$TOOLS/.scipy-$VERSION.lock"
    flock 9
fi
if [ "$(cat "$DEST/.complete" 2>/dev/null)" != "$PACKAGES" ]; then
    tmp="$(mktemp -d "$TOOLS/.scipy.XXXXXX")"
    trap 'rm -rf "$tmp"' EXIT
    # shellcheck disable=SC2086
    python3 -m pip install -q --target "$tmp" $PACKAGES >&2
    rm -rf "$DEST"
    mv "$tmp" "$DEST"
    trap - EXIT
    echo "$PACKAGES" > "$DEST/.complete"
fi
echo "$DEST"
