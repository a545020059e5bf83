//! `lfit.fit`: `lfit fit` on a dataset (held in memory or read from a file), its result as
//! arrays (`lfit.FitResult`).

use std::path::PathBuf;

use pyo3::prelude::*;
use serde_json::Value;

use crate::convert::{OrPy, array_nd, array1, bad, floats, json_to_py, without_gil};
use crate::dataset::dataset_arg;
use crate::energy::energy_config;
use crate::model::optional_model;

/// The result of `lfit.fit`: one row per fitted frame. Arrays are float64 unless said; errors
/// that need ground truth (`v2v_mm`, `mpjpe_mm`, `pa_mpjpe_mm`) are NaN without it, and the distance to the
/// observations (`observation_error`, unit `observation_unit`) is NaN with it.
#[pyclass(module = "lfit", name = "FitResult", frozen)]
pub struct FitResult {
    document: Value,
    frames: Vec<i64>,
    params: Vec<f64>,
    dims: (usize, usize, usize),
    columns: Vec<(&'static str, Vec<f64>)>,
    observation_unit: Option<String>,
}

fn column(rows: &[Value], key: &str) -> Vec<f64> {
    rows.iter()
        .map(|r| r.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN))
        .collect()
}

fn numbers(v: Option<&Value>) -> Vec<f64> {
    v.and_then(Value::as_array)
        .map(|a| a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect())
        .unwrap_or_default()
}

impl FitResult {
    fn new(document: Value, dims: (usize, usize, usize)) -> Self {
        let rows: Vec<Value> = document["frames"].as_array().cloned().unwrap_or_default();
        let frames = rows
            .iter()
            .map(|r| r["frame"].as_i64().unwrap_or(-1))
            .collect();
        let mut params = Vec::with_capacity(rows.len() * (dims.0 + dims.1 + dims.2));
        for r in &rows {
            for (key, n) in [("pose", dims.0), ("shape", dims.1), ("expression", dims.2)] {
                let mut v = numbers(r.get(key));
                v.resize(n, f64::NAN);
                params.extend(v);
            }
        }
        let unit = ["mm", "px"].into_iter().find(|u| {
            rows.iter()
                .any(|r| r.get(format!("observation_error_{u}")).is_some())
        });
        let mut columns = vec![
            ("energies", column(&rows, "energy")),
            ("start_energies", column(&rows, "start_energy")),
            ("times", column(&rows, "time_s")),
            ("evaluations", column(&rows, "evaluations")),
            ("v2v_mm", column(&rows, "v2v_mm")),
            ("mpjpe_mm", column(&rows, "mpjpe_mm")),
            ("pa_mpjpe_mm", column(&rows, "pa_mpjpe_mm")),
            ("reference_mpjpe_mm", column(&rows, "reference_mpjpe_mm")),
            ("reference_pa_mpjpe_mm", column(&rows, "reference_pa_mpjpe_mm")),
        ];
        let obs = unit.map_or_else(
            || vec![f64::NAN; rows.len()],
            |u| column(&rows, &format!("observation_error_{u}")),
        );
        columns.push(("observation_error", obs));
        // `holdout`: the error on what the fit left out, in the sensor's unit.
        let held = ["mm", "px"]
            .into_iter()
            .find(|u| rows.iter().any(|r| r.get(format!("holdout_error_{u}")).is_some()))
            .map_or_else(
                || vec![f64::NAN; rows.len()],
                |u| column(&rows, &format!("holdout_error_{u}")),
            );
        columns.push(("holdout_error", held));
        Self {
            frames,
            params,
            dims,
            columns,
            observation_unit: unit.map(str::to_string),
            document,
        }
    }

