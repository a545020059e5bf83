//! The `landmarks2d` observation model (papers/002 §3.3): dense face landmarks — model vertices —
//! projected by one calibrated perspective camera.

use glam::DVec3;
use rand::RngCore;

use super::builtin::{DEPTH_FLOOR, combine_rows, project, project_camera_adjoint};
use super::{
    LandmarkSetup, ObservationModel, PoseGradient, PoseJacobian, PosedView, ResidualGroup,
    check_vertices, uniform_groups,
};
use crate::camera::Camera;
use crate::error::{ModelError, Result};
use crate::noise::{NoiseConfig, corrupt_pixels};
use crate::observe::Scales;
use crate::skinning::vertex_normals;
use crate::template::Template;

/// Distance of the default camera in front of the landmarks' centre (metres): a head fills about
/// half of the 512-pixel image.
pub const LANDMARK_CAMERA_DISTANCE: f64 = 0.6;
/// papers/002 supp.: focal length (512, 512), principal point (256, 256).
pub const LANDMARK_FOCAL: f64 = 512.0;
/// papers/002 supp.: a 512 × 512 image.
pub const LANDMARK_IMAGE: u32 = 512;

impl LandmarkSetup {
    /// The setup of `template`'s `landmark_vertices`: papers/002's camera (f = 512 px, principal
    /// point (256, 256), 512 × 512) [`LANDMARK_CAMERA_DISTANCE`] in front of the landmarks' rest
    /// centre (+z, where a face model looks), and the landmarks' rest normals.
    pub fn for_template(template: &Template) -> Self {
        let vertices = template.info.landmark_vertices.clone();
        let rest = template.rest_positions();
        let centre = if vertices.is_empty() {
            DVec3::ZERO
        } else {
            vertices
                .iter()
                .filter_map(|&v| rest.get(v as usize))
                .sum::<DVec3>()
                / vertices.len() as f64
        };
        let camera = Camera::look_at(
            centre + DVec3::Z * LANDMARK_CAMERA_DISTANCE,
            centre,
            LANDMARK_FOCAL,
            LANDMARK_IMAGE,
            LANDMARK_IMAGE,
        );
        Self::with_rest(template, &rest, camera, vertices)
    }

    /// A setup of `vertices` seen by `camera`; the normals are `template`'s rest normals (zero for
    /// a vertex out of range, which [`ObservationModel::validate`] refuses).
    pub fn new(template: &Template, camera: Camera, vertices: Vec<u32>) -> Self {
        Self::with_rest(template, &template.rest_positions(), camera, vertices)
    }

    /// [`Self::new`] with the template's rest vertices already at hand.
    fn with_rest(template: &Template, rest: &[DVec3], camera: Camera, vertices: Vec<u32>) -> Self {
        let rest: Vec<glam::Vec3> = rest.iter().map(|p| p.as_vec3()).collect();
        let all = vertex_normals(&rest, &template.faces);
        let normals = vertices
            .iter()
            .map(|&v| {
                all.get(v as usize)
                    .map_or([0.0; 3], |n| n.as_dvec3().to_array())
            })
            .collect();
        Self {
            camera,
            vertices,
            normals,
        }
    }

    /// Whether landmark `k` at world position `p` faces the camera: its rest normal, carried by
    /// the skinning rotations of its vertex, points to the camera centre.
    fn faces_camera(&self, posed: &PosedView<'_>, k: usize, p: DVec3) -> bool {
        let n = DVec3::from_array(self.normals[k]);
        let v = self.vertices[k] as usize;
        let world = posed.template().rig.weights[v]
            .iter()
            .fold(DVec3::ZERO, |acc, &(j, w)| {
                acc + w * (posed.joint_rotation(j) * n)
            });
        world.dot(self.camera.center() - p) > 0.0
    }
}

impl ObservationModel for LandmarkSetup {
    fn name(&self) -> &str {
        "landmarks2d"
    }

    fn validate(&self, template: &Template) -> Result<()> {
        if self.vertices.is_empty() {
            return Err(ModelError::Config(format!(
                "model '{}' has no landmarks for the landmarks2d modality (the model file's landmark_vertices: lfit model import-makehuman --part face writes them)",
                template.id
            )));
        }
        if self.normals.len() != self.vertices.len() {
            return Err(ModelError::Shape {
                what: "landmark normals".into(),
                expected: self.vertices.len().to_string(),
                got: self.normals.len().to_string(),
            });
        }
        check_vertices(template, &self.vertices, "landmark vertex")?;
        self.camera.validate(0)
    }

    fn dim(&self, _: &Template) -> usize {
        2 * self.vertices.len()
    }

    fn groups(&self, _: &Template, scales: &Scales) -> Vec<ResidualGroup> {
        uniform_groups(self.vertices.len(), 2, scales.pixel)
    }

