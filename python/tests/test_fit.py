"""lfit.fit: the same results as `lfit fit` on the same data, as arrays; bad input is the CLI's
one-line error; Ctrl-C stops a fit."""

import json
import threading
import time
import _thread

import numpy as np
import pytest

import lfit
from conftest import ROOT, one_line, require


@pytest.fixture(scope="module")
def markers_file(tmp_path_factory, cli):
    path = tmp_path_factory.mktemp("fit") / "markers.npz"
    cli("synth", "--modality", "markers", "--model", ROOT / "models" / "makehuman-cmu_mb.npz",
        "--frames", 6, "--seed", 5, "--out", path)
    return path


@pytest.mark.parametrize("method, budget", [("lm", 100), ("lbfgs", 60), ("cma", 150)])
def test_fit_equals_the_cli(makehuman, markers_file, cli, tmp_path, method, budget):
    out = tmp_path / "cli.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz",
        "--method", method, "--budget", budget, "--frames", "1..5", "--seed", 3, "--out", out)
    theirs = json.loads(out.read_text())
    ours = lfit.fit(makehuman, markers_file, method=method, budget=budget, frames="1..5", seed=3)
    assert list(ours.frames) == [1, 2, 3, 4]
    rows = theirs["frames"]
    np.testing.assert_array_equal(ours.energies, [r["energy"] for r in rows])
    np.testing.assert_array_equal(ours.poses, [r["pose"] for r in rows])
    np.testing.assert_array_equal(ours.shapes, [r["shape"] for r in rows])
    np.testing.assert_array_equal(ours.v2v_mm, [r["v2v_mm"] for r in rows])
    np.testing.assert_array_equal(ours.pa_mpjpe_mm, [r["pa_mpjpe_mm"] for r in rows])
    assert (ours.pa_mpjpe_mm > 0).all() and (ours.pa_mpjpe_mm <= 1.05 * ours.mpjpe_mm).all()
    np.testing.assert_array_equal(ours.evaluations, [r["evaluations"] for r in rows])
    assert ours.params.shape == (4, makehuman.dim)
    assert ours.summary["frames"] == 4 and ours.method == theirs["method"]
    assert np.isnan(ours.observation_error).all() and ours.observation_unit is None
    doc = ours.document()
    assert doc["energy_config"] == theirs["energy_config"] and doc["data"] == str(markers_file)


def test_holdout_equals_the_cli(makehuman, markers_file, cli, tmp_path):
    out = tmp_path / "cli.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz",
        "--method", "lm", "--budget", 100, "--frames", "0..4", "--holdout", "LFHD,RKNE,LWRA",
        "--out", out)
    theirs = json.loads(out.read_text())
    # A list or the CLI's comma-separated string: the same fit.
    for items in (["LFHD", "RKNE", "LWRA"], "LFHD,RKNE,LWRA"):
        ours = lfit.fit(makehuman, markers_file, method="lm", budget=100, frames="0..4", holdout=items)
        rows = theirs["frames"]
        np.testing.assert_array_equal(ours.poses, [r["pose"] for r in rows])
        np.testing.assert_array_equal(ours.holdout_error, [r["holdout_error_mm"] for r in rows])
        assert ours.summary["mean_holdout_error_mm"] == theirs["summary"]["mean_holdout_error_mm"]
        assert ours.document()["holdout"] == ["LFHD", "RKNE", "LWRA"]
    # Without it: NaN.
    plain = lfit.fit(makehuman, markers_file, method="lm", budget=20, frames="0..2")
    assert np.isnan(plain.holdout_error).all()
    with pytest.raises(ValueError, match="'NOPE' is not a marker of the data"):
        lfit.fit(makehuman, markers_file, method="lm", budget=20, holdout="NOPE")
    with pytest.raises(ValueError, match="holdout must be a string or a list of strings"):
        lfit.fit(makehuman, markers_file, method="lm", budget=20, holdout=3)


