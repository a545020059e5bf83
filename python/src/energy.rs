//! `lfit.Energy`: one frame's energy as a function of the free parameter entries, with its
//! gradient, residuals and Jacobian (`scipy.optimize.least_squares(e.residuals, e.x0,
//! jac=e.jacobian, bounds=(e.lower, e.upper))` minimises what `lfit.fit(method="lm")` does).
//! Evaluations release the GIL, so frames can be evaluated from several Python threads.

use std::path::PathBuf;
use std::sync::Arc;

use lfit::api::FrameProblem;
use lfit::model::energy::{EnergyConfig, Target};
use lfit::model::observe::{Modality, Sensor};
use lfit::model::template::Template;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{OrPy, array_nd, array1, bad, bools, floats, json_to_py, py_to_json};
use crate::dataset::dataset_arg;
use crate::model::{model_arg, optional_model};

/// An energy configuration argument: a dict (the JSON of `lfit fit --energy`), the path of such
/// a file, or None (the configuration `lfit fit` uses for gradient methods and LM).
pub fn energy_config(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<EnergyConfig>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    let config = if obj.cast::<PyDict>().is_ok() {
        let v = py_to_json(obj, "config")?;
        serde_json::from_value::<EnergyConfig>(v)
            .map_err(|e| bad(format!("malformed energy configuration: {e}")))?
    } else {
        let path: PathBuf = obj.extract().map_err(|_| {
            bad("config: expected a dict or the path of an energy configuration JSON file")
        })?;
        lfit::api::read_energy_config(Some(&path), true).py_err()?
    };
    config
        .validate()
        .map_err(|e| crate::convert::err(e.into()))?;
    Ok(Some(config))
}

/// One frame's energy over the free entries of its scenario.
///
/// From a dataset frame: `Energy(model, data, frame)` — the dataset's start pose, the
/// scenario's free entries (local/sequence: the local box around the start; global: the
/// model's limits), exactly as `lfit fit` poses the frame. From observations:
/// `Energy(model, observations=..., sensor=..., visible=None, scenario="global", start=None)` —
/// `sensor` is a modality name (its default setup for the model) or a dict as
/// `Dataset.sensor` gives. `config`: a dict or JSON file of the energy configuration; default
/// the one `lfit fit` uses for gradient methods and LM. `height_prior`: the subject's height
/// as a soft measurement in the energy (`lfit fit --height-prior`): metres, `"M:STD"` or
/// `(M, STD)`. `floor`: the ground plane as a measurement (`lfit fit --floor`),
/// `"FORM:HEIGHT[,MM]"` (`truth`: a dataset frame's own lowest true sole).
#[pyclass(module = "lfit", name = "Energy", frozen)]
pub struct Energy {
    problem: FrameProblem,
}

fn x_of(problem: &FrameProblem, x: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let f = floats(x, "x")?;
    if f.shape.len() != 1 {
        return Err(bad(format!(
            "x has shape {}, expected ({},)",
            crate::convert::shape_text(&f.shape),
            problem.dim()
        )));
    }
    problem.check_point(&f.data).py_err()?;
    Ok(f.data)
}