    /// Every landmark's pixel; it is seen when it is in front of the camera (depth > 1 cm),
    /// projects inside the image and faces the camera.
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        let cam = &self.camera;
        for (k, &v) in self.vertices.iter().enumerate() {
            let p = posed.vertex(v as usize);
            let (uv, _) = project(cam, p);
            values[2 * k..2 * k + 2].copy_from_slice(&uv);
            let seen = cam.to_camera(p).z > DEPTH_FLOOR
                && cam.in_image(glam::DVec2::new(uv[0], uv[1]))
                && self.faces_camera(posed, k, p);
            visible[2 * k..2 * k + 2].fill(seen);
        }
    }

    fn jacobian(&self, posed: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        let d = jac.dim();
        let rot_t = self.camera.rot().transpose();
        let mut rows = vec![0.0; 3 * d];
        for (k, &v) in self.vertices.iter().enumerate() {
            let p = jac.vertex(v as usize, &mut rows);
            debug_assert!((p - posed.vertex(v as usize)).length() < 1e-9);
            let (_, dq) = project(&self.camera, p);
            for (r, dq) in dq.iter().enumerate() {
                let row = 2 * k + r;
                combine_rows(&mut out[row * d..(row + 1) * d], rot_t * *dq, &rows, d);
            }
        }
    }

    fn vertices_read(&self) -> Vec<u32> {
        self.vertices.clone()
    }

    fn backprop(&self, posed: &PosedView<'_>, dpred: &[f64], grad: &mut PoseGradient<'_, '_>) {
        let rot_t = self.camera.rot().transpose();
        for (k, &v) in self.vertices.iter().enumerate() {
            let (gu, gv) = (dpred[2 * k], dpred[2 * k + 1]);
            if gu == 0.0 && gv == 0.0 {
                continue;
            }
            let q = self.camera.to_camera(posed.vertex(v as usize));
            grad.vertex(
                v as usize,
                rot_t * project_camera_adjoint(&self.camera, q, gu, gv),
            );
        }
    }

    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        corrupt_pixels(values, visible, noise, rng);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::default_template;
    use crate::observe::{Modality, Sensor};
    use crate::pose::{POSE_DIM, rot_offset};
    use crate::skeleton::HEAD;

    /// The default body with landmarks on its head: every vertex the head joint dominates.
    fn headed() -> (Template, Vec<u32>) {
        let mut t = default_template();
        let dom = t.dominant_joint();
        let head: Vec<u32> = (0..t.num_vertices() as u32)
            .filter(|&v| dom[v as usize] == HEAD)
            .collect();
        t.info.landmark_vertices = head.clone();
        (t, head)
    }

    #[test]
    fn papers_camera_looks_at_the_landmarks_from_the_front() {
        let (t, head) = headed();
        let Sensor::Landmarks2d(s) = Sensor::default_for(Modality::Landmarks2d, &t) else {
            unreachable!()
        };
        s.validate(&t).unwrap();
        assert_eq!((s.camera.fx, s.camera.fy), (512.0, 512.0));
        assert_eq!((s.camera.cx, s.camera.cy), (256.0, 256.0));
        assert_eq!((s.camera.width, s.camera.height), (512, 512));
        assert_eq!(s.vertices, head);
        // The subject's left (+x) is on the image's right, up is up.
        let c = s.camera.center();
        let uv = |p: DVec3| s.camera.project(p).unwrap();
        let centre = c - DVec3::Z * LANDMARK_CAMERA_DISTANCE;
        assert!((uv(centre) - glam::DVec2::new(256.0, 256.0)).length() < 1e-9);
        assert!(uv(centre + 0.05 * DVec3::X).x > 256.0);
        assert!(uv(centre + 0.05 * DVec3::Y).y < 256.0);
    }

    /// Visibility follows the skinned normal: the face is seen at rest and the back of the head
    /// is not; turned half round, the other way.
    #[test]
    fn a_landmark_is_seen_when_its_vertex_faces_the_camera() {
        let (t, head) = headed();
        let sensor = Sensor::default_for(Modality::Landmarks2d, &t);
        let Sensor::Landmarks2d(s) = &sensor else {
            unreachable!()
        };
        let mut pose = [0.0; POSE_DIM];
        let rest = sensor.predict_sparse(&t, &pose);
        let (mut front, mut back) = (0, 0);
        for (k, n) in s.normals.iter().enumerate() {
            if n[2] > 0.3 {
                assert!(rest.visible[2 * k], "front landmark {k} hidden");
                front += 1;
            } else if n[2] < -0.3 {
                assert!(!rest.visible[2 * k], "back landmark {k} seen");
                back += 1;
            }
        }
        assert!(front > 10 && back > 10, "{front} {back}");
        // Turn the head by 180° about the vertical (its own joint): front and back swap.
        pose[rot_offset(HEAD) + 1] = std::f64::consts::PI;
        let turned = sensor.predict_sparse(&t, &pose);
        for (k, n) in s.normals.iter().enumerate() {
            if n[2].abs() > 0.3 {
                assert_eq!(turned.visible[2 * k], n[2] < 0.0, "landmark {k}");
            }
        }
        assert_eq!(rest.values.len(), 2 * head.len());
    }

    #[test]
    fn bad_setups_are_refused_with_a_reason() {
        let (t, _) = headed();
        let mut bare = default_template();
        bare.info.landmark_vertices.clear();
        let err = Sensor::default_for(Modality::Landmarks2d, &bare)
            .validate(&bare)
            .unwrap_err()
            .to_string();
        assert!(err.contains("no landmarks"), "{err}");
        let Sensor::Landmarks2d(good) = Sensor::default_for(Modality::Landmarks2d, &t) else {
            unreachable!()
        };
        let mut outside = good.clone();
        outside.vertices[3] = t.num_vertices() as u32 + 7;
        let err = outside.validate(&t).unwrap_err().to_string();
        assert!(err.contains("landmark vertex"), "{err}");
        assert!(err.contains(&(t.num_vertices() + 7).to_string()), "{err}");
        let mut flat = good.clone();
        flat.camera.fx = 0.0;
        let err = flat.validate(&t).unwrap_err().to_string();
        assert!(err.contains("focal"), "{err}");
        let mut short = good;
        short.normals.pop();
        assert!(short.validate(&t).is_err());
    }
}
