"""synth, load_dataset and the imports (C3D, COCO keypoints, BVH): the same data as the CLI
commands they mirror; bad input is a one-line error and writes nothing."""

import _thread
import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import lfit
from conftest import ROOT, one_line, require

MH = ROOT / "models" / "makehuman-cmu_mb.npz"


def same_dataset(a, b):
    assert len(a) == len(b) and a.modality == b.modality and a.scenario == b.scenario
    np.testing.assert_array_equal(a.start_params, b.start_params)
    np.testing.assert_array_equal(a.gt_params, b.gt_params)
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.visibility, b.visibility)
    assert a.sensor == b.sensor


@pytest.mark.parametrize("modality", ["markers", "keypoints2d", "hmd"])
def test_synth_equals_the_cli_byte_for_byte(cli, tmp_path, modality):
    cli_out = tmp_path / "cli.npz"
    cli("synth", "--modality", modality, "--model", MH, "--frames", 7, "--seed", 4, "--scenario", "sequence", "--out", cli_out)
    py_out = tmp_path / "py.npz"
    d = lfit.synth(modality, MH, frames=7, seed=4, scenario="sequence", out=py_out)
    assert py_out.read_bytes() == cli_out.read_bytes()
    same_dataset(d, lfit.load_dataset(cli_out))
    assert d.path == py_out and d.summary["frames"] == 7
    assert d.gt_params.shape == (7, 112) and d.fps == 30.0 and d.model_id == "makehuman-cmu_mb"


