"""lfit.Energy: residuals, Jacobian and gradient agree with each other and with finite
differences, and scipy.optimize.least_squares on them reaches lfit's Levenberg–Marquardt
energies (this replaces tests/lm_vs_scipy.rs, which drove `lfit objective-server` through
JSON lines)."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import lfit
from conftest import ROOT, one_line, scipy_optimize

FRAMES = 50
# Final energies both below this are equal (typical final energies are 0.05-1).
ZERO = 1e-9


@pytest.fixture(scope="module")
def markers(makehuman):
    return lfit.synth("markers", makehuman, frames=4, seed=3)


def test_residuals_jacobian_gradient_agree(makehuman, markers):
    e = lfit.Energy(makehuman, markers, 1)
    x = e.x0 + 0.01
    r, j = e.residuals_and_jacobian(x)
    assert r.shape == (e.residual_count,) and j.shape == (e.residual_count, e.dim)
    np.testing.assert_array_equal(r, e.residuals(x))
    np.testing.assert_array_equal(j, e.jacobian(x))
    value, grad = e.value_and_grad(x)
    assert value == pytest.approx(float(r @ r), rel=1e-10)
    assert value == pytest.approx(e.value(x), rel=1e-12)
    np.testing.assert_allclose(grad, 2 * j.T @ r, rtol=1e-6, atol=1e-8)
    # Central differences of the residuals, column by column.
    h = 1e-6
    fd = np.stack([(e.residuals(x + h * np.eye(e.dim)[k]) - e.residuals(x - h * np.eye(e.dim)[k])) / (2 * h) for k in range(e.dim)], axis=1)
    np.testing.assert_allclose(j, fd, rtol=1e-4, atol=1e-5)
    # Batched values equal single ones.
    xs = np.stack([e.x0, x])
    np.testing.assert_array_equal(e.value(xs), [e.value(e.x0), e.value(x)])
    assert e.full(x).shape == (makehuman.dim,) and len(e.names) == e.dim == len(e.free)
    assert "total" in e.terms(x)


def test_a_height_prior_is_one_more_row(makehuman, markers):
    """height_prior=: the `lfit fit --height-prior` row, ((h(β) − M)/STD)² over the visible
    markers' count, in the value, the residuals and the Jacobian; bad forms refused."""
    plain = lfit.Energy(makehuman, markers, 1)
    e = lfit.Energy(makehuman, markers, 1, height_prior=(1.85, 0.02))
    x = e.x0 + 0.01
    assert e.residual_count == plain.residual_count + 1
    seen = int(np.asarray(markers.visibility[1]).reshape(-1, 3)[:, 0].sum())
    start, end = makehuman.layout["blocks"]["shape"]
    h = makehuman.rest_height(e.full(x)[start:end])
    want = ((h - 1.85) / 0.02) ** 2 / seen
    assert e.terms(x)["height"] == pytest.approx(want, rel=1e-9)
    assert e.value(x) == pytest.approx(plain.value(x) + want, rel=1e-9)
    r, j = e.residuals_and_jacobian(x)
    value, grad = e.value_and_grad(x)
    np.testing.assert_allclose(grad, 2 * j.T @ r, rtol=1e-6, atol=1e-8)
    h6 = 1e-6
    fd = np.stack([(e.residuals(x + h6 * np.eye(e.dim)[k]) - e.residuals(x - h6 * np.eye(e.dim)[k])) / (2 * h6) for k in range(e.dim)], axis=1)
    np.testing.assert_allclose(j, fd, rtol=1e-4, atol=1e-5)
    # Each frame's true height ("truth"): the frame's ground-truth β's rest height.
    t = lfit.Energy(makehuman, markers, 1, height_prior="truth")
    true_h = makehuman.rest_height(np.asarray(markers.gt_params[1])[start:end])
    assert t.terms(x)["height"] == pytest.approx(((h - true_h) / 0.01) ** 2 / seen, rel=1e-9)
    # The same energy from the CLI's forms of the prior.
    for form in ["1.85:0.02", (1.85, 0.02)]:
        assert lfit.Energy(makehuman, markers, 1, height_prior=form).value(x) == e.value(x)
    with pytest.raises(lfit.LfitError, match="--height-prior 'tall'"):
        lfit.Energy(makehuman, markers, 1, height_prior="tall")
    with pytest.raises(lfit.LfitError, match="a height prior needs a model with shape coefficients"):
        rigid = lfit.Model.load("default")
        lfit.Energy(rigid, lfit.synth("markers", rigid, frames=1, seed=1), 0, height_prior=1.7)


def test_a_floor_is_one_more_row(makehuman, markers):
    """floor=: the `lfit fit --floor` row on the lowest sole, in the value and the Jacobian;
    a floor under every sole adds nothing (`above`), one over it pulls (`contact`); `truth` is
    the frame's own lowest true sole; bad forms refused."""
    plain = lfit.Energy(makehuman, markers, 1)
    x = plain.x0 + 0.01
    under = lfit.Energy(makehuman, markers, 1, floor="above:-5")
    assert under.residual_count == plain.residual_count + 1
    assert under.terms(x)["floor"] == 0.0 and under.value(x) == plain.value(x)
    e = lfit.Energy(makehuman, markers, 1, floor="contact:0.5,10")
    assert e.terms(x)["floor"] > 0.0
    assert e.value(x) == pytest.approx(plain.value(x) + e.terms(x)["floor"], rel=1e-12)
    r, j = e.residuals_and_jacobian(x)
    value, grad = e.value_and_grad(x)
    np.testing.assert_allclose(grad, 2 * j.T @ r, rtol=1e-6, atol=1e-8)
    # At the truth the floor at its own lowest sole adds nothing.
    truth = np.asarray(markers.gt_params[1])
    t = lfit.Energy(makehuman, markers, 1, start=truth, floor="contact:truth")
    np.testing.assert_array_equal(t.full(t.x0), truth)
    assert t.terms(t.x0)["floor"] == pytest.approx(0.0, abs=1e-20)
    assert lfit.Energy(makehuman, markers, 1, start=truth, floor="contact:0").terms(t.x0)["floor"] > 0.0
    with pytest.raises(lfit.LfitError, match="--floor 'low'"):
        lfit.Energy(makehuman, markers, 1, floor="low")


