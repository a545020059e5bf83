//! Pictures of fits (`lfit render`, and the best/median/worst frames in bench and quickstart
//! reports): a small software renderer, written for lfit.
//!
//! - [`raster`]: z-buffered triangles with Gouraud colours, discs, rings, lines, captions, PNG;
//! - [`scene`]: front/side orthographic views and calibrated camera views of meshes (fit in
//!   colour, ground truth as a grey ghost with its outline) with observations on top;
//! - this module: the scene of one dataset frame — posed meshes, the frame's observations —
//!   shared by the command ([`cli`]) and the reports ([`pictures`]).

pub mod cli;
pub mod pictures;
pub mod raster;
pub mod scene;

use glam::{DVec2, DVec3, Vec3};
use lfit_model::observe::Sensor;
use lfit_model::skinning::{SkinningMethod, pose_vertices};
use lfit_model::template::Template;
use lfit_synth::{Dataset, Observations};

pub use cli::{RenderArgs, render};
use scene::{OBSERVED, Panel, Point, Role, View};

/// Hand colours of the `hmd` modality: headset, wrists, hand tips.
const HEADSET: [u8; 3] = [230, 120, 0];
const WRIST: [u8; 3] = [200, 40, 160];

/// What one frame row shows: its fitted parameters (if any) and a label.
#[derive(Debug, Clone)]
pub struct FrameRow {
    pub frame: usize,
    pub fit: Option<Vec<f64>>,
    pub label: String,
}

/// What a dataset frame's observations draw: world points and segments, and per camera its 2D
/// points (and mask).
#[derive(Debug, Clone, Default)]
pub struct Overlay {
    pub points: Vec<Point>,
    pub segments: Vec<(DVec3, DVec3, [u8; 3])>,
    /// 2D observations in the camera view (empty for 3D modalities).
    pub pixels: Vec<Point>,
    pub mask: Option<lfit_model::scan::Mask>,
}

fn dvec(v: &[f64], at: usize) -> DVec3 {
    DVec3::new(v[at], v[at + 1], v[at + 2])
}

/// The observations of `frame` (in range) of `dataset`, with camera `camera`'s 2D points.
pub fn overlay(dataset: &Dataset, frame: usize, camera: usize) -> Overlay {
    let mut out = Overlay::default();
    match (&dataset.observations, &dataset.sensor) {
        (Observations::Sparse { values, visible }, sensor) => {
            let (v, vis) = (&values[frame], &visible[frame]);
            match sensor {
                Sensor::Markers(_) => {
                    for k in 0..v.len() / 3 {
                        if vis[3 * k] {
                            out.points.push(Point::World(dvec(v, 3 * k), OBSERVED));
                        }
                    }
                }
                Sensor::Keypoints2d(setup) => {
                    let cams = setup.cameras.len().max(1);
                    let nj = v.len() / (2 * cams);
                    if camera < setup.cameras.len() {
                        for j in 0..nj {
                            let i = 2 * (camera * nj + j);
                            if vis[i] {
                                out.pixels
                                    .push(Point::Pixel(DVec2::new(v[i], v[i + 1]), OBSERVED));
                            }
                        }
                    }
                }
                // One camera: every seen landmark.
                Sensor::Landmarks2d(_) => {
                    for k in 0..v.len() / 2 {
                        if vis[2 * k] {
                            out.pixels
                                .push(Point::Pixel(DVec2::new(v[2 * k], v[2 * k + 1]), OBSERVED));
                        }
                    }
                }
                Sensor::Hmd(_) if v.len() >= lfit_model::observe::HMD_DIM => {
                    // Headset, left wrist, right wrist: R (9, row-major) then t (3); then the
                    // hand tips.
                    use lfit_model::observe::hmd_layout;
                    for d in 0..hmd_layout::DEVICES {
                        let o = hmd_layout::device(d);
                        if !vis[o] {
                            continue;
                        }
                        let p = dvec(v, hmd_layout::position(d));
                        let color = if d == 0 { HEADSET } else { WRIST };
                        out.points.push(Point::World(p, color));
                        if d == 0 {
                            // The headset looks along its −z axis: the third column of R.
                            let z = DVec3::new(v[o + 2], v[o + 5], v[o + 8]);
                            out.segments.push((p, p - 0.2 * z, HEADSET));
                        }
                    }
                    for k in 0..2 {
                        let o = hmd_layout::tip(k);
                        if vis[o] {
                            let tip = dvec(v, o);
                            out.points.push(Point::World(tip, OBSERVED));
                            let w = hmd_layout::tip_device(k);
                            if vis[hmd_layout::device(w)] {
                                let wrist = dvec(v, hmd_layout::position(w));
                                out.segments.push((wrist, tip, WRIST));
                            }
                        }
                    }
                }
                _ => {}
            }
        }
        (
            Observations::Scan {
                points, visible, ..
            },
            _,
        ) => {
            // Every 8th visible scan point, so that the body stays visible.
            out.points.extend(
                points[frame]
                    .iter()
                    .zip(&visible[frame])
                    .filter(|(_, v)| **v)
                    .step_by(8)
                    .map(|(p, _)| Point::World(p.as_dvec3(), OBSERVED)),
            );
        }
        (Observations::Silhouettes { masks }, _) => {
            out.mask = masks[frame].get(camera).cloned();
        }
    }
    out
}

