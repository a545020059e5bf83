//! `lfit.Model`: a body model (template directory, SMPL-layout `.npz`, a committed model or a
//! procedural body by name) and its forward pass.

use std::path::PathBuf;
use std::sync::Arc;

use lfit::model::layout::Block;
use lfit::model::skinning::{SkinningMethod, joint_transforms, pose_vertices_batch};
use lfit::model::template::Template;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::convert::{OrPy, array_nd, bad, floats, json_to_py};

/// Models committed to the repository and shipped in the wheel (`lfit/models/NAME.npz`).
pub const SHIPPED: [&str; 2] = ["makehuman-cmu_mb", "makehuman-face"];

/// A body model: mesh, skeleton, skinning weights, blend shapes, markers.
#[pyclass(module = "lfit", name = "Model", frozen)]
pub struct Model {
    pub template: Arc<Template>,
}

/// A model argument: a `Model`, or what `Model.load` takes (path or name).
pub fn model_arg(obj: &Bound<'_, PyAny>) -> PyResult<Arc<Template>> {
    if let Ok(m) = obj.cast::<Model>() {
        return Ok(m.get().template.clone());
    }
    Model::load(obj.py(), obj).map(|m| m.template)
}

/// An optional model argument (`None`: absent).
pub fn optional_model(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Arc<Template>>> {
    match obj {
        Some(o) if !o.is_none() => model_arg(o).map(Some),
        _ => Ok(None),
    }
}

fn shipped_dir(py: Python<'_>) -> PyResult<PathBuf> {
    let file: PathBuf = py.import("lfit")?.getattr("__file__")?.extract()?;
    Ok(file
        .parent()
        .map_or_else(|| PathBuf::from("models"), |d| d.join("models")))
}

#[pymethods]
impl Model {
    /// Loads a model: a template directory or SMPL-layout `.npz` file, a model shipped with the
    /// package by name (`makehuman-cmu_mb`, `makehuman-face`), or a procedural body by name
    /// (`default`, `morphable`, or a proportion variant such as `tall`).
    #[staticmethod]
    pub fn load(py: Python<'_>, source: &Bound<'_, PyAny>) -> PyResult<Self> {
        let path: PathBuf = source.extract().map_err(|_| {
            bad(format!(
                "model: expected a path or a model name, got {}",
                source
                    .get_type()
                    .name()
                    .map_or_else(|_| "?".into(), |n| n.to_string())
            ))
        })?;
        let text = path.to_string_lossy().to_string();
        // What is not a model name is a path, and a missing one gets the CLI's error.
        let looks_like_path = path.extension().is_some() || path.components().count() > 1;
        let template = if path.exists() || looks_like_path {
            lfit::api::load_model(Some(&path), "default").py_err()?
        } else if SHIPPED.contains(&text.as_str()) {
            let file = shipped_dir(py)?.join(format!("{text}.npz"));
            lfit::api::load_model(Some(&file), "default").py_err()?
        } else if text == "morphable" || lfit::model::BodyShape::named(&text).is_some() {
            lfit::api::load_model(None, &text).py_err()?
        } else {
            return Err(bad(format!(
                "model '{text}': no such file, and not a model name (shipped: {}; procedural: morphable, {})",
                SHIPPED.join(", "),
                lfit::model::BodyShape::NAMES.join(", ")
            )));
        };
        Ok(Self {
            template: Arc::new(template),
        })
    }

    /// The model's id (datasets and checkpoints record it).
    #[getter]
    fn id(&self) -> String {
        self.template.id.clone()
    }

    /// Length of a full parameter vector: `3 + 3J + B + E`.
    #[getter]
    fn dim(&self) -> usize {
        self.template.layout().dim()
    }

    /// Length of the pose part: `3 + 3J` (translation, then an axis-angle per joint).
    #[getter]
    fn pose_dim(&self) -> usize {
        self.template.layout().pose_dim()
    }

    /// Number of shape coefficients β (B).
    #[getter]
    fn shape_dim(&self) -> usize {
        self.template.layout().shape
    }

    /// Number of expression coefficients ψ (E).
    #[getter]
    fn expression_dim(&self) -> usize {
        self.template.layout().expression
    }

    /// The parameter layout: `{"dim", "names": [entry names], "blocks": {"translation": (start,
    /// end), "rotations": ..., "shape": ..., "expression": ...}}` (empty blocks left out).
    #[getter]
    fn layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let l = self.template.layout();
        let blocks = PyDict::new(py);
        for b in [
            Block::Translation,
            Block::Rotations,
            Block::Shape,
            Block::Expression,
        ] {
            let r = l.range(b);
            if !r.is_empty() {
                blocks.set_item(b.name(), PyTuple::new(py, [r.start, r.end])?)?;
            }
        }
        let d = PyDict::new(py);
        d.set_item("dim", l.dim())?;
        d.set_item("names", l.names())?;
        d.set_item("blocks", blocks)?;
        Ok(d)
    }

    /// Joint names, in parameter order.
    #[getter]
    fn joint_names(&self) -> Vec<String> {
        self.template
            .rig
            .joints
            .iter()
            .map(|j| j.name.clone())
            .collect()
    }

    /// Parent index of every joint (-1 for the root).
    #[getter]
    fn parents(&self) -> Vec<i64> {
        self.template
            .rig
            .joints
            .iter()
            .map(|j| j.parent.map_or(-1, |p| p as i64))
            .collect()
    }

    /// Marker names of the `markers` modality (the model's markers, in observation order).
    #[getter]
    fn marker_names(&self) -> Vec<String> {
        self.template
            .rig
            .markers
            .iter()
            .map(|m| m.name.clone())
            .collect()
    }

    /// Triangles, `(F, 3)` int64 vertex indices.
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let flat: Vec<i64> = self
            .template
            .faces
            .iter()
            .flat_map(|f| f.map(i64::from))
            .collect();
        Ok(PyArray1::from_vec(py, flat)
            .reshape([self.template.faces.len(), 3])?
            .into_any())
    }

    /// Rest (template) vertices, `(V, 3)` float64, metres.
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let flat: Vec<f64> = self
            .template
            .vertices
            .iter()
            .flat_map(|v| [v.x as f64, v.y as f64, v.z as f64])
            .collect();
        array_nd(py, flat, &[self.template.num_vertices(), 3])
    }

    /// Everything the model holds, as `lfit model info` prints it (joints with parents, parts
    /// and limits; parameter blocks and names; markers; shape spaces; provenance).
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, &lfit::api::model_info(&self.template))
    }

    /// Posed vertices and joints of one parameter vector or a batch.
    ///
    /// `params`: `(P,)` or `(N, P)`, with P the full `dim` (pose, β, ψ) or `pose_dim` (then
    /// `shape` and `expression`, `(≤B,)`/`(N, ≤B)` and `(≤E,)`/`(N, ≤E)`, zero-padded, may be
    /// given). Returns `(vertices, joints)`: `(V, 3)` and `(J, 3)`, or `(N, V, 3)` and `(N, J,
    /// 3)`, float64 metres; vertices as `lfit template pose` writes them. `skinning`: `lbs`
    /// (linear blend skinning) or `dqs` (dual quaternions).
    #[pyo3(signature = (params, shape=None, expression=None, skinning="lbs"))]
    fn pose<'py>(
        &self,
        py: Python<'py>,
        params: &Bound<'py, PyAny>,
        shape: Option<&Bound<'py, PyAny>>,
        expression: Option<&Bound<'py, PyAny>>,
        skinning: &str,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let method = match skinning {
            "lbs" => SkinningMethod::Linear,
            "dqs" => SkinningMethod::DualQuaternion,
            other => {
                return Err(bad(format!(
                    "unknown skinning '{other}' (expected lbs or dqs)"
                )));
            }
        };
        let params = full_params(&self.template, params, shape, expression)?;
        let single = params.1;
        let params = params.0;
        let template = self.template.clone();
        let (vertices, joints) = py.detach(|| {
            let vertices = pose_vertices_batch(&template, &params, method);
            let joints: Vec<Vec<f64>> = params
                .iter()
                .map(|p| {
                    joint_transforms(&template, p)
                        .joints
                        .iter()
                        .flat_map(|j| j.to_array())
                        .collect()
                })
                .collect();
            (vertices, joints)
        });
        let (n, nv, nj) = (
            params.len(),
            self.template.num_vertices(),
            self.template.rig.num_joints(),
        );
        let v: Vec<f64> = vertices
            .iter()
            .flatten()
            .flat_map(|v| [v.x as f64, v.y as f64, v.z as f64])
            .collect();
        let j: Vec<f64> = joints.into_iter().flatten().collect();
        if single {
            Ok((array_nd(py, v, &[nv, 3])?, array_nd(py, j, &[nj, 3])?))
        } else {
            Ok((array_nd(py, v, &[n, nv, 3])?, array_nd(py, j, &[n, nj, 3])?))
        }
    }

    /// The β of least norm whose rest mesh is `height` metres tall, sole to crown — the shape
    /// prior's most likely body of that stature (`lfit fit --known-shape height:M`,
    /// `lfit_model::stature::shape_for_height`): `(B,)` float64. A height out of the shape
    /// box's reach, or not a positive number: `LfitError`.
    fn shape_for_height<'py>(&self, py: Python<'py>, height: f64) -> PyResult<Bound<'py, PyAny>> {
        let beta = lfit::model::stature::shape_for_height(&self.template, height)
            .map_err(|e| bad(e.to_string()))?;
        let n = beta.len();
        array_nd(py, beta, &[n])
    }

    /// The rest mesh's height in metres (its vertical extent, sole to crown) at shape `shape`
    /// (`(≤B,)`, zero-padded; default the mean shape): `lfit_model::stature::rest_height`.
    #[pyo3(signature = (shape=None))]
    fn rest_height(&self, shape: Option<&Bound<'_, PyAny>>) -> PyResult<f64> {
        let b = self.template.layout().shape;
        let beta = match shape {
            Some(s) => {
                let f = floats(s, "shape")?.finite("shape")?;
                if f.shape.len() != 1 || f.data.len() > b {
                    return Err(bad(format!(
                        "shape has shape {}, expected (≤{b},)",
                        crate::convert::shape_text(&f.shape)
                    )));
                }
                f.data
            }
            None => Vec::new(),
        };
        Ok(lfit::model::stature::rest_height(&self.template, &beta).0)
    }

    fn __repr__(&self) -> String {
        let l = self.template.layout();
        format!(
            "Model('{}', vertices={}, joints={}, shape={}, expression={})",
            self.template.id,
            self.template.num_vertices(),
            l.num_joints(),
            l.shape,
            l.expression
        )
    }
}

