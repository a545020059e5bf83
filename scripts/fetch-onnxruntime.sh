#!/usr/bin/env bash
# Fetches the ONNX Runtime shared library that `lfit fit --runtime ort` loads (ort's
# load-dynamic): libonnxruntime.so from the onnxruntime==1.31.1 wheel on PyPI, into
# ${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/onnxruntime-1.31.1/. Idempotent; prints the path.
# With --python it also installs the Python package (for docs/onnx_step.py) into
# .../onnxruntime-1.31.1/python (use it with PYTHONPATH).
set -euo pipefail
VERSION=1.31.1
TOOLS="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}"
DEST="$TOOLS/onnxruntime-$VERSION"
LIB="$DEST/libonnxruntime.so.$VERSION"
case "$(uname -m)" in
    x86_64) PLATFORM=manylinux_2_28_x86_64 ;;
    aarch64) PLATFORM=manylinux_2_28_aarch64 ;;
    *) echo "fetch-onnxruntime: no onnxruntime wheel for $(uname -m)" >&2; exit 1 ;;
esac
PIP=(python3 -m pip)
if ! "${PIP[@]}" --version >/dev/null 2>&1; then
    echo "fetch-onnxruntime: needs python3 with pip" >&2
    exit 1
fi
if [ ! -f "$LIB" ]; then
    mkdir -p "$DEST"
    tmp="$(mktemp -d "$DEST/.download.XXXXXX")"
    trap 'rm -rf "$tmp"' EXIT
    # The library inside is the same for every CPython tag; pin one so any python3 can fetch it.
    "${PIP[@]}" download -q "onnxruntime==$VERSION" --no-deps --only-binary=:all: \
        --python-version 3.11 --platform "$PLATFORM" -d "$tmp" >&2
    wheel="$(ls "$tmp"/onnxruntime-"$VERSION"-*.whl)"
    python3 - "$wheel" "$tmp/lib" <<'PY'
import sys, zipfile
wheel, out = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(wheel) as z:
    names = [n for n in z.namelist() if n.startswith("onnxruntime/capi/libonnxruntime.so")]
    if not names:
        sys.exit("fetch-onnxruntime: the wheel has no libonnxruntime.so")
    z.extract(names[0], out)
PY
    mv "$tmp/lib/onnxruntime/capi/libonnxruntime.so.$VERSION" "$LIB.part"
    mv "$LIB.part" "$LIB"
fi
if [ "${1:-}" = "--python" ] && [ ! -f "$DEST/python/.complete" ]; then
    "${PIP[@]}" install -q --target "$DEST/python" "onnxruntime==$VERSION" numpy >&2
    touch "$DEST/python/.complete"
fi
echo "$LIB"
