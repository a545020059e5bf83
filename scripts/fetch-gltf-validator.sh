#!/usr/bin/env bash
# Installs the Khronos glTF validator (npm package gltf-validator, pinned) into a cache directory
# outside the clone, for the `lfit export --format gltf` tests. Idempotent: a second run with the
# pinned version already there does nothing. Prints the install prefix on stdout; the tests find
# the package there through LFIT_GLTF_VALIDATOR=<prefix> (scripts/validate-gltf.mjs reads it).
set -euo pipefail

VERSION="2.0.0-dev.3.10"
PREFIX="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/gltf-validator"
PACKAGE_JSON="$PREFIX/node_modules/gltf-validator/package.json"

installed_version() {
    node -e 'process.stdout.write(require(process.argv[1]).version)' "$PACKAGE_JSON" 2>/dev/null || true
}

if ! command -v node >/dev/null 2>&1; then
    echo "fetch-gltf-validator: node is not installed" >&2
    exit 1
fi
if [ -f "$PACKAGE_JSON" ] && [ "$(installed_version)" = "$VERSION" ]; then
    echo "$PREFIX"
    exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
    echo "fetch-gltf-validator: npm is not installed" >&2
    exit 1
fi
mkdir -p "$PREFIX"
echo "fetch-gltf-validator: installing gltf-validator@$VERSION into $PREFIX" >&2
npm install --prefix "$PREFIX" --no-audit --no-fund --no-save --loglevel=error "gltf-validator@$VERSION" >&2
if [ "$(installed_version)" != "$VERSION" ]; then
    echo "fetch-gltf-validator: gltf-validator@$VERSION is not in $PREFIX after npm install" >&2
    exit 1
fi
echo "$PREFIX"