def test_synth_new_library_kinds_and_uniform_share_equal_the_cli(cli, tmp_path):
    kinds = "lie,crawl,fall,stairs,spin,circle,flight"
    cli_out = tmp_path / "cli.npz"
    cli("synth", "--modality", "markers", "--model", MH, "--frames", 40, "--seed", 3, "--library-motions", kinds, "--uniform-share", 0.25, "--out", cli_out)
    py_out = tmp_path / "py.npz"
    d = lfit.synth("markers", MH, frames=40, seed=3, library_motions=kinds.split(","), uniform_share=0.25, out=py_out)
    assert py_out.read_bytes() == cli_out.read_bytes()
    names = d.meta["frame_motions"]
    assert set(names) <= set(kinds.split(",")) | {"uniform"} and "uniform" in names
    assert d.summary["frames_uniform"] == names.count("uniform")
    for bad in (1.5, -0.1):
        with pytest.raises(lfit.LfitError, match="uniform_share"):
            lfit.synth("markers", MH, frames=3, uniform_share=bad, out=tmp_path / "bad.npz")
    with pytest.raises(lfit.LfitError, match="uniform_share"):
        lfit.synth("markers", MH, frames=3, scenario="sequence", uniform_share=0.2, out=tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()


def noise_free_synth_as_the_cli(cli, tmp_path, name, modality, frames, flags, **kwargs):
    """lfit.synth(modality, frames=frames, seed=8, noise=0, **kwargs), asserting its file equals
    `lfit synth` with the same settings and `flags`, byte for byte."""
    cli_out, py_out = tmp_path / f"{name}-cli.npz", tmp_path / f"{name}-py.npz"
    cli("synth", "--modality", modality, "--model", MH, "--frames", frames, "--seed", 8, "--noise", 0, *flags, "--out", cli_out)
    d = lfit.synth(modality, MH, frames=frames, seed=8, noise=0.0, out=py_out, **kwargs)
    assert py_out.read_bytes() == cli_out.read_bytes()
    return d


def test_synth_marker_slip_equals_the_cli_and_moves_only_the_observations(cli, tmp_path):
    d = noise_free_synth_as_the_cli(cli, tmp_path, "slip", "markers", 6, ("--marker-slip-mm", 15), marker_slip_mm=15.0)
    assert d.summary["marker_slip_mm"] == 15.0 and d.meta["config"]["marker_slip"] == 0.015
    plain = lfit.synth("markers", MH, frames=6, seed=8, noise=0.0)
    # The same poses and the model's marker set; markers observed off their vertices by centimetres.
    np.testing.assert_array_equal(d.gt_params, plain.gt_params)
    assert d.sensor == plain.sensor
    moved = np.linalg.norm((d.observations - plain.observations).reshape(6, -1, 3), axis=2)
    assert 0.005 < moved.mean() < 0.05 and (moved == 0).any()
    for bad, why in ((150.0, "marker_slip"), (-1.0, "marker_slip")):
        with pytest.raises(lfit.LfitError, match=why):
            lfit.synth("markers", MH, frames=3, marker_slip_mm=bad, out=tmp_path / "bad.npz")
    with pytest.raises(lfit.LfitError, match="marker_slip.*hmd"):
        lfit.synth("hmd", MH, frames=3, marker_slip_mm=10.0, out=tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()


def test_synth_camera_file_equals_the_cli(cli, tmp_path):
    rig = ROOT / "configs" / "rigs" / "tripods-2.json"
    d = noise_free_synth_as_the_cli(cli, tmp_path, "rig", "keypoints2d", 4, ("--camera", rig), camera_file=rig)
    cams = json.loads(rig.read_text())["cameras"]
    assert len(d.sensor["cameras"]) == 2
    for got, want in zip(d.sensor["cameras"], cams):
        assert got["fx"] == want["fx"] and got["width"] == want["width"]
    assert d.observations.shape == (4, 2 * 2 * 31)
    with pytest.raises(lfit.LfitError, match="not both"):
        lfit.synth("keypoints2d", MH, frames=3, cameras=2, camera_file=rig, out=tmp_path / "bad.npz")
    with pytest.raises(lfit.LfitError, match="missing.json"):
        lfit.synth("keypoints2d", MH, frames=3, camera_file=tmp_path / "missing.json", out=tmp_path / "bad.npz")
    with pytest.raises(lfit.LfitError, match="keypoints2d rig"):
        lfit.synth("markers", MH, frames=3, camera_file=rig, out=tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()


def test_synth_noise_spread_equals_the_cli_and_quiets_some_subjects(cli, tmp_path):
    cli_out, py_out = tmp_path / "spread-cli.npz", tmp_path / "spread-py.npz"
    cli("synth", "--modality", "markers", "--model", MH, "--frames", 30, "--seed", 8, "--noise-spread", 0.8, "--out", cli_out)
    d = lfit.synth("markers", MH, frames=30, seed=8, noise_spread=0.8, out=py_out)
    assert py_out.read_bytes() == cli_out.read_bytes()
    assert d.summary["noise_spread"] == 0.8 and d.meta["config"]["noise_spread"] == 0.8
    full = lfit.synth("markers", MH, frames=30, seed=8)
    assert "noise_spread" not in full.meta["config"] and "noise_spread" not in full.summary
    clean = lfit.synth("markers", MH, frames=30, seed=8, noise=0.0)
    # The same poses; per frame the median marker deviation is the full noise's or below it.
    np.testing.assert_array_equal(d.gt_params, full.gt_params)
    def median_dev(x):
        dev = np.abs(x.observations - clean.observations)
        return np.array([np.median(r[r > 0]) for r in dev])
    spread, alone = median_dev(d), median_dev(full)
    assert (spread < 0.5 * np.median(alone)).sum() >= 5, spread / np.median(alone)
    assert np.median(spread) < np.median(alone)
    for bad in (1.5, -0.1):
        with pytest.raises(lfit.LfitError, match="noise_spread"):
            lfit.synth("markers", MH, frames=3, noise_spread=bad, out=tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()


def test_synth_keypoint_bias_equals_the_cli_and_moves_only_the_observations(cli, tmp_path):
    d = noise_free_synth_as_the_cli(cli, tmp_path, "bias", "keypoints2d", 5, ("--keypoint-bias-mm", 30), keypoint_bias_mm=30.0)
    assert d.summary["keypoint_bias_mm"] == 30.0 and d.meta["config"]["keypoint_bias"] == 0.03
    plain = lfit.synth("keypoints2d", MH, frames=5, seed=8, noise=0.0)
    # The same poses and cameras, the keypoints seen pixels off the joint centres.
    np.testing.assert_array_equal(d.gt_params, plain.gt_params)
    assert d.sensor == plain.sensor
    seen = np.asarray(d.visibility, dtype=bool) & np.asarray(plain.visibility, dtype=bool)
    moved = np.abs(d.observations - plain.observations)[seen]
    assert 1.0 < moved.mean() < 20.0
    for bad, why in ((150.0, "keypoint_bias"), (-1.0, "keypoint_bias")):
        with pytest.raises(lfit.LfitError, match=why):
            lfit.synth("keypoints2d", MH, frames=3, keypoint_bias_mm=bad, out=tmp_path / "bad.npz")
    with pytest.raises(lfit.LfitError, match="keypoint_bias.*markers"):
        lfit.synth("markers", MH, frames=3, keypoint_bias_mm=10.0, out=tmp_path / "bad.npz")
    # A synthetic detector's offsets (every subject alike): the CLI's dataset, byte for byte.
    det = noise_free_synth_as_the_cli(cli, tmp_path, "det", "keypoints2d", 4, ("--keypoint-bias-mm", 20, "--keypoint-detector", 3), keypoint_bias_mm=20.0, keypoint_detector=3)
    assert det.summary["keypoint_detector"] == 3 and det.meta["config"]["keypoint_detector"] == 3
    with pytest.raises(lfit.LfitError, match="keypoint_detector"):
        lfit.synth("keypoints2d", MH, frames=3, keypoint_detector=3, out=tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()


def test_synth_bad_input_writes_nothing(tmp_path):
    out = tmp_path / "x.npz"
    with pytest.raises(lfit.LfitError) as e:
        lfit.synth("radar", frames=3, out=out)
    assert "radar" in one_line(e) and not out.exists()
    with pytest.raises(lfit.LfitError, match="cannot read .*none.npz"):
        lfit.synth("markers", frames=3, motions=[tmp_path / "none.npz"], out=out)
    assert not out.exists()


def test_ctrl_c_stops_synth(tmp_path, sigint_handled):
    """Synthesis runs on rayon's threads, where Python's signal handlers never run: Ctrl-C must
    still stop it within a frame or two, raise KeyboardInterrupt and write nothing."""
    out = tmp_path / "never.npz"
    # Calibrate: scan frames of the MakeHuman body (a rendered depth scan each).
    t0 = time.perf_counter()
    lfit.synth("scan", MH, frames=4, seed=2)
    per_frame = (time.perf_counter() - t0) / 4
    # Enough frames for ~60 s on two threads; the interrupt lands after 0.5 s.
    frames = max(200, int(120 / per_frame))
    timer = threading.Timer(0.5, _thread.interrupt_main)
    start = time.perf_counter()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        lfit.synth("scan", MH, frames=frames, seed=2, out=out)
    elapsed = time.perf_counter() - start
    timer.cancel()
    assert elapsed < 10, (elapsed, per_frame, frames)
    assert not out.exists()


def test_c3d_import_equals_the_cli(cli, tmp_path):
    synthetic = tmp_path / "m.npz"
    cli("synth", "--modality", "markers", "--model", MH, "--frames", 5, "--seed", 8, "--out", synthetic)
    c3d = tmp_path / "m.c3d"
    cli("data", "export-c3d", "--data", synthetic, "--out", c3d)
    cli_out = tmp_path / "cli.npz"
    cli("data", "import", "--c3d", c3d, "--model", MH, "--out", cli_out)
    d = lfit.import_c3d(c3d, MH)
    same_dataset(d, lfit.load_dataset(cli_out))
    assert not d.has_ground_truth and d.gt_params.shape == (0, 112)
    assert d.summary["import"] is not None
    # Fitting it reports the distance to the markers instead of V2V.
    r = lfit.fit(MH, d, method="lm", budget=60, frames="0..2")
    assert r.observation_unit == "mm" and np.isfinite(r.observation_error).all()
    assert np.isnan(r.v2v_mm).all() and np.isnan(r.pa_mpjpe_mm).all()


def test_trc_import_equals_the_cli_and_the_c3d(cli, tmp_path):
    """The markers of a C3D written again as an OpenSim TRC file import to the C3D's dataset."""
    synthetic = tmp_path / "m.npz"
    cli("synth", "--modality", "markers", "--model", MH, "--frames", 4, "--seed", 9, "--out", synthetic)
    c3d = tmp_path / "m.c3d"
    cli("data", "export-c3d", "--data", synthetic, "--out", c3d)
    from_c3d = lfit.import_c3d(c3d, MH)
    names = [m["name"] for m in lfit.Model.load(str(MH)).info()["markers"]]
    obs = np.asarray(from_c3d.observations).reshape(len(from_c3d), len(names), 3)
    seen = np.asarray(from_c3d.visibility).reshape(len(from_c3d), len(names), 3)[..., 0]
    rows = ["PathFileType\t4\t(X/Y/Z)\tm.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"30\t30\t{len(obs)}\t{len(names)}\tm\t30\t1\t{len(obs)}",
            "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names),
            "\t\t" + "\t".join(f"X{k}\tY{k}\tZ{k}" for k in range(1, len(names) + 1)), ""]
    for f, frame in enumerate(obs):
        cells = ["\t".join(repr(float(v)) for v in p) if seen[f, k] else "\t\t" for k, p in enumerate(frame)]
        rows.append(f"{f + 1}\t{f / 30}\t" + "\t".join(cells))
    trc = tmp_path / "m.trc"
    trc.write_text("\n".join(rows) + "\n")
    cli_out = tmp_path / "cli.npz"
    cli("data", "import", "--trc", trc, "--model", MH, "--out", cli_out)
    d = lfit.import_trc(trc, MH)
    same_dataset(d, lfit.load_dataset(cli_out))
    np.testing.assert_array_equal(d.observations, from_c3d.observations)
    np.testing.assert_array_equal(d.visibility, from_c3d.visibility)
    assert d.summary["import"]["format"] == "trc"
    with pytest.raises(lfit.LfitError, match="not a TRC file"):
        lfit.import_trc(c3d, MH)


def test_c3d_import_errors(cli, tmp_path):
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x02\x50" + b"\x00" * 100)
    out = tmp_path / "o.npz"
    with pytest.raises(lfit.LfitError) as e:
        lfit.import_c3d(bad, out=out)
    p = cli("data", "import", "--c3d", bad, "--out", out, check=False)
    assert p.stderr.strip() == f"error: {one_line(e)}"
    assert not out.exists()


CAMERA = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480,
          "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [0.0, -1.0, 4.0]}


def one_camera_coco(tmp_path):
    """One camera (`CAMERA`) and four frames of COCO-17 keypoints at random in its image."""
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps({"cameras": [CAMERA]}))
    rng = np.random.default_rng(1)
    images = [{"id": i, "width": 640, "height": 480, "file_name": f"{i}.png"} for i in range(4)]
    annotations = []
    for i in range(4):
        kp = np.zeros((17, 3))
        kp[:, 0] = rng.uniform(250, 390, 17)
        kp[:, 1] = rng.uniform(100, 400, 17)
        kp[:, 2] = 2
        annotations.append({"id": i + 1, "image_id": i, "category_id": 1, "keypoints": kp.ravel().tolist()})
    coco = tmp_path / "cam0.json"
    coco.write_text(json.dumps({"images": images, "annotations": annotations, "categories": [{"id": 1}]}))
    return cams, coco


def test_keypoint_import_equals_the_cli(cli, tmp_path):
    cam = CAMERA
    cams, coco = one_camera_coco(tmp_path)
    cli_out = tmp_path / "cli.npz"
    cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams, "--model", MH, "--out", cli_out)
    d = lfit.import_keypoints([coco], "coco17", cams, MH)
    same_dataset(d, lfit.load_dataset(cli_out))
    assert d.modality == "keypoints2d" and len(d) == 4
    with pytest.raises(lfit.LfitError, match="unknown keypoint layout .coco19."):
        lfit.import_keypoints([coco], "coco19", cams, MH)
    # The keypoints as fractions of the image (MediaPipe's normalised landmarks), read with
    # `keypoint_scale="image"`: the CLI's dataset, the pixel import's keypoints.
    norm = json.loads(coco.read_text())
    for a in norm["annotations"]:
        k = np.asarray(a["keypoints"]).reshape(-1, 3)
        k[:, 0] /= 640.0
        k[:, 1] /= 480.0
        a["keypoints"] = k.ravel().tolist()
    coco_n = tmp_path / "cam0-normalised.json"
    coco_n.write_text(json.dumps(norm))
    cli_n = tmp_path / "cli-n.npz"
    cli("data", "import", "--keypoints", coco_n, "--layout", "coco17", "--camera", cams, "--model", MH,
        "--keypoint-scale", "image", "--out", cli_n)
    n = lfit.import_keypoints([coco_n], "coco17", cams, MH, keypoint_scale="image")
    same_dataset(n, lfit.load_dataset(cli_n))
    np.testing.assert_allclose(n.observations, d.observations, atol=1e-9)
    with pytest.raises(lfit.LfitError, match="--keypoint-scale image.openpose3.openpose4"):
        lfit.import_keypoints([coco_n], "coco17", cams, MH)
    # A Z-up camera file (`--up z`): the CLI's dataset, the same keypoints, other cameras.
    cli_z = tmp_path / "cli-z.npz"
    cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams, "--model", MH, "--up", "z", "--out", cli_z)
    z = lfit.import_keypoints([coco], "coco17", cams, MH, up="z")
    same_dataset(z, lfit.load_dataset(cli_z))
    np.testing.assert_array_equal(z.observations, d.observations)
    assert z.sensor != d.sensor
    with pytest.raises(lfit.LfitError, match="unknown up axis 'x'"):
        lfit.import_keypoints([coco], "coco17", cams, MH, up="x")
    # The same axis as a direction is `z` to the bit; a tilted direction is the CLI's too.
    same_dataset(lfit.import_keypoints([coco], "coco17", cams, MH, up="0,0,3"), z)
    cli_t = tmp_path / "cli-t.npz"
    cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams, "--model", MH, "--up", "0.3,0.9,-0.2", "--out", cli_t)
    t = lfit.import_keypoints([coco], "coco17", cams, MH, up="0.3,0.9,-0.2")
    same_dataset(t, lfit.load_dataset(cli_t))
    assert t.sensor != d.sensor and t.sensor != z.sensor
    with pytest.raises(lfit.LfitError, match="not all zero"):
        lfit.import_keypoints([coco], "coco17", cams, MH, up="0,0,0")
    # OpenCV's keys and a lens distortion: the CLI's dataset, the keypoints undistorted.
    ocv = dict(cam)
    for k in ("fx", "fy", "cx", "cy", "width", "height", "rotation", "translation"):
        del ocv[k]
    ocv.update({"K": [[500.0, 0, 320.0], [0, 500.0, 240.0], [0, 0, 1]], "resolution": [640, 480],
                "rvec": [0.0, 0.0, 0.0], "tvec": [[0.0], [-1.0], [4.0]], "dist": [-0.2, 0.05, 0.0, 0.0]})
    cams_l = tmp_path / "cams-lens.json"
    cams_l.write_text(json.dumps({"cameras": [ocv]}))
    cli_l = tmp_path / "cli-l.npz"
    cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams_l, "--model", MH, "--out", cli_l)
    l = lfit.import_keypoints([coco], "coco17", cams_l, MH)
    same_dataset(l, lfit.load_dataset(cli_l))
    assert l.sensor == d.sensor
    seen = np.asarray(d.visibility)
    moved = np.abs(np.asarray(l.observations) - np.asarray(d.observations))[seen]
    assert moved.max() > 1.0
    # The camera among others in an anipose / Pose2Sim calibration.toml in millimetres, chosen
    # by name (`camera_names`, `camera_units`): the CLI's dataset, the first one's cameras.
    toml = ""
    for name, ty in (("side", 2.0), ("front", -1.0)):
        toml += (f'[{name}]\nname = "{name}"\nsize = [ 640.0, 480.0]\n'
                 "matrix = [ [ 500.0, 0.0, 320.0], [ 0.0, 500.0, 240.0], [ 0.0, 0.0, 1.0]]\n"
                 "distortions = [ 0.0, 0.0, 0.0, 0.0]\nrotation = [ 0.0, 0.0, 0.0]\n"
                 f"translation = [ 0.0, {ty * 1000}, 4000.0]\nfisheye = false\n\n")
    cams_t = tmp_path / "calibration.toml"
    cams_t.write_text(toml + "[metadata]\nadjusted = false\nerror = 0.0\n")
    cli_t = tmp_path / "cli-toml.npz"
    cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams_t, "--camera-names", "front",
        "--camera-units", "mm", "--model", MH, "--out", cli_t)
    t = lfit.import_keypoints([coco], "coco17", cams_t, MH, camera_names=["front"], camera_units="mm")
    same_dataset(t, lfit.load_dataset(cli_t))
    np.testing.assert_array_equal(t.observations, d.observations)
    assert t.sensor["cameras"][0]["translation"] == pytest.approx(cam["translation"], abs=1e-12)
    with pytest.raises(lfit.LfitError, match="no camera named 'back' in the camera file \\(its 2 names: side, front\\)"):
        lfit.import_keypoints([coco], "coco17", cams_t, MH, camera_names=["back"])
    # `lfit.read_cameras` is `lfit data cameras`: the same summary, the same file written.
    rig_py, rig_cli = tmp_path / "rig-py.json", tmp_path / "rig-cli.json"
    summary = lfit.read_cameras(cams_t, camera_names=["front", "side"], camera_units="mm", out=rig_py)
    cli_summary = cli("data", "cameras", "--camera", cams_t, "--camera-names", "front,side", "--camera-units", "mm",
                      "--out", rig_cli)
    assert summary["cameras"] == cli_summary["cameras"]
    assert [c["name"] for c in summary["cameras"]] == ["front", "side"]
    assert summary["cameras"][0]["height_m"] == pytest.approx(1.0) and summary["cameras"][1]["height_m"] == pytest.approx(-2.0)
    assert rig_py.read_bytes() == rig_cli.read_bytes()
    with pytest.raises(lfit.LfitError, match="--camera-units inch: expected m, cm or mm"):
        lfit.read_cameras(cams_t, camera_units="inch")


