"""Shared helpers of the Python package's tests.

A test that needs a component this machine lacks (the `lfit` CLI binary, scipy, the MocapBank
clip, the neural fitter) skips with the reason locally and fails when CI=true, as the Rust tests
do (tests/support).
"""

import json
import os
import signal
import subprocess
from pathlib import Path

# One BLAS thread per call: the scipy parity test runs frames on several threads already.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import lfit  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def require(reason):
    """Skip with `reason` locally; fail in CI, which must run every test."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"required in CI: {reason}")
    pytest.skip(reason)


@pytest.fixture
def sigint_handled():
    """Python's own SIGINT handler for the test. A shell that starts the tests in the background
    (`./scripts/test.sh &`) leaves SIGINT ignored, Python then installs no handler, and
    `_thread.interrupt_main` does nothing: the Ctrl-C tests would run their work to the end."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def cli_path():
    """The release `lfit` binary the wheel was built next to (LFIT_BIN overrides)."""
    if os.environ.get("LFIT_BIN"):
        return Path(os.environ["LFIT_BIN"])
    target = os.environ.get("CARGO_TARGET_DIR", str(Path.home() / ".cache/lfit-target"))
    return Path(target) / "release" / "lfit"


@pytest.fixture(scope="session")
def cli():
    """Runs the `lfit` CLI; returns its parsed JSON summary (or the CompletedProcess with
    check=False)."""
    exe = cli_path()
    if not exe.exists():
        require(f"the lfit CLI binary {exe} is missing (cargo build --release)")

    def run(*args, check=True):
        p = subprocess.run([str(exe), *map(str, args), "-q"], capture_output=True, text=True)
        if not check:
            return p
        assert p.returncode == 0, p.stderr
        return json.loads(p.stdout) if p.stdout.strip() else None

    return run


@pytest.fixture(scope="session")
def makehuman():
    return lfit.Model.load(ROOT / "models" / "makehuman-cmu_mb.npz")


def scipy_optimize():
    try:
        import scipy.optimize

        return scipy.optimize
    except ImportError as e:  # pragma: no cover - depends on the machine
        require(f"scipy is not importable ({e}); scripts/fetch-scipy.sh installs it (LFIT_SCIPY_PYTHONPATH)")


def one_line(err):
    text = str(err.value)
    assert "\n" not in text and text, repr(text)
    return text


@pytest.fixture
def rng():
    return np.random.default_rng(7)
