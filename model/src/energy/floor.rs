//! The `floor` term ([`FloorPrior`], [`super::Energy::with_floor`]): the ground the subject stands
//! on, a horizontal plane at a known height of the world's up axis (`+y`, as the models and the
//! synthesized captures are built).
//!
//! One camera sees a body along its rays: a larger subject farther away projects like a smaller
//! one nearer, and a learned or classical fit settles that trade-off with the shape prior alone
//! (docs/results/captured-motion.md, rounds 29–35). The floor breaks it the way monocular
//! capture does: a foot on a known plane fixes where along its ray the foot is. The term reads
//! the lowest of a fixed set of sole vertices (the posed mesh's lowest point wherever the feet
//! are below the knees) and measures its height `y` against the floor `F`:
//!
//! - [`FloorForm::Above`]: `d = min(y − F, 0)` — nothing goes through the floor (a one-sided
//!   penalty; jumps, sitting and lying are untouched);
//! - [`FloorForm::Contact`]: `d = y − F` — the lowest sole touches the floor (standing, walking,
//!   running frames with a foot down; wrong in a jump's flight).
//!
//! Its value is `a d²` with `a = λ_data / (n σ²)`, one visible group of the data term at standard
//! deviation `σ` (as the height prior and the anchor weigh), one residual row `√a d` whose
//! Jacobian is the lowest vertex's height row.

use glam::DVec3;

use crate::body::jacobian::PointJacobians;
use crate::body::kinematics::{Adjoint, Kinematics, SkinTable};
use crate::error::{ModelError, Result};
use crate::template::Template;

/// How far above the rest mesh's lowest point a vertex may lie and still be a sole candidate
/// (metres): the soles and the toes' and heels' undersides of a standing rest pose.
pub const SOLE_BAND_M: f64 = 0.03;

/// The side of the horizontal grid (metres) that thins the sole candidates: the lowest
/// candidate of each cell is kept, a few dozen per foot on an adult body.
pub const SOLE_CELL_M: f64 = 0.03;

/// Which side of the floor the term penalises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FloorForm {
    /// The lowest sole may not go below the floor (one-sided).
    Above,
    /// The lowest sole lies on the floor (two-sided).
    Contact,
}

impl FloorForm {
    pub fn name(self) -> &'static str {
        match self {
            Self::Above => "above",
            Self::Contact => "contact",
        }
    }
}

impl std::str::FromStr for FloorForm {
    type Err = ModelError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "above" => Ok(Self::Above),
            "contact" => Ok(Self::Contact),
            _ => Err(ModelError::Config(format!(
                "unknown floor form '{s}': above or contact"
            ))),
        }
    }
}

/// The ground plane `y = F` and the sole vertices measured against it.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorPrior {
    height_m: f64,
    std_m: f64,
    form: FloorForm,
    /// The template it was made for (`id`, vertex count), checked where it is used.
    template: (String, usize),
    /// Sole candidates, ascending vertex order.
    vertices: Vec<usize>,
}

impl FloorPrior {
    /// The floor at height `height_m` (metres, world `+y`) with standard deviation `std_m` on
    /// `template`'s soles. One-line errors where the height is not finite or the standard
    /// deviation is not finite and positive.
    pub fn new(template: &Template, height_m: f64, std_m: f64, form: FloorForm) -> Result<Self> {
        let height_m = finite_height(height_m)?;
        check_std(std_m)?;
        let vertices = sole_vertices(template);
        if vertices.is_empty() {
            return Err(ModelError::Config(format!(
                "model '{}' has no vertices for a floor term",
                template.id
            )));
        }
        Ok(Self {
            height_m,
            std_m,
            form,
            template: (template.id.clone(), template.vertices.len()),
            vertices,
        })
    }

    /// The same floor at another height (the candidates kept).
    pub fn at(&self, height_m: f64) -> Result<Self> {
        Ok(Self {
            height_m: finite_height(height_m)?,
            ..self.clone()
        })
    }

    /// The same floor with another standard deviation (finite and positive, metres).
    pub fn with_std(&self, std_m: f64) -> Result<Self> {
        check_std(std_m)?;
        Ok(Self {
            std_m,
            ..self.clone()
        })
    }

    /// The floor's height (metres, world `+y`).
    pub fn height_m(&self) -> f64 {
        self.height_m
    }

    /// Its standard deviation (metres).
    pub fn std_m(&self) -> f64 {
        self.std_m
    }

    pub fn form(&self) -> FloorForm {
        self.form
    }

    /// The sole candidates (vertex indices).
    pub fn vertices(&self) -> &[usize] {
        &self.vertices
    }