    fn col<'py>(&self, py: Python<'py>, name: &str) -> Bound<'py, numpy::PyArray1<f64>> {
        let v = self
            .columns
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| v.clone())
            .unwrap_or_default();
        array1(py, v)
    }

    fn block<'py>(
        &self,
        py: Python<'py>,
        from: usize,
        width: usize,
    ) -> PyResult<Bound<'py, PyAny>> {
        let total = self.dims.0 + self.dims.1 + self.dims.2;
        let n = self.frames.len();
        let flat: Vec<f64> = (0..n)
            .flat_map(|i| {
                self.params[i * total + from..i * total + from + width]
                    .iter()
                    .copied()
            })
            .collect();
        array_nd(py, flat, &[n, width])
    }
}

#[pymethods]
impl FitResult {
    /// The fitted frames' indices, int64 `(N,)`.
    #[getter]
    fn frames<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<i64>> {
        numpy::PyArray1::from_vec(py, self.frames.clone())
    }

    /// Full fitted parameter vectors, `(N, P)` (pose, β, ψ).
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.block(py, 0, self.dims.0 + self.dims.1 + self.dims.2)
    }

    /// Fitted poses, `(N, 3 + 3J)`.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.block(py, 0, self.dims.0)
    }

    /// Fitted shape coefficients β, `(N, B)`.
    #[getter]
    fn shapes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.block(py, self.dims.0, self.dims.1)
    }

    /// Fitted expression coefficients ψ, `(N, E)`.
    #[getter]
    fn expressions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.block(py, self.dims.0 + self.dims.1, self.dims.2)
    }

    /// Final energy of every frame.
    #[getter]
    fn energies<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "energies")
    }

    /// Energy at every frame's start (not counted as an evaluation).
    #[getter]
    fn start_energies<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "start_energies")
    }

    /// Seconds spent on every frame.
    #[getter]
    fn times<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "times")
    }

    /// Energy evaluations of every frame.
    #[getter]
    fn evaluations<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "evaluations")
    }

    /// Mean vertex error against the ground truth, mm (NaN without ground truth).
    #[getter]
    fn v2v_mm<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "v2v_mm")
    }

    /// Mean joint error against the ground truth, mm (NaN without ground truth).
    #[getter]
    fn mpjpe_mm<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "mpjpe_mm")
    }

    /// Mean joint error after a similarity alignment of the joints (rotation, scale,
    /// translation), mm: the monocular figure (NaN without ground truth).
    #[getter]
    fn pa_mpjpe_mm<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "pa_mpjpe_mm")
    }

    /// With a captured joint reference (`import_keypoints(reference=...)`): mean joint error
    /// against it, mm, over the joints it holds (NaN for frames without any, and without one).
    #[getter]
    fn reference_mpjpe_mm<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "reference_mpjpe_mm")
    }

    /// The same after a similarity alignment, mm (NaN where the frame holds fewer than three
    /// reference joints).
    #[getter]
    fn reference_pa_mpjpe_mm<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "reference_pa_mpjpe_mm")
    }

    /// Without ground truth: mean distance of the fit to the seen observations (markers: mm,
    /// keypoints: px; `observation_unit`), NaN otherwise.
    #[getter]
    fn observation_error<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "observation_error")
    }

    /// With `holdout`: mean distance of the fit to the seen observations it was not given
    /// (markers: mm, keypoints: px), NaN for frames where none of them was seen and without
    /// `holdout`.
    #[getter]
    fn holdout_error<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        self.col(py, "holdout_error")
    }

    /// `mm`, `px`, or None (with ground truth).
    #[getter]
    fn observation_unit(&self) -> Option<String> {
        self.observation_unit.clone()
    }

    /// The method's name.
    #[getter]
    fn method(&self) -> String {
        self.document["method"]
            .as_str()
            .unwrap_or_default()
            .to_string()
    }

    /// Means over the frames, as `lfit fit` prints them.
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, &self.document["summary"])
    }

    /// The whole result document `lfit fit --out` writes (per-frame terms, traces, ...).
    fn document<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, &self.document)
    }

    /// Writes the result document as JSON (what `lfit fit --out` writes; `lfit export` and
    /// `lfit render` read it).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        let bytes = serde_json::to_vec_pretty(&self.document).map_err(|e| bad(e.to_string()))?;
        lfit::model::template::write_atomic(&path, &bytes)
            .map_err(|e| crate::convert::err(e.into()))
    }

    fn __len__(&self) -> usize {
        self.frames.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "FitResult({}, {} frames, mean energy {})",
            self.method(),
            self.frames.len(),
            self.document["summary"]["mean_energy"]
        )
    }
}