def test_a_floor_fits_as_the_cli(makehuman, markers_file, cli, tmp_path):
    """floor=: `lfit fit --floor`, the same poses and the floor the result file records; a bad
    form is the CLI's one-line error."""
    out = tmp_path / "cli.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz",
        "--method", "lm", "--budget", 100, "--frames", "0..3", "--floor", "contact:truth,10",
        "--out", out)
    theirs = json.loads(out.read_text())
    ours = lfit.fit(makehuman, markers_file, method="lm", budget=100, frames="0..3",
                    floor="contact:truth,10")
    np.testing.assert_array_equal(ours.poses, [r["pose"] for r in theirs["frames"]])
    doc = ours.document()
    assert doc["floor"] == theirs["floor"] and doc["floor"]["form"] == "contact"
    assert ours.summary["mean_lowest_sole_m"] == theirs["summary"]["mean_lowest_sole_m"]
    plain = lfit.fit(makehuman, markers_file, method="lm", budget=100, frames="0..3")
    assert not np.array_equal(plain.poses, ours.poses) and "floor" not in plain.document()
    with pytest.raises(ValueError, match="--floor 'under:0'"):
        lfit.fit(makehuman, markers_file, method="lm", budget=20, floor="under:0")


def test_a_pose_prior_energy_fits_as_the_cli(makehuman, markers_file, cli, tmp_path):
    """`lfit motion prior`'s energy file given to `fit(energy=)`: the CLI's fit, the prior's term
    reported; as a dict (the file's JSON) the same."""
    model = ROOT / "models" / "makehuman-cmu_mb.npz"
    prior = tmp_path / "prior.json"
    motions = sorted((ROOT / "data" / "motions" / "cmu" / "train").glob("00[12]_0*.npz"))
    cli("motion", "prior", "--motions", *motions, "--model", model, "--stride", 4, "--out", prior)
    out = tmp_path / "cli.json"
    cli("fit", "--data", markers_file, "--model", model, "--method", "lm", "--budget", 100,
        "--frames", "0..3", "--energy", prior, "--out", out)
    rows = json.loads(out.read_text())["frames"]
    assert all("pose-prior" in r["terms"] for r in rows)
    for energy in (str(prior), json.loads(prior.read_text())):
        ours = lfit.fit(makehuman, markers_file, method="lm", budget=100, frames="0..3", energy=energy)
        np.testing.assert_array_equal(ours.poses, [r["pose"] for r in rows])
    plain = lfit.fit(makehuman, markers_file, method="lm", budget=100, frames="0..3")
    assert not np.array_equal(plain.poses, ours.poses)


def test_motion_prior_is_the_cli_s_energy(makehuman, cli, tmp_path):
    """`lfit.motion_prior` gives the CLI's energy configuration (the same file bytes with `out=`),
    a summary with its scores, a mixture with `components=`, and one-line errors."""
    model = ROOT / "models" / "makehuman-cmu_mb.npz"
    motions = sorted((ROOT / "data" / "motions" / "cmu" / "train").glob("00[12]_0*.npz"))
    held = sorted((ROOT / "data" / "motions" / "cmu" / "validation").glob("*.npz"))[:1]
    prior = tmp_path / "cli.json"
    cli("motion", "prior", "--motions", *motions, "--model", model, "--stride", 4,
        "--modality", "keypoints2d", "--held-out", *held, "--out", prior)
    out = tmp_path / "py.json"
    energy, summary = lfit.motion_prior(motions, makehuman, stride=4, modality="keypoints2d",
                                        held_out=held, out=out)
    assert out.read_bytes() == prior.read_bytes()
    assert energy == json.loads(prior.read_text())
    assert energy["weights"]["pose_prior"] == 0.001 and summary["components"] == 1
    assert summary["held_out"]["frames"] > 0
    assert summary["held_out"]["mean_log_likelihood"] < summary["mean_log_likelihood"]
    mix, s2 = lfit.motion_prior(motions, makehuman, stride=4, components=2, seed=1)
    assert len(mix["pose_prior"]["components"]) == 2 and s2["em_converged"]
    for kwargs, why in [({"modality": "hmd"}, "give --weight"), ({"stride": 0}, "stride"),
                        ({"components": 0}, "components")]:
        with pytest.raises(lfit.LfitError, match=why):
            lfit.motion_prior(motions, makehuman, **kwargs)
    with pytest.raises(lfit.LfitError, match="motions must be"):
        lfit.motion_prior([42], makehuman)


