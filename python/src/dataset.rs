//! `lfit.Dataset` (frames of observations with their start poses and, for synthetic data, the
//! ground truth) and `lfit.Motion` (an imported motion), with the functions that make them:
//! `load_dataset`, `synth`, `import_c3d`, `import_trc`, `import_keypoints`, `import_bvh`.

use std::path::PathBuf;
use std::sync::Arc;

use lfit::synth::{Dataset as Data, Observations};
use numpy::PyArrayMethods;
use pyo3::prelude::*;

use crate::convert::{OrPy, array_nd, bad, cancellable, json_to_py, without_gil};
use crate::model::optional_model;

/// Frames of observations of one modality, their start poses and (synthetic data) the ground
/// truth, as `lfit synth` and `lfit data import` write them.
#[pyclass(module = "lfit", name = "Dataset", frozen)]
pub struct Dataset {
    pub inner: Arc<Data>,
    /// The file it was read from or written to, if any (recorded in fit results).
    pub path: Option<PathBuf>,
    /// What the command that made it reported (synthesis or import), if it was made here.
    pub summary: Option<serde_json::Value>,
}

/// A dataset argument: a `Dataset`, or the path of one.
pub fn dataset_arg(obj: &Bound<'_, PyAny>) -> PyResult<(Arc<Data>, Option<PathBuf>)> {
    if let Ok(d) = obj.cast::<Dataset>() {
        let d = d.get();
        return Ok((d.inner.clone(), d.path.clone()));
    }
    let path: PathBuf = obj
        .extract()
        .map_err(|_| bad("data: expected an lfit.Dataset or the path of a dataset file"))?;
    let d = load(obj.py(), &path)?;
    Ok((Arc::new(d), Some(path)))
}

fn load(py: Python<'_>, path: &PathBuf) -> PyResult<Data> {
    without_gil(py, |_| {
        use anyhow::Context as _;
        Data::load(path).with_context(|| format!("dataset {}", path.display()))
    })
}

fn rows_array<'py>(
    py: Python<'py>,
    rows: &[Vec<f64>],
    width: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    array_nd(py, flat, &[rows.len(), width])
}

fn save(py: Python<'_>, data: &Data, out: &PathBuf) -> PyResult<()> {
    if out.is_dir() {
        return Err(bad(format!(
            "out {} is a directory, expected a file",
            out.display()
        )));
    }
    without_gil(py, |_| Ok(data.save(out)?))
}