def test_bvh_import_equals_the_cli(cli, tmp_path):
    bvh = os.environ.get("LFIT_MOCAPBANK_BVH")
    if not bvh or not Path(bvh).exists():
        require("LFIT_MOCAPBANK_BVH is not set (scripts/fetch-mocapbank.sh fetches the clip)")
    m = ROOT / "configs" / "maps" / "mocapbank_to_makehuman_cmu_mb.json"
    cli_out = tmp_path / "clip.npz"
    cli("motion", "import", "--bvh", bvh, "--map", m, "--model", MH, "--stride", 5, "--out", cli_out)
    motion = lfit.import_bvh(bvh, MH, map=m, stride=5)
    np.testing.assert_array_equal(motion.params, np.load(cli_out)["poses"])
    assert motion.summary["bone_cosine_mean"] > 0.95 and len(motion) == motion.params.shape[0]
    py_out = tmp_path / "py.npz"
    motion.save(py_out)
    assert py_out.read_bytes() == cli_out.read_bytes()
    # A pose prior from the Motion object is the one from its file (only the names differ).
    from_object, _ = lfit.motion_prior([motion], MH)
    from_file, _ = lfit.motion_prior([py_out], MH)
    for key in ("mean", "whitening"):
        assert from_object["pose_prior"][key] == from_file["pose_prior"][key]
    assert "Motion 0" in from_object["pose_prior"]["source"]
    # The motion drives synthesis as a file does.
    d = lfit.synth("markers", MH, frames=3, seed=1, motions=[py_out])
    assert all(":" in f for f in d.meta["frame_motions"])
    # Augmented frames (mirror, heading, jitter) are the CLI's, byte for byte.
    aug = ["--mirror", "--heading", "--jitter-deg", 4]
    cli_aug = tmp_path / "cli-aug.npz"
    cli("synth", "--modality", "markers", "--model", MH, "--frames", 6, "--seed", 2, "--motions", py_out, *aug, "--out", cli_aug)
    py_aug = tmp_path / "py-aug.npz"
    a = lfit.synth("markers", MH, frames=6, seed=2, motions=[py_out], mirror=True, heading=True, jitter_deg=4.0, out=py_aug)
    assert py_aug.read_bytes() == cli_aug.read_bytes()
    assert not np.array_equal(a.gt_params, lfit.synth("markers", MH, frames=6, seed=2, motions=[py_out]).gt_params)
    with pytest.raises(lfit.LfitError, match="jitter_deg"):
        lfit.synth("markers", MH, frames=3, motions=[py_out], jitter_deg=60.0)


