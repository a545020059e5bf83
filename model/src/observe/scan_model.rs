//! The `scan` observation model: a dense point cloud, one point per template vertex (known
//! correspondences), with Gaussian jitter and holes. papers/000's scan energy does not compare it
//! entry by entry: it compares the posed surface with a distance transform built from the visible
//! points (ED, ES) and with the scan's silhouettes (EJ), which the energy keeps as its own terms.

use rand::RngCore;

use super::{
    ObservationModel, PoseGradient, PoseJacobian, PosedView, ResidualGroup, ScanSetup,
    check_vertices, points_from_values, uniform_groups,
};
use crate::error::{ModelError, Result};
use crate::noise::{NoiseConfig, jitter_points, punch_holes};
use crate::observe::Scales;
use crate::template::Template;

impl ObservationModel for ScanSetup {
    fn name(&self) -> &str {
        "scan"
    }

    fn validate(&self, template: &Template) -> Result<()> {
        if !(self.voxel_size.is_finite() && self.voxel_size > 0.0) {
            return Err(ModelError::Setting {
                name: "voxel_size",
                value: self.voxel_size.to_string(),
                reason: "must be positive".into(),
            });
        }
        check_vertices(template, &self.residual_vertices, "scan residual vertex")?;
        self.cameras
            .iter()
            .enumerate()
            .try_for_each(|(i, c)| c.validate(i))
    }

    /// One point per template vertex.
    fn dim(&self, template: &Template) -> usize {
        3 * template.num_vertices()
    }

    fn groups(&self, template: &Template, scales: &Scales) -> Vec<ResidualGroup> {
        uniform_groups(template.num_vertices(), 3, scales.position)
    }

    /// The posed surface as the renderers skin it ([`PosedView::mesh`]).
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        for (o, p) in values.chunks_exact_mut(3).zip(posed.mesh()) {
            o.copy_from_slice(&p.as_dvec3().to_array());
        }
        visible.fill(true);
    }

    fn jacobian(&self, _: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        let d = jac.dim();
        for (v, rows) in out.chunks_exact_mut(3 * d).enumerate() {
            jac.vertex(v, rows);
        }
    }

    fn backprop(&self, _: &PosedView<'_>, dpred: &[f64], grad: &mut PoseGradient<'_, '_>) {
        for (v, g) in dpred.chunks_exact(3).enumerate() {
            grad.vertex(v, glam::DVec3::new(g[0], g[1], g[2]));
        }
    }

    /// Gaussian jitter of every point (f32, as the cloud is stored), then holes: spheres around
    /// random visible points whose points the scanner misses (their coordinates are kept).
    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        let mut points = points_from_values(values);
        let mut seen: Vec<bool> = visible.chunks_exact(3).map(|v| v[0]).collect();
        jitter_points(&mut points, noise.point_sigma, rng);
        punch_holes(
            &points,
            &mut seen,
            noise.scan_holes,
            noise.scan_hole_radius,
            rng,
        );
        for ((o, p), (vis, s)) in values
            .chunks_exact_mut(3)
            .zip(&points)
            .zip(visible.chunks_exact_mut(3).zip(seen))
        {
            o.copy_from_slice(&p.as_dvec3().to_array());
            vis.fill(s);
        }
    }
}