#[pymethods]
impl Dataset {
    /// Reads a dataset file (`.npz` of `lfit synth` or `lfit data import`).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let d = load(py, &path)?;
        Ok(Self {
            inner: Arc::new(d),
            path: Some(path),
            summary: None,
        })
    }

    /// Writes the dataset (atomically: a temporary file renamed over `path`).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        save(py, &self.inner, &path)
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// What `synth` or the import reported when the dataset was made here (visible fraction,
    /// the import's report), else None.
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        match &self.summary {
            Some(v) => json_to_py(py, v),
            None => Ok(py.None().into_bound(py)),
        }
    }

    /// `markers`, `keypoints2d`, `hmd`, `scan`, `silhouettes` or `landmarks2d`.
    #[getter]
    fn modality(&self) -> &'static str {
        self.inner.modality().name()
    }

    /// `local`, `global` or `sequence` (the free entries and box of a fit).
    #[getter]
    fn scenario(&self) -> &'static str {
        self.inner.meta.config.scenario.name()
    }

    /// The id of the model the dataset was made for.
    #[getter]
    fn model_id(&self) -> String {
        self.inner.meta.template_id.clone()
    }

    /// Frame rate, Hz.
    #[getter]
    fn fps(&self) -> f64 {
        self.inner.meta.config.fps
    }

    /// The file it was read from or written to, or None.
    #[getter]
    fn path(&self) -> Option<PathBuf> {
        self.path.clone()
    }

    /// Whether the frames have ground-truth parameters (False for imported captures).
    #[getter]
    fn has_ground_truth(&self) -> bool {
        self.inner.has_ground_truth()
    }

    /// Start parameters of every frame, `(N, P)` float64 (pose, then β and ψ).
    #[getter]
    fn start_params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.start_poses, self.inner.meta.param_dim())
    }

    /// Ground-truth parameters, `(N, P)` float64; `(0, P)` without ground truth.
    #[getter]
    fn gt_params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.gt_poses, self.inner.meta.param_dim())
    }

    /// Observations of a sparse modality, `(N, D)` float64 (markers: x, y, z per marker in
    /// metres; keypoints2d: u, v per keypoint and camera in pixels; hmd: the trackers), or of
    /// `scan`, `(N, V, 3)` points. `silhouettes` datasets hold masks: an error.
    #[getter]
    fn observations<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        match &self.inner.observations {
            Observations::Sparse { values, .. } => {
                rows_array(py, values, values.first().map_or(0, Vec::len))
            }
            Observations::Scan { points, .. } => {
                let v = points.first().map_or(0, Vec::len);
                let flat: Vec<f64> = points
                    .iter()
                    .flatten()
                    .flat_map(|p| [p.x as f64, p.y as f64, p.z as f64])
                    .collect();
                array_nd(py, flat, &[points.len(), v, 3])
            }
            Observations::Silhouettes { .. } => Err(bad(
                "a silhouettes dataset holds foreground masks, not observation vectors (numpy.load the file for its 'silhouettes' array)",
            )),
        }
    }

    /// Visibility of every observation entry (sparse: `(N, D)`; scan: `(N, V)`), bool.
    #[getter]
    fn visibility<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let rows = match &self.inner.observations {
            Observations::Sparse { visible, .. } | Observations::Scan { visible, .. } => visible,
            Observations::Silhouettes { .. } => {
                return Err(bad("a silhouettes dataset has no visibility flags"));
            }
        };
        let width = rows.first().map_or(0, Vec::len);
        let flat: Vec<bool> = rows.iter().flatten().copied().collect();
        Ok(numpy::PyArray1::from_vec(py, flat)
            .reshape([rows.len(), width])?
            .into_any())
    }

    /// The captured joint reference (`import_keypoints(reference=...)`): each frame's position
    /// of each model joint, `(N, J, 3)` metres in the dataset's world (0 where not held); None
    /// without one.
    #[getter]
    fn reference_joints<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(r) = &self.inner.reference else {
            return Ok(None);
        };
        let j = r.points.first().map_or(0, Vec::len);
        let flat: Vec<f64> = r.points.iter().flatten().flatten().copied().collect();
        array_nd(py, flat, &[r.points.len(), j, 3]).map(Some)
    }

    /// Which reference joints each frame holds, `(N, J)` bool; None without a reference.
    #[getter]
    fn reference_visible<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(r) = &self.inner.reference else {
            return Ok(None);
        };
        let j = r.visible.first().map_or(0, Vec::len);
        let flat: Vec<bool> = r.visible.iter().flatten().copied().collect();
        Ok(Some(
            numpy::PyArray1::from_vec(py, flat)
                .reshape([r.visible.len(), j])?
                .into_any(),
        ))
    }

    /// The sensor setup (cameras, markers, trackers) as a dict; `lfit.Energy(sensor=...)` takes
    /// it back.
    #[getter]
    fn sensor<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = serde_json::to_value(&self.inner.sensor).map_err(|e| bad(e.to_string()))?;
        json_to_py(py, &v)
    }

    /// The metadata (`meta` of the file): model id, generator settings, seed, frame motions.
    #[getter]
    fn meta<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = serde_json::to_value(&self.inner.meta).map_err(|e| bad(e.to_string()))?;
        json_to_py(py, &v)
    }

    fn __repr__(&self) -> String {
        format!(
            "Dataset({} frames, {}, {}, model '{}'{})",
            self.inner.len(),
            self.inner.modality().name(),
            self.inner.meta.config.scenario.name(),
            self.inner.meta.template_id,
            if self.inner.has_ground_truth() {
                ""
            } else {
                ", no ground truth"
            }
        )
    }
}

/// Reads a dataset file; the same as `Dataset.load`.
#[pyfunction]
pub fn load_dataset(py: Python<'_>, path: PathBuf) -> PyResult<Dataset> {
    Dataset::load(py, path)
}