def test_in_memory_dataset_and_frame_list(makehuman):
    data = lfit.synth("keypoints2d", makehuman, frames=5, seed=2)
    seen = []
    result = lfit.fit(makehuman, data, method="lm", budget=50, frames=[0, 3], progress=lambda d, t: seen.append((d, t)))
    assert list(result.frames) == [0, 3] and seen == [(1, 2), (2, 2)]
    assert (result.energies <= result.start_energies + 1e-12).all()
    assert result.document()["data"] is None


def test_ctrl_c_stops_a_fit(makehuman, sigint_handled):
    data = lfit.synth("markers", makehuman, frames=400, seed=9)
    timer = threading.Timer(0.5, _thread.interrupt_main)
    start = time.perf_counter()
    timer.start()
    def guard(done, total):
        # Fails the test instead of running for minutes when the interrupt is not honoured.
        if done > 30:
            raise RuntimeError("Ctrl-C did not stop the fit")

    with pytest.raises(KeyboardInterrupt):
        lfit.fit(makehuman, data, method="cma", budget=3000, progress=guard)
    elapsed = time.perf_counter() - start
    timer.cancel()
    # 400 frames of 3000 evaluations take minutes; the interrupt lands within a frame or two.
    assert elapsed < 20, elapsed


def test_errors_are_the_cli_lines(cli, markers_file, tmp_path):
    missing = tmp_path / "nothing.npz"
    out = tmp_path / "never.json"
    cases = [
        ((None, missing), {"method": "lm", "budget": 10}, ["--data", missing, "--method", "lm", "--budget", 10]),
        ((None, markers_file), {"method": "lm", "budget": 0}, ["--data", markers_file, "--method", "lm", "--budget", 0]),
        ((None, markers_file), {"method": "lm", "budget": 10, "frames": "3..99"}, ["--data", markers_file, "--method", "lm", "--budget", 10, "--frames", "3..99"]),
        ((None, markers_file), {"method": "lm", "budget": 10, "strategy": "sideways"}, ["--data", markers_file, "--method", "lm", "--budget", 10, "--strategy", "sideways"]),
        ((None, markers_file), {"method": "lm", "budget": 10, "known_shape": "0.5,x"}, ["--data", markers_file, "--method", "lm", "--budget", 10, "--known-shape", "0.5,x"]),
        ((None, markers_file), {"method": "lm", "budget": 10, "known_shape": "height:2.6"}, ["--data", markers_file, "--method", "lm", "--budget", 10, "--known-shape", "height:2.6"]),
    ]
    for args, kwargs, flags in cases:
        with pytest.raises(lfit.LfitError) as e:
            lfit.fit(*args, **kwargs)
        p = cli("fit", *flags, "--out", out, check=False)
        assert p.returncode == 1 and p.stderr.strip() == f"error: {one_line(e)}", (p.stderr, str(e.value))
        assert not out.exists()


def test_bad_arguments(makehuman, markers_file):
    with pytest.raises(lfit.LfitError, match="unknown method 'lmm'"):
        lfit.fit(makehuman, markers_file, method="lmm")
    with pytest.raises(lfit.LfitError, match=r"known_shape\[2\] is not a finite number"):
        lfit.fit(makehuman, markers_file, known_shape=[0.0, 1.0, np.nan])
    with pytest.raises(lfit.LfitError, match="data: expected an lfit.Dataset"):
        lfit.fit(makehuman, 3)
    with pytest.raises(lfit.LfitError, match="frames: -1 is not a frame index"):
        lfit.fit(makehuman, markers_file, frames=[-1])


