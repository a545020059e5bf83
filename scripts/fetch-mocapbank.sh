#!/usr/bin/env bash
# Fetches the real motion-capture clip of the retargeting test (issue 15): the MocapBank BVH
# that the bvh_anim 0.4.0 crate ships as data/test_mocapbank.bvh (455 frames at 30 Hz, Y-up,
# centimetres). Its licence is not stated, so lfit does not commit it: `cargo fetch` of a
# throw-away manifest depending on bvh_anim =0.4.0 puts the crate in cargo's registry cache, the
# file is checked against its recorded sha256 and copied to
# ${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/mocapbank/test_mocapbank.bvh. Idempotent; prints
# that path. A wrong or missing file is a one-line error and leaves nothing behind.
set -euo pipefail
VERSION=0.4.0
# sha256 of data/test_mocapbank.bvh in bvh_anim-0.4.0.crate (crates.io), checked 2026-11-30.
SHA256=174e516ae2f6ef42b923a2c7cb75de21aef00d59f59719834d1aba04d2bbeaa8
TOOLS="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}"
DEST="$TOOLS/mocapbank"
FILE="$DEST/test_mocapbank.bvh"
if [ -f "$FILE" ] && [ "$(sha256sum "$FILE" | cut -d' ' -f1)" = "$SHA256" ]; then
    echo "$FILE"
    exit 0
fi
if ! command -v cargo >/dev/null 2>&1; then
    echo "fetch-mocapbank: needs cargo" >&2
    exit 1
fi
mkdir -p "$TOOLS"
tmp="$(mktemp -d "$TOOLS/.mocapbank.XXXXXX")"
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$tmp/probe/src"
cat > "$tmp/probe/Cargo.toml" <<TOML
[package]
name = "lfit-fetch-mocapbank"
version = "0.0.0"
edition = "2021"
publish = false

[dependencies]
bvh_anim = "=$VERSION"

[workspace]
TOML
: > "$tmp/probe/src/lib.rs"
if ! (cd "$tmp/probe" && cargo fetch -q >&2); then
    echo "fetch-mocapbank: cargo fetch of bvh_anim $VERSION failed" >&2
    exit 1
fi
CARGO_HOME_DIR="${CARGO_HOME:-$HOME/.cargo}"
src=""
for f in "$CARGO_HOME_DIR"/registry/src/*/bvh_anim-"$VERSION"/data/test_mocapbank.bvh; do
    [ -f "$f" ] && src="$f"
done
if [ -z "$src" ]; then
    echo "fetch-mocapbank: bvh_anim-$VERSION/data/test_mocapbank.bvh is not in $CARGO_HOME_DIR/registry/src after cargo fetch" >&2
    exit 1
fi
got="$(sha256sum "$src" | cut -d' ' -f1)"
if [ "$got" != "$SHA256" ]; then
    echo "fetch-mocapbank: $src has sha256 $got, expected $SHA256" >&2
    exit 1
fi
cp "$src" "$tmp/test_mocapbank.bvh"
mkdir -p "$DEST"
mv "$tmp/test_mocapbank.bvh" "$FILE"
echo "$FILE"