def test_missing_dataset_is_one_line(tmp_path):
    with pytest.raises(lfit.LfitError) as e:
        lfit.load_dataset(tmp_path / "none.npz")
    assert one_line(e).startswith(f"dataset {tmp_path / 'none.npz'}")


def test_a_panoptic_reference_scores_the_fit_as_the_cli_does(cli, tmp_path):
    """`reference=`: Panoptic 3D skeleton files imported with the keypoints; `fit` scores each
    frame against them, the CLI's figures to the bit."""
    cams, coco = one_camera_coco(tmp_path)
    folder = tmp_path / "hdPose3d_stage1_coco19"
    folder.mkdir()
    rng = np.random.default_rng(2)
    for f in range(4):
        joints = np.concatenate([rng.uniform(-20, 20, (19, 3)) + [0, 90, 0], np.full((19, 1), 0.6)], axis=1)
        bodies = [{"id": 2, "joints19": joints.ravel().tolist()}]
        if f == 3:
            bodies.append({"id": 5, "joints19": joints.ravel().tolist()})
        (folder / f"body3DScene_{f:08d}.json").write_text(json.dumps({"version": 0.7, "bodies": bodies}))
    cli_out = tmp_path / "cli.npz"
    summary = cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams,
                  "--model", MH, "--reference", folder, "--reference-person", 2, "--out", cli_out)
    d = lfit.import_keypoints([coco], "coco17", cams, MH, reference=[folder], reference_person=2)
    same_dataset(d, lfit.load_dataset(cli_out))
    # The reference as arrays: the file's BodyCenter (body 2, frame 0) is the root's, in metres.
    loaded = lfit.load_dataset(cli_out)
    np.testing.assert_array_equal(d.reference_joints, loaded.reference_joints)
    np.testing.assert_array_equal(d.reference_visible, loaded.reference_visible)
    frame0 = json.loads((folder / "body3DScene_00000000.json").read_text())["bodies"][0]["joints19"]
    np.testing.assert_allclose(d.reference_joints[0, 0], np.asarray(frame0[8:11]) / 100.0, rtol=0, atol=1e-12)
    assert d.reference_visible.shape == d.reference_joints.shape[:2] and d.reference_visible[:, 0].all()
    assert d.summary["import"]["reference"] == summary["import"]["reference"]
    assert summary["import"]["reference"]["person"] == 2
    out = tmp_path / "fit.json"
    cli("fit", "--data", cli_out, "--model", MH, "--method", "lm", "--budget", 40, "--out", out)
    theirs = json.loads(out.read_text())
    ours = lfit.fit(MH, d, method="lm", budget=40)
    rows = theirs["frames"]
    np.testing.assert_array_equal(ours.reference_mpjpe_mm, [r["reference_mpjpe_mm"] for r in rows])
    np.testing.assert_array_equal(ours.reference_pa_mpjpe_mm, [r["reference_pa_mpjpe_mm"] for r in rows])
    assert np.isfinite(ours.reference_mpjpe_mm).all() and (ours.reference_mpjpe_mm > 0).all()
    assert ours.summary["mean_reference_mpjpe_mm"] == theirs["summary"]["mean_reference_mpjpe_mm"]
    assert ours.summary["reference_frames"] == 4
    # Without a reference: NaN.
    no_reference = lfit.import_keypoints([coco], "coco17", cams, MH)
    assert no_reference.reference_joints is None and no_reference.reference_visible is None
    plain = lfit.fit(MH, no_reference, method="lm", budget=10)
    assert np.isnan(plain.reference_mpjpe_mm).all()
    # Two bodies in a frame and no person chosen; a person without a reference: one line each.
    bad = tmp_path / "bad.npz"
    with pytest.raises(lfit.LfitError) as e:
        lfit.import_keypoints([coco], "coco17", cams, MH, reference=[folder], out=bad)
    p = cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams, "--model", MH,
            "--reference", folder, "--out", bad, check=False)
    assert p.stderr.strip() == f"error: {one_line(e)}" and "--reference-person" in p.stderr
    assert not bad.exists()
    with pytest.raises(lfit.LfitError, match="--reference-person chooses a body"):
        lfit.import_keypoints([coco], "coco17", cams, MH, reference_person=2)
    # A TRC of 3D keypoints under OpenPose's names (`reference_layout="body25"`), millimetres.
    names = ["MidHip", "RHip", "RKnee", "LShoulder"]
    rows = ["PathFileType\t4\t(X/Y/Z)\tk.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"30\t30\t4\t{len(names)}\tmm\t30\t1\t4",
            "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names),
            "\t\t" + "\t".join(f"X{k}\tY{k}\tZ{k}" for k in range(1, len(names) + 1)), ""]
    for f in range(4):
        rows.append(f"{f + 1}\t{f / 30}\t" + "\t".join(f"{10 * k}\t{900 + f}\t{-5 * k}" for k in range(len(names))))
    trc = tmp_path / "k.trc"
    trc.write_text("\n".join(rows) + "\n")
    cli_t = tmp_path / "cli-t.npz"
    summary = cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams, "--model", MH,
                  "--reference", trc, "--reference-layout", "body25", "--out", cli_t)
    t = lfit.import_keypoints([coco], "coco17", cams, MH, reference=[trc], reference_layout="body25")
    assert t.summary["import"]["reference"] == summary["import"]["reference"]
    assert summary["import"]["reference"]["format"] == "trc" and summary["import"]["reference"]["mapped_joints"] == 4
    # Read in the keypoints' own layout (coco17, which has no MidHip): the three limb points.
    assert lfit.import_keypoints([coco], "coco17", cams, MH, reference=[trc]).summary["import"]["reference"]["mapped_joints"] == 3
    # `reference_map`: the file's labels named onto model joints (MidHip onto the hips).
    ref_map = tmp_path / "reference-map.json"
    ref_map.write_text(json.dumps({"Hips": "MidHip", "RightLeg": "RKnee"}))
    cli_m = tmp_path / "cli-m.npz"
    summary = cli("data", "import", "--keypoints", coco, "--layout", "coco17", "--camera", cams, "--model", MH,
                  "--reference", trc, "--reference-map", ref_map, "--out", cli_m)
    m = lfit.import_keypoints([coco], "coco17", cams, MH, reference=[trc], reference_map=ref_map)
    assert m.summary["import"]["reference"] == summary["import"]["reference"]
    assert summary["import"]["reference"]["mapped_joints"] == 2
    np.testing.assert_array_equal(m.reference_joints, lfit.load_dataset(cli_m).reference_joints)
    np.testing.assert_allclose(m.reference_joints[2, 0], [0.0, 0.902, 0.0], rtol=0, atol=1e-12)