/// `frames`: None (all), a string as `lfit fit --frames` takes (`0..20`, `3-5`, `7`, or a comma
/// list), or a sequence of frame indices.
fn frames_arg(frames: Option<&Bound<'_, PyAny>>) -> PyResult<Option<String>> {
    let Some(f) = frames.filter(|f| !f.is_none()) else {
        return Ok(None);
    };
    if let Ok(s) = f.extract::<String>() {
        return Ok(Some(s));
    }
    let list: Vec<i64> = f.extract().map_err(|_| {
        bad("frames: expected a string such as '0..20' or a sequence of frame indices")
    })?;
    if list.is_empty() {
        return Err(bad("frames: empty list"));
    }
    if let Some(i) = list.iter().find(|&&i| i < 0) {
        return Err(bad(format!("frames: {i} is not a frame index")));
    }
    Ok(Some(
        list.iter()
            .map(i64::to_string)
            .collect::<Vec<_>>()
            .join(","),
    ))
}

/// `known_shape`: None, `"truth"`, `"height:M"`, or the subject's β as numbers.
fn known_shape_arg(k: Option<&Bound<'_, PyAny>>) -> PyResult<Option<String>> {
    let Some(k) = k.filter(|k| !k.is_none()) else {
        return Ok(None);
    };
    if let Ok(s) = k.extract::<String>() {
        return Ok(Some(s));
    }
    let f = floats(k, "known_shape")?.finite("known_shape")?;
    if f.shape.len() != 1 {
        return Err(bad(format!(
            "known_shape has shape {}, expected (B,)",
            crate::convert::shape_text(&f.shape)
        )));
    }
    Ok(Some(
        f.data
            .iter()
            .map(f64::to_string)
            .collect::<Vec<_>>()
            .join(","),
    ))
}

/// `height_prior`: None, the subject's height in metres, `"M"` / `"M:STD"` (`lfit fit
/// --height-prior`) or a pair `(M, STD)`.
pub(crate) fn height_prior_arg(h: Option<&Bound<'_, PyAny>>) -> PyResult<Option<String>> {
    let Some(h) = h.filter(|h| !h.is_none()) else {
        return Ok(None);
    };
    if let Ok(s) = h.extract::<String>() {
        return Ok(Some(s));
    }
    if let Ok(m) = h.extract::<f64>() {
        return Ok(Some(m.to_string()));
    }
    if let Ok((m, std)) = h.extract::<(f64, f64)>() {
        return Ok(Some(format!("{m}:{std}")));
    }
    Err(bad(
        "height_prior: expected metres (a number), 'M:STD' or a pair (M, STD)",
    ))
}