#[pymethods]
impl Energy {
    #[new]
    #[pyo3(signature = (model=None, data=None, frame=0, *, observations=None, visible=None, sensor=None, scenario="global", start=None, config=None, height_prior=None, floor=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        model: Option<&Bound<'_, PyAny>>,
        data: Option<&Bound<'_, PyAny>>,
        frame: usize,
        observations: Option<&Bound<'_, PyAny>>,
        visible: Option<&Bound<'_, PyAny>>,
        sensor: Option<&Bound<'_, PyAny>>,
        scenario: &str,
        start: Option<&Bound<'_, PyAny>>,
        config: Option<&Bound<'_, PyAny>>,
        height_prior: Option<&Bound<'_, PyAny>>,
        floor: Option<&str>,
    ) -> PyResult<Self> {
        let floor: Option<lfit::api::FloorArg> = floor.map(str::parse).transpose().py_err()?;
        let height_prior: Option<lfit::api::HeightPriorArg> =
            crate::fit::height_prior_arg(height_prior)?
                .map(|h| h.parse())
                .transpose()
                .py_err()?;
        let config =
            energy_config(config)?.unwrap_or_else(|| EnergyConfig::default().for_gradient());
        let data = data.filter(|d| !d.is_none());
        let observations = observations.filter(|o| !o.is_none());
        // A dataset frame's ground truth (`height_prior="truth"` reads its β).
        let mut truth: Option<Vec<f64>> = None;
        let problem = match (data, observations) {
            (Some(_), Some(_)) => {
                return Err(bad(
                    "give either data (a dataset and frame) or observations, not both",
                ));
            }
            (None, None) => {
                return Err(bad(
                    "Energy needs data (a dataset and frame) or observations with a sensor",
                ));
            }
            (Some(d), None) => {
                if visible.is_some_and(|v| !v.is_none()) || sensor.is_some_and(|s| !s.is_none()) {
                    return Err(bad(
                        "visible and sensor go with observations; a dataset frame has its own",
                    ));
                }
                let (dataset, _) = dataset_arg(d)?;
                truth = dataset.ground_truth(frame).map(<[f64]>::to_vec);
                let template = match optional_model(model)? {
                    Some(t) => {
                        lfit::api::check_model(&dataset, &t).py_err()?;
                        t
                    }
                    None => lfit::api::template_for(&dataset, None).py_err()?,
                };
                let problem = FrameProblem::from_dataset(&dataset, template.clone(), frame, config)
                    .py_err()?;
                match start.filter(|s| !s.is_none()) {
                    Some(s) => {
                        let start = start_vector(&template, s)?;
                        FrameProblem::around(problem.energy, dataset.meta.config.scenario, start)
                    }
                    None => problem,
                }
            }
            (None, Some(obs)) => {
                let model = model
                    .filter(|m| !m.is_none())
                    .ok_or_else(|| bad("Energy from observations needs a model"))?;
                let template = model_arg(model)?;
                let sensor = sensor_arg(sensor, &template)?;
                let values = floats(obs, "observations")?;
                if values.shape.len() != 1 {
                    return Err(bad(format!(
                        "observations has shape {}, expected one frame's vector (D,)",
                        crate::convert::shape_text(&values.shape)
                    )));
                }
                let n = values.data.len();
                let visible = match visible.filter(|v| !v.is_none()) {
                    Some(v) => {
                        let (shape, flags) = bools(v, "visible")?;
                        if shape != [n] {
                            return Err(bad(format!(
                                "visible has shape {}, expected ({n},) like observations",
                                crate::convert::shape_text(&shape)
                            )));
                        }
                        flags
                    }
                    None => vec![true; n],
                };
                let scenario: lfit::synth::Scenario = scenario
                    .parse()
                    .map_err(|e: lfit::synth::SynthError| crate::convert::err(e.into()))?;
                let start = match start.filter(|s| !s.is_none()) {
                    Some(s) => start_vector(&template, s)?,
                    None => vec![0.0; template.layout().dim()],
                };
                let energy = lfit::model::energy::Energy::new(
                    template,
                    sensor,
                    Target::Sparse {
                        values: values.data,
                        visible,
                    },
                    config,
                )
                .map_err(|e| crate::convert::err(e.into()))?;
                FrameProblem::around(energy, scenario, start)
            }
        };
        let problem = match height_prior {
            Some(h) => problem.with_height_prior(h, truth.as_deref()).py_err()?,
            None => problem,
        };
        let problem = match floor {
            Some(f) => problem.with_floor(f, truth.as_deref()).py_err()?,
            None => problem,
        };
        Ok(Self { problem })
    }

    /// Number of free entries: the length of a point `x`.
    #[getter]
    fn dim(&self) -> usize {
        self.problem.dim()
    }

    /// The start point (the free entries of the frame's start parameters).
    #[getter]
    fn x0<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array1(py, self.problem.mask.gather(&self.problem.start))
    }

    /// Lower bounds of the free entries (the box `lfit fit` searches).
    #[getter]
    fn lower<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array1(py, self.problem.lower.clone())
    }

    /// Upper bounds of the free entries.
    #[getter]
    fn upper<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array1(py, self.problem.upper.clone())
    }

    /// Indices of the free entries in the model's parameter vector.
    #[getter]
    fn free(&self) -> Vec<usize> {
        self.problem.mask.free.clone()
    }

    /// Names of the free entries (`t_x`, `l_knee.rx`, `shape.3`, ...).
    #[getter]
    fn names(&self) -> Vec<String> {
        let l = self.problem.energy.template().layout();
        self.problem.mask.free.iter().map(|&i| l.name(i)).collect()
    }

    /// The modality of the observations.
    #[getter]
    fn modality(&self) -> &'static str {
        self.problem.energy.modality().name()
    }

    /// The energy configuration, as a dict.
    #[getter]
    fn config<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v =
            serde_json::to_value(self.problem.energy.config()).map_err(|e| bad(e.to_string()))?;
        json_to_py(py, &v)
    }

    /// Number of residuals (None when the energy is not a sum of squares: scan, silhouettes).
    #[getter]
    fn residual_count(&self) -> Option<usize> {
        self.problem
            .energy
            .least_squares_unsupported()
            .is_none()
            .then(|| self.problem.energy.residual_count())
    }

    /// Evaluations counted so far (values and gradients; residual calls are not counted).
    #[getter]
    fn evaluations(&self) -> u64 {
        self.problem.energy.evaluations()
    }

    /// The full parameter vector of a point `x` (the start with the free entries replaced).
    fn full<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, numpy::PyArray1<f64>>> {
        let x = x_of(&self.problem, x)?;
        Ok(array1(py, self.problem.full(&x)))
    }

    /// The energy at `x` `(dim,)` → float; or at every row of `(N, dim)` → `(N,)`, in parallel
    /// with the GIL released.
    fn value<'py>(&self, py: Python<'py>, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let f = floats(x, "x")?;
        if f.shape.len() == 2 {
            let (rows, _) = f.rows(self.problem.dim(), "x")?;
            let full: Vec<Vec<f64>> = rows
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    self.problem
                        .check_point(r)
                        .map_err(|e| crate::convert::err(e.context(format!("row {i}"))))?;
                    Ok(self.problem.full(r))
                })
                .collect::<PyResult<_>>()?;
            let values = py.detach(|| self.problem.energy.evaluate_batch(&full));
            return Ok(array1(py, values).into_any());
        }
        let x = x_of(&self.problem, x)?;
        let v = self.problem.energy.evaluate(&self.problem.full(&x)).total;
        Ok(v.into_pyobject(py)?.into_any())
    }

    /// The energy and its exact gradient over the free entries: `(float, (dim,))`.
    fn value_and_grad<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<(f64, Bound<'py, numpy::PyArray1<f64>>)> {
        let x = x_of(&self.problem, x)?;
        let energy = &self.problem.energy;
        if let Some(why) = energy.gradient_unsupported() {
            return Err(bad(format!("no gradient for this energy: {why}")));
        }
        let pose = self.problem.full(&x);
        let (e, g) = py.detach(|| energy.evaluate_with_gradient(&pose));
        Ok((e.total, array1(py, self.problem.mask.gather(&g))))
    }

    /// The named terms of the energy at `x` (data, EP, EA, priors, ...), unweighted, and the
    /// total.
    fn terms<'py>(&self, py: Python<'py>, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
        let x = x_of(&self.problem, x)?;
        let e = self.problem.energy.evaluate(&self.problem.full(&x));
        let d = PyDict::new(py);
        for (k, v) in &e.terms {
            d.set_item(*k, *v)?;
        }
        d.set_item("total", e.total)?;
        Ok(d)
    }

    /// Residuals at `x`, `(M,)`: the energy is their sum of squares (robust losses folded in).
    fn residuals<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, numpy::PyArray1<f64>>> {
        let x = x_of(&self.problem, x)?;
        let (r, _) = py
            .detach(|| self.problem.residuals_at(&x, false))
            .py_err()?;
        Ok(array1(py, r))
    }

    /// The exact Jacobian of the residuals over the free entries at `x`, `(M, dim)`.
    fn jacobian<'py>(&self, py: Python<'py>, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let x = x_of(&self.problem, x)?;
        let (r, j) = py.detach(|| self.problem.residuals_at(&x, true)).py_err()?;
        array_nd(py, j.unwrap_or_default(), &[r.len(), self.problem.dim()])
    }

    /// Residuals and Jacobian from one evaluation: `((M,), (M, dim))`.
    fn residuals_and_jacobian<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, numpy::PyArray1<f64>>, Bound<'py, PyAny>)> {
        let x = x_of(&self.problem, x)?;
        let (r, j) = py.detach(|| self.problem.residuals_at(&x, true)).py_err()?;
        let m = r.len();
        Ok((
            array1(py, r),
            array_nd(py, j.unwrap_or_default(), &[m, self.problem.dim()])?,
        ))
    }

    /// Seconds per `residuals_and_jacobian` call measured inside Rust over `repeats` calls at
    /// `x` (the same library call without Python's conversions; for overhead measurements).
    fn _rust_seconds_per_residuals_and_jacobian(
        &self,
        py: Python<'_>,
        x: &Bound<'_, PyAny>,
        repeats: usize,
    ) -> PyResult<f64> {
        let x = x_of(&self.problem, x)?;
        let repeats = repeats.max(1);
        py.detach(|| {
            let t = std::time::Instant::now();
            for _ in 0..repeats {
                let (r, j) = self.problem.residuals_at(std::hint::black_box(&x), true)?;
                std::hint::black_box((r, j));
            }
            Ok(t.elapsed().as_secs_f64() / repeats as f64)
        })
        .py_err()
    }

    fn __repr__(&self) -> String {
        format!(
            "Energy({}, model '{}', {} free entries)",
            self.problem.energy.modality().name(),
            self.problem.energy.template().id,
            self.problem.dim()
        )
    }
}

fn start_vector(template: &Template, s: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let f = floats(s, "start")?.finite("start")?;
    let dim = template.layout().dim();
    if f.shape != [dim] {
        return Err(bad(format!(
            "start has shape {}, expected ({dim},): a full parameter vector of '{}'",
            crate::convert::shape_text(&f.shape),
            template.id
        )));
    }
    Ok(f.data)
}

fn sensor_arg(sensor: Option<&Bound<'_, PyAny>>, template: &Arc<Template>) -> PyResult<Sensor> {
    let Some(s) = sensor.filter(|s| !s.is_none()) else {
        return Err(bad(
            "Energy from observations needs sensor: a modality name (markers, keypoints2d, hmd) or a dict as Dataset.sensor gives",
        ));
    };
    if let Ok(name) = s.extract::<String>() {
        let modality: Modality = name
            .parse()
            .map_err(|e: lfit::model::ModelError| crate::convert::err(e.into()))?;
        return Ok(Sensor::default_for(modality, template));
    }
    let v = py_to_json(s, "sensor")?;
    serde_json::from_value(v).map_err(|e| bad(format!("malformed sensor setup: {e}")))
}