fn finish(
    py: Python<'_>,
    data: Data,
    summary: serde_json::Value,
    out: Option<PathBuf>,
) -> PyResult<Dataset> {
    if let Some(out) = &out {
        save(py, &data, out)?;
    }
    Ok(Dataset {
        inner: Arc::new(data),
        path: out,
        summary: Some(summary),
    })
}

fn model_or_default(
    model: Option<&Bound<'_, PyAny>>,
) -> PyResult<Arc<lfit::model::template::Template>> {
    match optional_model(model)? {
        Some(t) => Ok(t),
        None => Ok(Arc::new(lfit::api::load_model(None, "default").py_err()?)),
    }
}

/// Synthesises a dataset as `lfit synth` does (same settings, same seed → same data); writes it
/// to `out` too when given. Ctrl-C stops it (`KeyboardInterrupt`, nothing written).
#[pyfunction]
#[pyo3(signature = (modality, model=None, *, scenario="local", frames=100, seed=0, source="motion", noise=1.0, noise_spread=0.0, fps=30.0, library_motions=None, motions=None, with_library=false, mirror=false, heading=false, jitter_deg=0.0, uniform_share=0.0, marker_slip_mm=0.0, keypoint_bias_mm=0.0, keypoint_detector=None, cameras=None, camera_file=None, out=None))]
#[allow(clippy::too_many_arguments)]
pub fn synth(
    py: Python<'_>,
    modality: String,
    model: Option<&Bound<'_, PyAny>>,
    scenario: &str,
    frames: usize,
    seed: u64,
    source: &str,
    noise: f64,
    noise_spread: f64,
    fps: f64,
    library_motions: Option<Vec<String>>,
    motions: Option<Vec<PathBuf>>,
    with_library: bool,
    mirror: bool,
    heading: bool,
    jitter_deg: f64,
    uniform_share: f64,
    marker_slip_mm: f64,
    keypoint_bias_mm: f64,
    keypoint_detector: Option<u64>,
    cameras: Option<usize>,
    camera_file: Option<PathBuf>,
    out: Option<PathBuf>,
) -> PyResult<Dataset> {
    let template = model_or_default(model)?;
    let args = lfit::api::SynthArgs {
        modality,
        scenario: scenario.to_string(),
        source: source.to_string(),
        frames,
        seed,
        fps,
        noise,
        noise_spread,
        motions: library_motions.map(|m| m.join(",")),
        marker_slip_mm,
        keypoint_bias_mm,
        keypoint_detector,
        out: out.clone().unwrap_or_default(),
    };
    let files = lfit::api::MotionFilesArgs {
        files: motions.unwrap_or_default(),
        with_library,
        augment: lfit::synth::MotionAugment {
            mirror,
            heading,
            jitter_deg,
        },
        uniform_share,
    };
    let rig = lfit::api::Rig::from_args(cameras, camera_file.as_deref()).py_err()?;
    let (data, summary) = cancellable(py, |cancel| {
        lfit::api::synthesize_dataset(&args, &files, &rig, &template, &|_| {}, cancel)
    })?;
    finish(py, data, summary, out)
}

fn data_import(
    py: Python<'_>,
    args: lfit::api::DataImportArgs,
    model: Option<&Bound<'_, PyAny>>,
    out: Option<PathBuf>,
) -> PyResult<Dataset> {
    let template = optional_model(model)?;
    let (data, summary) = without_gil(py, |_| {
        lfit::api::import_dataset(&args, template.as_deref())
    })?;
    finish(py, data, summary, out)
}

/// `lfit data import`'s arguments for a marker file (`--c3d` or `--trc`).
fn marker_file_args(
    c3d: Option<PathBuf>,
    trc: Option<PathBuf>,
    label_map: Option<PathBuf>,
    up: &str,
    scenario: &str,
    out: &Option<PathBuf>,
) -> lfit::api::DataImportArgs {
    lfit::api::DataImportArgs {
        c3d,
        trc,
        label_map,
        up: up.to_string(),
        keypoints: Vec::new(),
        layout: None,
        camera: None,
        camera_names: Vec::new(),
        camera_units: None,
        keypoint_scale: None,
        keypoint_map: None,
        reference: Vec::new(),
        reference_person: None,
        reference_layout: None,
        reference_map: None,
        min_confidence: 0.1,
        fps: 30.0,
        scenario: scenario.to_string(),
        model: None,
        out: out.clone().unwrap_or_default(),
    }
}