/// Fits the frames of `data` as `lfit fit` does, with the same settings and the same result.
///
/// `model`: the dataset's model (a `Model`, path or name; default: the procedural body the
/// dataset names). `data`: a `Dataset` or the path of one. `method`: `lm`, `lm-triggs`, `gn`,
/// `lbfgs`, `cma`, `pso`, `de`, ... or `neural`/`neural+lm` (with `checkpoint`; needs a wheel
/// built with the `neural` feature). `budget`: energy evaluations per frame. `frames`: a
/// `--frames` string or a sequence of indices. `known_shape`: `"truth"`, `"height:M"` (the
/// subject's height in metres: the most likely β that tall) or β. `height_prior`: the
/// subject's height as a soft measurement with β estimated — metres, `"M:STD"` or `(M, STD)`
/// (`lfit fit --height-prior`; not with `known_shape`). `floor`: the ground plane,
/// `"FORM:HEIGHT[,MM]"` (`lfit fit --floor`: `above` or `contact`, metres up +y or `truth`).
/// `dofs`: `"all"`,
/// `"observed"`, `"observed:DEG"`, `"anchored"`, `"anchored:DEG"`, `"anchored:DEG,MM"` or
/// `"observed[:DEG]+anchored[:DEG[,MM]]"` (`lfit fit --dofs`, the network's too; default the
/// method's own).
/// `neural_iterations`: the network's first K iterations only (`lfit fit --neural-iterations`).
/// `neural_tolerance`: stop a frame's network once an iteration lowered the energy by less than
/// that fraction (`lfit fit --neural-tolerance`).
/// `sequence_shape`: `"per-frame"` (default), `"first-pass"`, `"joint"` or `"joint:N"` (`lfit
/// fit --sequence-shape`). `marker_placement`: `"model"` (default) or `"solve"` (`lfit fit
/// --marker-placement`). `offsets`: a file of where the markers or keypoints sit (`lfit fit
/// --offsets`). `holdout`: markers (names) or 2D keypoints (`"camera:K"`, joint names) left out
/// of the fit and scored on (`lfit fit --holdout`; a comma-separated string or a list).
/// `energy`: a dict or JSON file of the energy configuration.
/// `progress(done, total)` is called after each frame. Runs with the GIL released; Ctrl-C stops
/// it between frames (`KeyboardInterrupt`).
#[pyfunction]
#[pyo3(signature = (model, data, method="lm", budget=100, *, checkpoint=None, known_shape=None, height_prior=None, floor=None, frames=None, seed=0, strategy="holistic", preset=None, step_scale=None, cma_diagonal=false, cma_elitist=false, cma_popsize=None, energy=None, batch=1, neural_start="phi", neural_pick="last", neural_iterations=None, neural_tolerance=None, sequence_shape="per-frame", marker_placement="model", offsets=None, holdout=None, dofs=None, device="flex", runtime="burn", ort_threads=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn fit(
    py: Python<'_>,
    model: Option<&Bound<'_, PyAny>>,
    data: &Bound<'_, PyAny>,
    method: &str,
    budget: usize,
    checkpoint: Option<PathBuf>,
    known_shape: Option<&Bound<'_, PyAny>>,
    height_prior: Option<&Bound<'_, PyAny>>,
    floor: Option<String>,
    frames: Option<&Bound<'_, PyAny>>,
    seed: u64,
    strategy: &str,
    preset: Option<String>,
    step_scale: Option<f64>,
    cma_diagonal: bool,
    cma_elitist: bool,
    cma_popsize: Option<usize>,
    energy: Option<&Bound<'_, PyAny>>,
    batch: usize,
    neural_start: &str,
    neural_pick: &str,
    neural_iterations: Option<usize>,
    neural_tolerance: Option<f64>,
    sequence_shape: &str,
    marker_placement: &str,
    offsets: Option<PathBuf>,
    holdout: Option<&Bound<'_, PyAny>>,
    dofs: Option<String>,
    device: &str,
    runtime: &str,
    ort_threads: Option<usize>,
    progress: Option<Py<PyAny>>,
) -> PyResult<FitResult> {
    let kind: lfit::api::MethodKind = method.parse().py_err()?;
    let template = optional_model(model)?;
    let (dataset, path) = dataset_arg(data)?;
    let config = energy_config(energy)?;
    let args = lfit::api::FitArgs {
        data: path.unwrap_or_default(),
        method: kind,
        budget,
        strategy: strategy.to_string(),
        preset,
        step_scale,
        cma: lfit::fitters::optim::cma::CmaVariant {
            diagonal: cma_diagonal,
            elitist: cma_elitist,
            popsize: cma_popsize,
        },
        frames: frames_arg(frames)?,
        seed,
        out: PathBuf::new(),
        energy: None,
        template: None,
        checkpoint,
        neural_start: neural_start.to_string(),
        neural_pick: neural_pick.to_string(),
        neural_iterations,
        neural_tolerance,
        device: device.to_string(),
        batch,
        runtime: runtime.to_string(),
        ort_threads,
        known_shape: known_shape_arg(known_shape)?,
        height_prior: height_prior_arg(height_prior)?,
        floor,
        sequence_shape: sequence_shape.to_string(),
        marker_placement: marker_placement.to_string(),
        offsets,
        dofs,
        holdout: holdout.map(holdout_arg).transpose()?,
    };
    let document = without_gil(py, |interrupted| {
        let report = |done: usize, total: usize| -> anyhow::Result<()> {
            interrupted()?;
            if let Some(p) = &progress {
                Python::attach(|py| p.call1(py, (done, total)).map(|_| ()))
                    .map_err(|e| anyhow::anyhow!("progress callback failed: {e}"))?;
            }
            Ok(())
        };
        lfit::api::fit_dataset(&args, &dataset, template.clone(), config.clone(), &report)
    })?;
    let dims = match &template {
        Some(t) => {
            let l = t.layout();
            (l.pose_dim(), l.shape, l.expression)
        }
        None => (
            dataset.meta.pose_dim,
            dataset.meta.shape_dim,
            dataset.meta.expression_dim,
        ),
    };
    Ok(FitResult::new(document, dims))
}