def test_neural_fit_and_a_checkpoint_of_another_model(makehuman, markers_file, cli, tmp_path):
    if not lfit.HAS_NEURAL:
        with pytest.raises(lfit.LfitError, match="no neural fitter"):
            lfit.fit(makehuman, markers_file, method="neural", budget=10, checkpoint=ROOT / "checkpoints" / "markers-makehuman")
        # The Burn-free wheel's refusal is asserted above; the neural path needs the neural wheel,
        # which scripts/test.sh builds unless LFIT_PY_NEURAL=0 (required in CI).
        require("this wheel was built without the neural feature (LFIT_PY_NEURAL=0)")
    ck = ROOT / "checkpoints" / "markers-makehuman"
    out = tmp_path / "n.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz", "--method", "neural+lm",
        "--checkpoint", ck, "--budget", 40, "--out", out)
    theirs = json.loads(out.read_text())["frames"]
    ours = lfit.fit(makehuman, markers_file, method="neural+lm", budget=40, checkpoint=ck)
    np.testing.assert_allclose(ours.energies, [r["energy"] for r in theirs], rtol=1e-9)
    # dofs="all": LM over every entry, the CLI's `--dofs all`; a different fit from the default's.
    out = tmp_path / "all.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz", "--method", "neural+lm",
        "--checkpoint", ck, "--budget", 40, "--dofs", "all", "--out", out)
    theirs = json.loads(out.read_text())["frames"]
    everything = lfit.fit(makehuman, markers_file, method="neural+lm", budget=40, checkpoint=ck, dofs="all")
    np.testing.assert_allclose(everything.energies, [r["energy"] for r in theirs], rtol=1e-9)
    assert not np.allclose(everything.poses, ours.poses)
    with pytest.raises(lfit.LfitError, match="unknown dofs 'most'"):
        lfit.fit(makehuman, markers_file, method="neural+lm", budget=40, checkpoint=ck, dofs="most")
    # The network on the anchored energy with what the markers leave held (the sequence
    # networks' dofs): the CLI's fits, other than the plain network's.
    seq = ROOT / "checkpoints" / "markers-makehuman-sequence"
    out = tmp_path / "seq.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz", "--method", "neural",
        "--checkpoint", seq, "--neural-start", "given", "--budget", 12, "--dofs", "observed:30+anchored:4",
        "--out", out)
    theirs = json.loads(out.read_text())["frames"]
    held = lfit.fit(makehuman, markers_file, method="neural", budget=12, checkpoint=seq, neural_start="given",
                    dofs="observed:30+anchored:4")
    np.testing.assert_allclose(held.energies, [r["energy"] for r in theirs], rtol=1e-9)
    plain = lfit.fit(makehuman, markers_file, method="neural", budget=12, checkpoint=seq, neural_start="given")
    assert not np.allclose(held.poses, plain.poses)
    # runtime="native" (lfit's own f32 forward): the CLI's native fits, and within f32 rounding of
    # Burn's (the network outputs agree to ~1e-6, tests/onnx_runtime.rs).
    out = tmp_path / "native.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz", "--method", "neural",
        "--checkpoint", ck, "--budget", 10, "--runtime", "native", "--out", out)
    theirs = json.loads(out.read_text())["frames"]
    native = lfit.fit(makehuman, markers_file, method="neural", budget=10, checkpoint=ck, runtime="native")
    burn = lfit.fit(makehuman, markers_file, method="neural", budget=10, checkpoint=ck)
    np.testing.assert_allclose(native.energies, [r["energy"] for r in theirs], rtol=1e-9)
    np.testing.assert_allclose(native.poses, burn.poses, atol=1e-4)
    def as_cli(budget, flag, value):
        """The neural fit with `--flag value` (Python keyword `flag`), asserted equal to the CLI's."""
        out = tmp_path / f"{value}.json"
        cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz", "--method", "neural",
            "--checkpoint", ck, "--budget", budget, "--" + flag.replace("_", "-"), value, "--out", out)
        theirs = json.loads(out.read_text())["frames"]
        ours = lfit.fit(makehuman, markers_file, method="neural", budget=budget, checkpoint=ck, **{flag: value})
        np.testing.assert_allclose(ours.energies, [r["energy"] for r in theirs], rtol=1e-9)
        return ours

    # neural_pick="lowest": the CLI's fits (the lowest-energy iterate, one more evaluation).
    lowest = as_cli(11, "neural_pick", "lowest")
    assert all(a <= b for a, b in zip(lowest.energies, burn.energies))
    # neural_start="both" (a fit from the given start and one from Φ(D), the lower-energy result):
    # the CLI's fits, never above the fit from Φ(D) alone on these single frames.
    both = as_cli(22, "neural_start", "both")
    assert all(a <= b * (1 + 1e-9) for a, b in zip(both.energies, burn.energies))
    # neural_iterations=2 (an early exit: the network's first 2 iterations, 4 evaluations): the
    # CLI's fits, not the full fit's.
    early = as_cli(4, "neural_iterations", 2)
    assert not np.allclose(early.energies, burn.energies)
    # neural_tolerance=0.2 (each frame stops where its step lowers the energy by < 20 %): the CLI's.
    as_cli(10, "neural_tolerance", 0.2)
    with pytest.raises(lfit.LfitError, match="neural tolerance 1.5: a relative energy decrease between 0 and 1"):
        lfit.fit(makehuman, markers_file, method="neural", budget=10, checkpoint=ck, neural_tolerance=1.5)
    with pytest.raises(lfit.LfitError, match="6 iterations asked of a network trained for 5: choose 1 to 5"):
        lfit.fit(makehuman, markers_file, method="neural", budget=12, checkpoint=ck, neural_iterations=6)
    with pytest.raises(lfit.LfitError, match="unknown neural start 'all' \\(expected phi, given, best or both\\)"):
        lfit.fit(makehuman, markers_file, method="neural", budget=22, checkpoint=ck, neural_start="all")
    with pytest.raises(lfit.LfitError, match="unknown neural pick 'first'"):
        lfit.fit(makehuman, markers_file, method="neural", budget=11, checkpoint=ck, neural_pick="first")
    with pytest.raises(lfit.LfitError, match="unknown runtime 'cuda' \\(expected burn, ort or native\\)"):
        lfit.fit(makehuman, markers_file, method="neural", budget=10, checkpoint=ck, runtime="cuda")
    # A checkpoint of another model: the CLI's line, nothing written.
    other = tmp_path / "default.npz"
    lfit.synth("markers", frames=2, seed=1, out=other)
    with pytest.raises(lfit.LfitError) as e:
        lfit.fit(None, other, method="neural", budget=10, checkpoint=ck)
    never = tmp_path / "never.json"
    p = cli("fit", "--data", other, "--method", "neural", "--budget", 10, "--checkpoint", ck, "--out", never, check=False)
    assert p.returncode == 1 and p.stderr.strip() == f"error: {one_line(e)}", (p.stderr, str(e.value))
    assert not never.exists()