/// Imports 3D markers from a C3D file as `lfit data import --c3d` does: a `markers` dataset
/// without ground truth for `model` (default: the procedural body). `label_map`: a JSON file
/// `{"C3D label": "model marker"}` (a key `"#K"`: the file's point K, counted from 0, for a label
/// the file repeats; default: labels equal to marker names); `up`: `y`, `z` or `"x,y,z"` (the
/// lab's up direction).
#[pyfunction]
#[pyo3(signature = (path, model=None, *, label_map=None, up="y", scenario="sequence", out=None))]
pub fn import_c3d(
    py: Python<'_>,
    path: PathBuf,
    model: Option<&Bound<'_, PyAny>>,
    label_map: Option<PathBuf>,
    up: &str,
    scenario: &str,
    out: Option<PathBuf>,
) -> PyResult<Dataset> {
    let args = marker_file_args(Some(path), None, label_map, up, scenario, &out);
    data_import(py, args, model, out)
}

/// Imports 3D markers from a TRC file (OpenSim's text format: OpenCap's, Motive's, Cortex's) as
/// `lfit data import --trc` does; the arguments as [`import_c3d`]'s.
#[pyfunction]
#[pyo3(signature = (path, model=None, *, label_map=None, up="y", scenario="sequence", out=None))]
pub fn import_trc(
    py: Python<'_>,
    path: PathBuf,
    model: Option<&Bound<'_, PyAny>>,
    label_map: Option<PathBuf>,
    up: &str,
    scenario: &str,
    out: Option<PathBuf>,
) -> PyResult<Dataset> {
    let args = marker_file_args(None, Some(path), label_map, up, scenario, &out);
    data_import(py, args, model, out)
}

/// Imports 2D keypoints (COCO keypoint files, or OpenPose frame files/folders; one path per
/// camera) in calibrated cameras as `lfit data import --keypoints` does: a `keypoints2d`
/// dataset without ground truth. `layout`: `coco17`, `body25`, `coco18`, `halpe26`,
/// `wholebody133`, `blazepose33` or `panoptic19`; `camera`: the camera JSON file (lfit's, OpenCV's keys, or a CMU Panoptic
/// calibration); `camera_names`: the file's cameras the paths come from, in their order (names,
/// or `"#K"` for its camera K; default all, in the file's order); `camera_units`: `m`, `cm` or
/// `mm`, the translations' unit where the file does not say it (an anipose `.toml`);
/// `keypoint_scale`: the files' unit, `pixels` (default), `image` (fractions of the image:
/// MediaPipe's normalised landmarks), `openpose3` or `openpose4` (OpenPose's `--keypoint_scale`);
/// `up`: its world's up axis, `y`, `z` or `"x,y,z"` (`lfit data import --up`: a Z-up world, or
/// one whose up is that direction, is turned into lfit's Y-up one); `reference`: a captured 3D
/// reference of the same frames' joints (CMU Panoptic `body3DScene_*.json` files or their
/// folder, `lfit data import --reference`), turned with the cameras, which `fit` then scores
/// against (MPJPE, PA-MPJPE), or one TRC or C3D file of 3D keypoints whose labels name
/// `reference_layout`'s points (default `layout`) or that `reference_map` (a JSON file
/// `{"model joint": "reference point"}`) names; `reference_person`: a Panoptic body's id where
/// frames hold several.
#[pyfunction]
#[pyo3(signature = (paths, layout, camera, model=None, *, camera_names=None, camera_units=None, keypoint_scale=None, keypoint_map=None, min_confidence=0.1, fps=30.0, scenario="sequence", up="y", reference=None, reference_person=None, reference_layout=None, reference_map=None, out=None))]
#[allow(clippy::too_many_arguments)]
pub fn import_keypoints(
    py: Python<'_>,
    paths: Vec<PathBuf>,
    layout: String,
    camera: PathBuf,
    model: Option<&Bound<'_, PyAny>>,
    camera_names: Option<Vec<String>>,
    camera_units: Option<String>,
    keypoint_scale: Option<String>,
    keypoint_map: Option<PathBuf>,
    min_confidence: f64,
    fps: f64,
    scenario: &str,
    up: &str,
    reference: Option<Vec<PathBuf>>,
    reference_person: Option<i64>,
    reference_layout: Option<String>,
    reference_map: Option<PathBuf>,
    out: Option<PathBuf>,
) -> PyResult<Dataset> {
    if paths.is_empty() {
        return Err(bad("import_keypoints needs at least one keypoint path"));
    }
    let args = lfit::api::DataImportArgs {
        c3d: None,
        trc: None,
        label_map: None,
        up: up.into(),
        keypoints: paths,
        layout: Some(layout),
        camera: Some(camera),
        camera_names: camera_names.unwrap_or_default(),
        camera_units,
        keypoint_scale,
        keypoint_map,
        reference: reference.unwrap_or_default(),
        reference_person,
        reference_layout,
        reference_map,
        min_confidence,
        fps,
        scenario: scenario.to_string(),
        model: None,
        out: out.clone().unwrap_or_default(),
    };
    data_import(py, args, model, out)
}