/// Full parameter vectors from `params` (full or pose-only) and optional shape/expression
/// blocks, checked (shapes, finite values); and whether the input was one vector.
fn full_params(
    template: &Template,
    params: &Bound<'_, PyAny>,
    shape: Option<&Bound<'_, PyAny>>,
    expression: Option<&Bound<'_, PyAny>>,
) -> PyResult<(Vec<Vec<f64>>, bool)> {
    let l = template.layout();
    let p = floats(params, "params")?.finite("params")?;
    let width = match p.shape.last() {
        Some(&w) if w == l.dim() => l.dim(),
        _ => l.pose_dim(),
    };
    let (rows, single) = p.rows(width, "params").map_err(|_| {
        bad(format!(
            "params has shape {}, expected ({pd},) or (N, {pd}) (3 + 3 × {} joints of '{}'){}",
            crate::convert::shape_text(&p.shape),
            l.num_joints(),
            template.id,
            if l.dim() > l.pose_dim() {
                format!(
                    ", or the full {} entries with shape and expression",
                    l.dim()
                )
            } else {
                String::new()
            },
            pd = l.pose_dim()
        ))
    })?;
    let n = rows.len();
    let mut out: Vec<Vec<f64>> = rows.iter().map(|r| r.to_vec()).collect();
    for (block, what, size) in [
        (shape, "shape", l.shape),
        (expression, "expression", l.expression),
    ] {
        let Some(b) = block.filter(|b| !b.is_none()) else {
            if width == l.pose_dim() {
                for row in &mut out {
                    row.resize(row.len() + size, 0.0);
                }
            }
            continue;
        };
        if width == l.dim() && l.dim() > l.pose_dim() {
            return Err(bad(format!(
                "{what} given twice: params already holds all {} entries",
                l.dim()
            )));
        }
        let f = floats(b, what)?.finite(what)?;
        let k = *f.shape.last().unwrap_or(&0);
        if k > size {
            return Err(bad(format!(
                "{what} has {k} numbers, but the model '{}' has only {size}",
                template.id
            )));
        }
        let (brows, bsingle) = f.rows(k, what)?;
        let brows: Vec<&[f64]> = match (bsingle, brows.len()) {
            (true, _) => vec![brows.first().copied().unwrap_or(&[]); n],
            (false, m) if m == n && !single => brows,
            (false, m) => {
                return Err(bad(format!(
                    "{what} has {m} rows for {} parameter vector{}",
                    n,
                    if n == 1 { "" } else { "s" }
                )));
            }
        };
        for (row, b) in out.iter_mut().zip(brows) {
            row.extend_from_slice(b);
            row.resize(row.len() + size - b.len(), 0.0);
        }
    }
    Ok((out, single))
}