/// Solves where the markers or 2D keypoints of `data` sit, at poses that are known, as `lfit
/// calibrate` does (a detector's keypoint offsets, a marker set's placement; for `fit(...,
/// offsets=)`). `model`: the dataset's model (default: the one it names). `data`: a `Dataset` or
/// its path. `poses`: the result JSON of `lfit fit` (or a `{"pose"}`/`{"poses"}` file) of the
/// poses its frames were recorded at, e.g. a fit of the motion capture filmed alongside;
/// default: the dataset's ground truth. `prior_mm`: σ of the offsets' prior (default 20 mm for
/// markers, 30 for keypoints). Returns `{"calibration": {...}, "keypoint_offsets" |
/// "marker_offsets": [[x, y, z], ...]}`, written to `out` too when given.
#[pyfunction]
#[pyo3(signature = (model, data, *, poses=None, prior_mm=None, out=None))]
pub fn calibrate<'py>(
    py: Python<'py>,
    model: Option<&Bound<'py, PyAny>>,
    data: &Bound<'py, PyAny>,
    poses: Option<PathBuf>,
    prior_mm: Option<f64>,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let template = optional_model(model)?;
    let (dataset, path) = dataset_arg(data)?;
    let doc = without_gil(py, |_| {
        let template = match template {
            Some(t) => {
                lfit::api::check_model(&dataset, &t)?;
                t
            }
            None => lfit::api::template_for(&dataset, None)?,
        };
        let name = path.map_or_else(|| "the dataset".into(), |p| p.display().to_string());
        let doc =
            lfit::api::calibrate_dataset(&dataset, &name, template, poses.as_deref(), prior_mm)?;
        if let Some(out) = &out {
            lfit::model::template::write_atomic(out, &serde_json::to_vec_pretty(&doc)?)?;
        }
        Ok(doc)
    })?;
    json_to_py(py, &doc)
}

/// `holdout`: a comma-separated string or a sequence of strings.
fn holdout_arg(value: &Bound<'_, PyAny>) -> PyResult<String> {
    if let Ok(s) = value.extract::<String>() {
        return Ok(s);
    }
    let items: Vec<String> = value
        .extract()
        .map_err(|_| bad("holdout must be a string or a list of strings"))?;
    Ok(items.join(","))
}