/// Reads a camera file as `lfit data cameras` does (lfit's JSON, OpenCV's keys, a CMU Panoptic
/// calibration, an anipose / Pose2Sim `.toml`, an EasyMocap folder): the cameras chosen by
/// `camera_names` (names or `"#K"`; default all), translations in `camera_units` where the file
/// does not say it, turned from `up`'s world into lfit's Y-up one; returns its summary (each
/// camera's `centre_m`, `height_m`, `distance_m`, `tilt_deg`, `fx`, `image`, `distortion`) and
/// writes the cameras in lfit's own JSON to `out` if given (`pinhole`: without the lenses).
#[pyfunction]
#[pyo3(signature = (camera, *, camera_names=None, camera_units=None, up="y", pinhole=false, out=None))]
pub fn read_cameras<'py>(
    py: Python<'py>,
    camera: PathBuf,
    camera_names: Option<Vec<String>>,
    camera_units: Option<String>,
    up: &str,
    pinhole: bool,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let args = lfit::api::DataCamerasArgs {
        camera,
        camera_names: camera_names.unwrap_or_default(),
        camera_units,
        up: up.to_string(),
        pinhole,
        out,
    };
    let summary = without_gil(py, |_| lfit::api::data_cameras(&args))?;
    json_to_py(py, &summary)
}

/// A motion in one model's parameter layout (`lfit motion import`): `params` `(T, P)`, `fps`,
/// `source`, and the import's report (`summary`: bone-direction cosines, scale).
#[pyclass(module = "lfit", name = "Motion", frozen)]
pub struct Motion {
    clip: lfit::synth::motion::file::MotionClip,
    summary: serde_json::Value,
}

#[pymethods]
impl Motion {
    /// Parameters of every frame, `(T, P)` float64.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let width = self.clip.model.layout.dim();
        rows_array(py, &self.clip.poses, width)
    }

    #[getter]
    fn fps(&self) -> f64 {
        self.clip.fps
    }

    #[getter]
    fn source(&self) -> String {
        self.clip.source.clone()
    }

    /// What the import reported (frames, scale, bone-direction cosines, ...).
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, &self.summary)
    }

    /// Writes the motion file (`.npz`; `lfit synth --motions` and `synth(motions=...)` read it).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        without_gil(py, |_| Ok(self.clip.write(&path)?))
    }

    fn __len__(&self) -> usize {
        self.clip.poses.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Motion({} frames at {} Hz, model '{}', {})",
            self.clip.poses.len(),
            self.clip.fps,
            self.clip.model.id,
            self.clip.source
        )
    }
}