def test_a_height_gives_the_cli_s_shape(makehuman, markers_file, cli, tmp_path):
    """known_shape="height:M": every frame gets the CLI's β of that height, frozen."""
    out = tmp_path / "cli.json"
    cli("fit", "--data", markers_file, "--model", ROOT / "models" / "makehuman-cmu_mb.npz",
        "--method", "lm", "--budget", 60, "--frames", "0..3", "--known-shape", "height:1.72",
        "--out", out)
    theirs = json.loads(out.read_text())
    ours = lfit.fit(makehuman, markers_file, method="lm", budget=60, frames="0..3",
                    known_shape="height:1.72")
    beta = theirs["known_shape"]["beta"]
    assert theirs["known_shape"]["height_m"] == 1.72 and np.abs(beta).max() > 0
    np.testing.assert_array_equal(ours.shapes, [beta] * 3)
    np.testing.assert_array_equal(ours.poses, [r["pose"] for r in theirs["frames"]])
    # The model's own: the same β, that tall; the mean shape's height; bad heights refused.
    np.testing.assert_array_equal(makehuman.shape_for_height(1.72), beta)
    assert abs(makehuman.rest_height(beta) - 1.72) < 1e-9
    assert abs(makehuman.rest_height() - 1.666) < 1e-3
    assert makehuman.rest_height(np.zeros(3)) == makehuman.rest_height()
    with pytest.raises(lfit.LfitError, match="out of reach"):
        makehuman.shape_for_height(2.6)
    with pytest.raises(lfit.LfitError, match="positive number of metres"):
        makehuman.shape_for_height(-1.0)
    with pytest.raises(lfit.LfitError, match=r"shape has shape \(17,\)"):
        makehuman.rest_height(np.zeros(17))