    pub(super) fn made_for(&self, template: &Template) -> Result<()> {
        if self.template != (template.id.clone(), template.vertices.len()) {
            return Err(ModelError::Config(format!(
                "a floor made for model '{}' ({} vertices) cannot serve '{}' ({} vertices)",
                self.template.0,
                self.template.1,
                template.id,
                template.vertices.len()
            )));
        }
        Ok(())
    }

    /// The lowest posed candidate of `kin`: its vertex and posed position (the first of equals
    /// in vertex order).
    pub(crate) fn lowest(&self, kin: &Kinematics, skin: &SkinTable) -> (usize, DVec3) {
        let mut best = (self.vertices[0], DVec3::splat(f64::INFINITY));
        for &v in &self.vertices {
            let p = kin.skin(skin.weights(v), kin.rest(&skin.rest, v));
            if p.y < best.1.y {
                best = (v, p);
            }
        }
        best
    }

    /// The lowest sole's height (metres) in `kin`.
    pub(crate) fn lowest_height(&self, kin: &Kinematics, skin: &SkinTable) -> f64 {
        self.lowest(kin, skin).1.y
    }

    /// The signed offset `d` of a lowest sole at height `y` (zero above the floor for `Above`).
    fn offset(&self, y: f64) -> f64 {
        let d = y - self.height_m;
        match self.form {
            FloorForm::Above => d.min(0.0),
            FloorForm::Contact => d,
        }
    }

    /// `d` and, where it is not zero and `adjoint` is given, `2 a d ∂y` into the adjoint (`a`
    /// the term's weight).
    pub(super) fn evaluate(
        &self,
        kin: &Kinematics,
        skin: &SkinTable,
        adjoint: Option<(&mut Adjoint, f64)>,
    ) -> f64 {
        let (v, p) = self.lowest(kin, skin);
        let d = self.offset(p.y);
        if let Some((adj, a)) = adjoint
            && d != 0.0
        {
            let g = DVec3::new(0.0, 2.0 * a * d, 0.0);
            adj.skinned_point(kin, skin.weights(v), v, kin.rest(&skin.rest, v), g);
        }
        d
    }

    /// The residual row `c0 d` and, with `jacobians`, its Jacobian row `c0 ∂y` into `row`
    /// (`dim` entries, written only where `d` is not zero: the caller gives it zeroed).
    pub(super) fn residual(
        &self,
        kin: &Kinematics,
        skin: &SkinTable,
        jacobians: Option<&mut PointJacobians<'_>>,
        c0: f64,
        row: &mut [f64],
    ) -> f64 {
        let (v, p) = self.lowest(kin, skin);
        let d = self.offset(p.y);
        if let Some(pj) = jacobians
            && d != 0.0
        {
            let dim = pj.dim;
            let mut jp = vec![0.0; 3 * dim];
            pj.skinned_point(v, &mut jp);
            for (o, j) in row.iter_mut().zip(&jp[dim..2 * dim]) {
                *o = c0 * j;
            }
        }
        c0 * d
    }
}

/// `height_m` if finite; the one-line error of a floor height otherwise.
fn finite_height(height_m: f64) -> Result<f64> {
    if height_m.is_finite() {
        Ok(height_m)
    } else {
        Err(ModelError::Config(format!(
            "floor height {height_m}: must be a finite number of metres"
        )))
    }
}

fn check_std(std_m: f64) -> Result<()> {
    if std_m.is_finite() && std_m > 0.0 {
        Ok(())
    } else {
        Err(ModelError::Config(format!(
            "floor standard deviation {std_m}: must be finite and positive (metres)"
        )))
    }
}

/// The sole candidates of `template`: the rest mesh's vertices (β = ψ = 0) within
/// [`SOLE_BAND_M`] of its lowest point, thinned to the lowest of each [`SOLE_CELL_M`] cell of the
/// horizontal `(x, z)` grid; ascending vertex order.
pub fn sole_vertices(template: &Template) -> Vec<usize> {
    let morph = &template.morph;
    let rest: Vec<DVec3> = (0..template.vertices.len())
        .map(|v| morph.rest_vertex(v, template.vertices[v].as_dvec3(), &[], &[]))
        .collect();
    let Some(floor) = rest.iter().map(|p| p.y).min_by(f64::total_cmp) else {
        return Vec::new();
    };
    let mut cells: std::collections::BTreeMap<(i64, i64), usize> = Default::default();
    for (v, p) in rest.iter().enumerate() {
        if p.y > floor + SOLE_BAND_M {
            continue;
        }
        let key = (
            (p.x / SOLE_CELL_M).floor() as i64,
            (p.z / SOLE_CELL_M).floor() as i64,
        );
        let slot = cells.entry(key).or_insert(v);
        if p.y < rest[*slot].y {
            *slot = v;
        }
    }
    let mut vertices: Vec<usize> = cells.into_values().collect();
    vertices.sort_unstable();
    vertices
}
