"""The example script examples/python/fit_c3d.py runs end to end on a C3D file written by
`lfit data export-c3d` from synthetic markers."""

import subprocess
import sys

from conftest import ROOT


def test_fit_c3d_example(cli, tmp_path):
    data = tmp_path / "m.npz"
    cli("synth", "--modality", "markers", "--model", ROOT / "models" / "makehuman-cmu_mb.npz",
        "--frames", 4, "--seed", 2, "--noise", 0, "--out", data)
    c3d = tmp_path / "m.c3d"
    cli("data", "export-c3d", "--data", data, "--out", c3d)
    p = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "python" / "fit_c3d.py"), str(c3d), "--budget", "60",
         "--plot", str(tmp_path / "e.png")],
        capture_output=True, text=True,
    )
    assert p.returncode == 0, p.stderr
    assert "marker error" in p.stdout and "mean" in p.stdout, p.stdout