def test_a_height_prior_is_the_cli_s(makehuman, markers_file, cli, tmp_path):
    """height_prior=: the CLI's --height-prior fits bit for bit in each of its forms; β stays
    estimated and its rest height moves toward the prior's; bad forms are the CLI's errors."""
    model = ROOT / "models" / "makehuman-cmu_mb.npz"
    out = tmp_path / "cli.json"
    cli("fit", "--data", markers_file, "--model", model, "--method", "lm", "--budget", 60,
        "--frames", "0..3", "--height-prior", "1.85:0.02", "--out", out)
    theirs = json.loads(out.read_text())
    assert theirs["height_prior"] == {"height_m": 1.85, "std_m": 0.02}
    for form in [(1.85, 0.02), "1.85:0.02"]:
        ours = lfit.fit(makehuman, markers_file, method="lm", budget=60, frames="0..3",
                        height_prior=form)
        np.testing.assert_array_equal(ours.poses, [r["pose"] for r in theirs["frames"]])
        np.testing.assert_array_equal(ours.shapes, [r["shape"] for r in theirs["frames"]])
    assert [makehuman.rest_height(b) for b in ours.shapes] == \
        [r["rest_height_m"] for r in theirs["frames"]]
    free = lfit.fit(makehuman, markers_file, method="lm", budget=60, frames="0..3")
    assert not (ours.shapes == ours.shapes[0]).all(), "β per frame"
    for b, f in zip(ours.shapes, free.shapes):
        assert abs(makehuman.rest_height(b) - 1.85) < abs(makehuman.rest_height(f) - 1.85)
    # A bare number: the default standard deviation (0.01 m), the CLI's "1.85".
    bare = lfit.fit(makehuman, markers_file, method="lm", budget=60, frames="0..3",
                    height_prior=1.85)
    cli("fit", "--data", markers_file, "--model", model, "--method", "lm", "--budget", 60,
        "--frames", "0..3", "--height-prior", "1.85", "--out", out)
    np.testing.assert_array_equal(bare.poses, [r["pose"] for r in json.loads(out.read_text())["frames"]])
    with pytest.raises(lfit.LfitError, match="--height-prior 'tall'"):
        lfit.fit(makehuman, markers_file, method="lm", budget=5, frames="0", height_prior="tall")
    with pytest.raises(lfit.LfitError, match="height_prior: expected metres"):
        lfit.fit(makehuman, markers_file, method="lm", budget=5, frames="0",
                 height_prior=(1.7, 0.01, 3))
    with pytest.raises(lfit.LfitError, match="use one"):
        lfit.fit(makehuman, markers_file, method="lm", budget=5, frames="0",
                 height_prior=1.7, known_shape="height:1.7")


def test_one_shape_per_sequence_equals_the_cli(makehuman, cli, tmp_path):
    """sequence_shape="joint": one β for the whole sequence (solved with every frame's pose),
    the CLI's bit for bit; the policy names are the CLI's."""
    data = tmp_path / "seq.npz"
    cli("synth", "--modality", "markers", "--scenario", "sequence", "--model",
        ROOT / "models" / "makehuman-cmu_mb.npz", "--frames", 5, "--seed", 11, "--out", data)
    out = tmp_path / "cli.json"
    cli("fit", "--data", data, "--model", ROOT / "models" / "makehuman-cmu_mb.npz", "--method", "lm",
        "--budget", 200, "--sequence-shape", "joint", "--seed", 3, "--out", out)
    theirs = json.loads(out.read_text())
    ours = lfit.fit(makehuman, data, method="lm", budget=200, sequence_shape="joint", seed=3)
    rows = theirs["frames"]
    np.testing.assert_array_equal(ours.shapes, [r["shape"] for r in rows])
    np.testing.assert_array_equal(ours.poses, [r["pose"] for r in rows])
    assert (ours.shapes == ours.shapes[0]).all(), "one β for the sequence"
    assert np.abs(ours.shapes[0]).max() > 0, "β was estimated, not left at the mean"
    with pytest.raises(lfit.LfitError, match="unknown sequence shape policy 'median'"):
        lfit.fit(makehuman, data, method="lm", budget=20, sequence_shape="median")