def test_observations_and_sensor_give_the_dataset_frames_energy(makehuman, markers):
    frame = 2
    from_data = lfit.Energy(makehuman, markers, frame)
    from_obs = lfit.Energy(
        makehuman,
        observations=markers.observations[frame],
        visible=markers.visibility[frame],
        sensor=markers.sensor,
        scenario=markers.scenario,
        start=markers.start_params[frame],
    )
    x = from_data.x0 + 0.02
    assert from_obs.dim == from_data.dim
    np.testing.assert_array_equal(from_obs.residuals(x), from_data.residuals(x))
    np.testing.assert_array_equal(from_obs.lower, from_data.lower)


@pytest.mark.parametrize(
    "x, needle",
    [
        (np.zeros(3), "x has 3 numbers, expected"),
        (np.zeros((2, 2, 2)), "x has shape (2, 2, 2)"),
        ("abc", "x has dtype <U3"),
        ([1.0, None], "x has dtype object"),
    ],
)
def test_bad_points(makehuman, markers, x, needle):
    e = lfit.Energy(makehuman, markers, 0)
    with pytest.raises(lfit.LfitError) as err:
        e.residuals(x)
    assert needle in one_line(err)


def test_nan_point_and_bad_frame(makehuman, markers):
    e = lfit.Energy(makehuman, markers, 0)
    x = e.x0.copy()
    x[4] = np.nan
    with pytest.raises(lfit.LfitError, match=r"x\[4\] is not a finite number \(NaN\)"):
        e.jacobian(x)
    with pytest.raises(lfit.LfitError, match="frame 9 is out of range: the dataset has 4 frames"):
        lfit.Energy(makehuman, markers, 9)
    with pytest.raises(lfit.LfitError, match="dataset was made with template 'makehuman-cmu_mb'"):
        lfit.Energy(lfit.Model.load("default"), markers, 0)
    with pytest.raises(lfit.LfitError, match="visible target value 0 is not finite"):
        lfit.Energy(makehuman, observations=np.full(117, np.nan), sensor="markers")


def fit_with_scipy(least_squares, e):
    x0 = np.clip(e.x0, e.lower, e.upper)
    res = least_squares(e.residuals, x0, jac=e.jacobian, bounds=(e.lower, e.upper), method="trf")
    return e.value(np.clip(res.x, e.lower, e.upper))


CASES = {
    "markers": ({}, {}),
    "keypoints2d": ({}, {}),
    "hmd": ({}, {}),
    "landmarks2d": (
        {"model": "makehuman-face", "source": "face", "scenario": "global"},
        {"energy": str(ROOT / "configs" / "face-energy.json")},
    ),
}


@pytest.mark.parametrize("modality", list(CASES))
def test_scipy_least_squares_reaches_lfit_lm_energies(modality):
    """lfit's LM ends at most 1 % above scipy's trf on every one of 50 frames (the documented
    50/50; measured worst ratios 1.0000-1.0026); and we report on how many frames scipy ends
    within 1 % of lfit's energy."""
    least_squares = scipy_optimize().least_squares
    synth_extra, fit_extra = CASES[modality]
    model = synth_extra.get("model")
    synth_kwargs = {k: v for k, v in synth_extra.items() if k != "model"}
    data = lfit.synth(modality, model, frames=FRAMES, seed=41, **synth_kwargs)
    ours = lfit.fit(model, data, method="lm", budget=500, **fit_extra)
    assert len(ours) == FRAMES
    config = fit_extra.get("energy")
    # Energy calls release the GIL: frames in parallel, as the objective-server driver did.
    with ThreadPoolExecutor(max_workers=4) as pool:
        theirs = list(pool.map(lambda f: fit_with_scipy(least_squares, lfit.Energy(model, data, int(f), config=config)), ours.frames))
    within_lm, within_scipy, worst = 0, 0, 0.0
    for frame, e_lm, e_scipy in zip(ours.frames, ours.energies, theirs):
        assert np.isfinite(e_lm) and np.isfinite(e_scipy) and e_scipy >= 0
        ratio = 1.0 if max(e_lm, e_scipy) < ZERO else e_lm / e_scipy
        worst = max(worst, ratio)
        within_lm += ratio <= 1.01
        within_scipy += 1.0 / 1.01 <= ratio <= 1.01
        assert ratio <= 1.01, f"{modality} frame {frame}: lfit LM {e_lm} vs scipy {e_scipy}"
    print(
        f"{modality}: lfit LM ≤ 1.01× scipy on {within_lm}/{FRAMES} frames (worst {worst:.4f}); "
        f"scipy within 1 % of lfit on {within_scipy}/{FRAMES}"
    )
    assert within_lm == FRAMES, f"{modality}: only {within_lm}/{FRAMES} frames within 1 % (worst {worst:.4f})"