/// Imports a BVH clip retargeted onto `model` as `lfit motion import --bvh` does. `map`: the
/// joint-name map JSON (`configs/maps/`; default: identical names); `units`: `auto`, `cm` or
/// `m`; `up`: `y`, `z` or `"x,y,z"`; `root`: `floor` or `rest` (`lfit motion import --root`); `stride`:
/// keep every N-th frame.
#[pyfunction]
#[pyo3(signature = (path, model=None, *, map=None, units="auto", up="y", root="floor", stride=1, rest_pose=None, out=None))]
#[allow(clippy::too_many_arguments)]
pub fn import_bvh(
    py: Python<'_>,
    path: PathBuf,
    model: Option<&Bound<'_, PyAny>>,
    map: Option<PathBuf>,
    units: &str,
    up: &str,
    root: &str,
    stride: usize,
    rest_pose: Option<PathBuf>,
    out: Option<PathBuf>,
) -> PyResult<Motion> {
    let template = optional_model(model)?;
    let args = lfit::api::MotionImportArgs {
        bvh: Some(path),
        map,
        amass: None,
        model: None,
        out: out.clone().unwrap_or_default(),
        units: units.to_string(),
        up: up.to_string(),
        root: root.to_string(),
        stride,
        rest_pose,
    };
    let (clip, summary) = without_gil(py, |_| lfit::api::import_clip(&args, template.as_deref()))?;
    if let Some(out) = &out {
        without_gil(py, |_| Ok(clip.write(out)?))?;
    }
    Ok(Motion { clip, summary })
}

/// Fits a pose prior as `lfit motion prior` does and returns `(energy, summary)`: the energy
/// configuration carrying it (a dict for `fit(energy=...)`) and the summary (frames, the prior's
/// scores on them and on `held_out`). `motions`: motion files and/or `Motion`s (`import_bvh`);
/// `data`: `lfit synth` datasets whose ground-truth poses join them; `stride`: every N-th frame;
/// `epsilon_deg`: ε of `Σ + ε² I`; `weight`: default `modality`'s (markers 0.01, keypoints2d
/// 0.001; required otherwise); `components`: Gaussians (a mixture by EM from `seed` above 1);
/// `held_out`: motion files scored, not fitted; `energy`: the base energy file (default: the
/// gradient variant); `out`: also written there (atomically).
#[pyfunction]
#[pyo3(signature = (motions, model=None, *, data=None, stride=1, epsilon_deg=3.0, weight=None, modality="markers", components=1, seed=0, held_out=None, energy=None, out=None))]
#[allow(clippy::too_many_arguments)]
pub fn motion_prior<'py>(
    py: Python<'py>,
    motions: &Bound<'py, PyAny>,
    model: Option<&Bound<'py, PyAny>>,
    data: Option<Vec<PathBuf>>,
    stride: usize,
    epsilon_deg: f64,
    weight: Option<f64>,
    modality: &str,
    components: usize,
    seed: u64,
    held_out: Option<Vec<PathBuf>>,
    energy: Option<PathBuf>,
    out: Option<PathBuf>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let template = match optional_model(model)? {
        Some(t) => t,
        None => Arc::new(without_gil(py, |_| lfit::api::load_model(None, "default"))?),
    };
    let mut paths = Vec::new();
    let mut objects: Vec<Py<Motion>> = Vec::new();
    for item in motions
        .try_iter()
        .map_err(|_| bad("motions must be a list of motion files or Motion objects"))?
    {
        let item = item?;
        if let Ok(m) = item.cast::<Motion>() {
            objects.push(m.clone().unbind());
        } else {
            paths.push(item.extract::<PathBuf>().map_err(|_| {
                bad("motions must be a list of motion files or Motion objects")
            })?);
        }
    }
    let args = lfit::api::MotionPriorArgs {
        motions: paths,
        data: data.unwrap_or_default(),
        model: None,
        stride,
        epsilon_deg,
        weight,
        modality: modality.to_string(),
        components,
        seed,
        held_out: held_out.unwrap_or_default(),
        energy,
        out: out.clone().unwrap_or_default(),
    };
    let clips: Vec<(String, &lfit::synth::motion::file::MotionClip)> = objects
        .iter()
        .enumerate()
        .map(|(k, m)| (format!("Motion {k} ({})", m.get().clip.source), &m.get().clip))
        .collect();
    let (config, summary) = without_gil(py, |_| {
        let (config, summary) = lfit::api::prior_energy(&args, &template, &clips)?;
        if let Some(out) = &out {
            lfit::model::template::write_atomic(out, &serde_json::to_vec_pretty(&config)?)?;
        }
        Ok((serde_json::to_value(&config)?, summary))
    })?;
    Ok((json_to_py(py, &config)?, json_to_py(py, &summary)?))
}