def test_solved_marker_placement_equals_the_cli(makehuman, cli, tmp_path):
    """marker_placement="solve": each marker's offset solved with the sequence's β, the CLI's
    fits bit for bit; refused with the CLI's line where it cannot apply."""
    model = ROOT / "models" / "makehuman-cmu_mb.npz"
    data = tmp_path / "slip.npz"
    cli("synth", "--modality", "markers", "--scenario", "sequence", "--model", model,
        "--frames", 6, "--seed", 12, "--marker-slip-mm", 15, "--out", data)
    out = tmp_path / "cli.json"
    cli("fit", "--data", data, "--model", model, "--method", "lm", "--budget", 100,
        "--sequence-shape", "joint", "--marker-placement", "solve", "--seed", 3, "--out", out)
    theirs = json.loads(out.read_text())
    assert len(theirs["summary"]["shape_pass"]["marker_offsets"]) == 39
    ours = lfit.fit(makehuman, data, method="lm", budget=100, sequence_shape="joint",
                    marker_placement="solve", seed=3)
    np.testing.assert_array_equal(ours.poses, [r["pose"] for r in theirs["frames"]])
    assert ours.summary["shape_pass"]["marker_offsets"] == theirs["summary"]["shape_pass"]["marker_offsets"]
    on_model = lfit.fit(makehuman, data, method="lm", budget=100, sequence_shape="joint", seed=3)
    assert not np.array_equal(on_model.poses, ours.poses), "the placement changed the fits"
    with pytest.raises(lfit.LfitError, match="unknown marker placement 'nearby'"):
        lfit.fit(makehuman, data, method="lm", budget=20, sequence_shape="joint", marker_placement="nearby")
    with pytest.raises(lfit.LfitError, match="runs in the β pass of --sequence-shape joint"):
        lfit.fit(makehuman, data, method="lm", budget=20, marker_placement="solve")
    # offsets=: the solve's placement reused per frame, as `lfit fit --offsets` does.
    reused = tmp_path / "reused.json"
    cli("fit", "--data", data, "--model", model, "--method", "lm", "--budget", 100,
        "--offsets", out, "--seed", 3, "--out", reused)
    theirs = json.loads(reused.read_text())
    ours = lfit.fit(makehuman, data, method="lm", budget=100, offsets=out, seed=3)
    np.testing.assert_array_equal(ours.poses, [r["pose"] for r in theirs["frames"]])
    plain = lfit.fit(makehuman, data, method="lm", budget=100, seed=3)
    assert ours.summary["mean_energy"] < plain.summary["mean_energy"]
    bad = tmp_path / "bad.json"
    bad.write_text("[[0, 0, 0]]")
    with pytest.raises(lfit.LfitError, match="--offsets: .*marker offsets"):
        lfit.fit(makehuman, data, method="lm", budget=20, offsets=bad)


def test_calibrate_equals_the_cli_on_slipped_markers(makehuman, cli, tmp_path):
    """calibrate(): a marker set's placement at the sequence's true poses, the CLI's document;
    it explains the slipped markers and serves fit(offsets=); refused with the CLI's line."""
    model = ROOT / "models" / "makehuman-cmu_mb.npz"
    data = tmp_path / "slip.npz"
    cli("synth", "--modality", "markers", "--scenario", "sequence", "--model", model,
        "--frames", 6, "--seed", 14, "--noise", 0, "--marker-slip-mm", 15, "--out", data)
    theirs_path = tmp_path / "cli-cal.json"
    cli("calibrate", "--data", data, "--model", model, "--out", theirs_path)
    theirs = json.loads(theirs_path.read_text())
    ours_path = tmp_path / "py-cal.json"
    ours = lfit.calibrate(makehuman, data, out=ours_path)
    assert ours["marker_offsets"] == theirs["marker_offsets"] and len(ours["marker_offsets"]) == 39
    assert json.loads(ours_path.read_text())["marker_offsets"] == theirs["marker_offsets"]
    cal = ours["calibration"]
    assert cal["poses"] == "ground truth" and cal["frames"] == 6 and cal["prior_mm"] == 20.0
    assert cal["data_term_after"] < 0.05 * cal["data_term_before"], cal
    placed = lfit.fit(makehuman, data, method="lm", budget=100, offsets=ours_path, seed=3)
    plain = lfit.fit(makehuman, data, method="lm", budget=100, seed=3)
    assert placed.summary["mean_energy"] < 0.5 * plain.summary["mean_energy"]
    with pytest.raises(lfit.LfitError, match="--prior-mm"):
        lfit.calibrate(makehuman, data, prior_mm=0.0, out=tmp_path / "never.json")
    hmd = lfit.synth("hmd", makehuman, frames=2, seed=1)
    with pytest.raises(lfit.LfitError, match="markers or 2D keypoints"):
        lfit.calibrate(makehuman, hmd, out=tmp_path / "never.json")
    assert not (tmp_path / "never.json").exists()