/// The camera that a frame's pictures add as a third view: `keypoints2d`, `silhouettes` and
/// `landmarks2d` observe in cameras, the others in 3D.
pub fn view_camera(dataset: &Dataset, camera: usize) -> Option<lfit_model::camera::Camera> {
    match &dataset.sensor {
        Sensor::Keypoints2d(_) | Sensor::Silhouettes(_) | Sensor::Landmarks2d(_) => {
            dataset.sensor.cameras().get(camera).copied()
        }
        _ => None,
    }
}

/// The panels of one frame row: front, side and (camera modalities) the camera view, with the
/// fit (blue), the ground truth (grey ghost, or the body itself without a fit) and the frame's
/// observations.
pub fn frame_panels(
    template: &Template,
    dataset: &Dataset,
    row: &FrameRow,
    camera: usize,
    skinning: SkinningMethod,
) -> Vec<Panel> {
    let pose = |p: &[f64]| -> Vec<Vec3> { pose_vertices(template, p, skinning) };
    let mut meshes = Vec::new();
    if let Some(fit) = &row.fit {
        meshes.push((pose(fit), Role::Fit));
    }
    if let Some(gt) = dataset.ground_truth(row.frame) {
        let role = if row.fit.is_some() {
            Role::Truth
        } else {
            Role::Body
        };
        meshes.push((pose(gt), role));
    }
    let ov = overlay(dataset, row.frame, camera);
    let mut views = vec![(View::Front, "front"), (View::Side, "side")];
    if let Some(cam) = view_camera(dataset, camera) {
        views.push((View::Camera(cam), "camera"));
    }
    views
        .into_iter()
        .enumerate()
        .map(|(k, (view, name))| {
            let name = if name == "camera" {
                format!("camera {camera}")
            } else {
                name.to_string()
            };
            // The row's label instead of the first view's name (the title names the views).
            let label = if row.label.is_empty() || k > 0 {
                name
            } else {
                row.label.clone()
            };
            let camera_view = matches!(view, View::Camera(_));
            let mut panel = Panel::new(view, label);
            panel.meshes = meshes.clone();
            panel.points = if camera_view {
                ov.pixels.clone()
            } else {
                ov.points.clone()
            };
            panel.segments = ov.segments.clone();
            if camera_view {
                panel.mask = ov.mask.clone();
            }
            panel
        })
        .collect()
}

/// The views of a frame row, for titles: `front | side` and the camera if any.
pub fn view_names(dataset: &Dataset, camera: usize) -> String {
    match view_camera(dataset, camera) {
        Some(_) => format!("front | side | camera {camera}"),
        None => "front | side".to_string(),
    }
}

/// The legend of a picture of fits.
pub fn legend(has_fit: bool, has_truth: bool) -> &'static str {
    match (has_fit, has_truth) {
        (true, true) => "fit blue, truth grey, observed red (ring: hidden)",
        (true, false) => "fit blue, observed red (ring: hidden)",
        (false, true) => "truth, observed red (ring: hidden)",
        (false, false) => "observed red (no ground truth)",
    }
}
