//! Scenes: a grid of panels, each a view (front, side, or a calibrated camera) of some meshes —
//! the fit in colour, the ground truth as a grey ghost with its outline, or one body alone — with
//! observation points and segments on top, and a caption.
//!
//! World conventions (SPEC §3): y up, the subject faces +z, +x is the subject's left. The front
//! view looks at the subject's face (camera on +z looking along −z): image right is world +x (the
//! subject's left), image up is world +y. The side view looks at the subject's right side (camera
//! on −x looking along +x): image right is world +z (the subject faces image right). Both are
//! orthographic and share one scale in a scene, so panels compare sizes directly. A camera view
//! projects through the pinhole camera of the dataset and shows its whole image.

use glam::{DVec2, DVec3, Vec3};
use lfit_model::camera::Camera;
use lfit_model::scan::Mask;
use lfit_model::skinning::vertex_normals;

use super::raster::{Canvas, Layer, Rgb, ScreenVertex};

pub const BACKGROUND: Rgb = [250, 250, 250];
/// The fitted body.
pub const FIT: Rgb = [70, 130, 210];
/// A body drawn alone (rest pose, ground truth without a fit).
pub const BODY: Rgb = [205, 170, 140];
/// The ground truth as a ghost over the fit, and its outline.
pub const TRUTH: Rgb = [150, 150, 150];
pub const TRUTH_OUTLINE: Rgb = [70, 70, 70];
/// Observations (markers, keypoints, headset and hand targets).
pub const OBSERVED: Rgb = [220, 40, 40];
pub const TEXT: Rgb = [20, 20, 20];

/// How a view projects.
#[derive(Debug, Clone, PartialEq)]
pub enum View {
    /// Orthographic from the front (camera on +z).
    Front,
    /// Orthographic from the subject's right (camera on −x).
    Side,
    /// Through a pinhole camera; the panel shows its whole image.
    Camera(Camera),
}

/// How a mesh is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The fit: opaque, shaded in [`FIT`].
    Fit,
    /// A body alone: opaque, shaded in [`BODY`].
    Body,
    /// The ground truth next to a fit: a translucent grey ghost where it is in front of the
    /// opaque meshes (or alone) and its silhouette outline.
    Truth,
}

/// A point drawn on top of the meshes: a filled disc where it is not hidden by an opaque mesh,
/// a ring where it is (orthographic views only).
#[derive(Debug, Clone, PartialEq)]
pub enum Point {
    /// A world point.
    World(DVec3, Rgb),
    /// A pixel of a camera view's image (2D observations).
    Pixel(DVec2, Rgb),
}

/// One panel.
#[derive(Debug, Clone)]
pub struct Panel {
    pub view: View,
    pub label: String,
    pub meshes: Vec<(Vec<Vec3>, Role)>,
    pub points: Vec<Point>,
    /// World segments (e.g. the headset's viewing direction).
    pub segments: Vec<(DVec3, DVec3, Rgb)>,
    /// A foreground mask of a camera view, tinted under the meshes.
    pub mask: Option<Mask>,
}

impl Panel {
    pub fn new(view: View, label: impl Into<String>) -> Self {
        Self {
            view,
            label: label.into(),
            meshes: Vec::new(),
            points: Vec::new(),
            segments: Vec::new(),
            mask: None,
        }
    }
}

/// A grid of panels (row-major, `columns` wide) under a title.
#[derive(Debug, Clone)]
pub struct Scene {
    pub title: String,
    pub columns: usize,
    pub panels: Vec<Panel>,
}

/// Orthographic (u, v, depth) of a world point: u right, v up, depth away from the viewer.
fn ortho(view: &View, p: DVec3) -> (f64, f64, f64) {
    match view {
        View::Side => (p.z, p.y, p.x),
        _ => (p.x, p.y, -p.z),
    }
}

/// Maps world points to panel pixels (relative to the panel's top-left corner).
#[derive(Debug, Clone)]
struct Projector {
    view: View,
    scale: f64,
    /// Panel pixel of the framing centre.
    origin: DVec2,
    /// Orthographic (u, v) at the framing centre; camera views: the image centre.
    centre: DVec2,
}

impl Projector {
    /// Pixel and depth (smaller = nearer); `None` behind a camera.
    fn project(&self, p: DVec3) -> Option<(f32, f32, f32)> {
        match &self.view {
            View::Camera(cam) => {
                let q = cam.to_camera(p);
                if q.z <= 0.01 {
                    return None;
                }
                let uv = cam.project_camera(q);
                let (x, y) = self.pixel_of_image(uv);
                Some((x, y, (-1.0 / q.z) as f32))
            }
            view => {
                let (u, v, d) = ortho(view, p);
                Some((
                    (self.origin.x + self.scale * (u - self.centre.x)) as f32,
                    (self.origin.y - self.scale * (v - self.centre.y)) as f32,
                    d as f32,
                ))
            }
        }
    }

    /// Panel pixel of a camera-image pixel.
    fn pixel_of_image(&self, uv: DVec2) -> (f32, f32) {
        (
            (self.origin.x + self.scale * (uv.x - self.centre.x)) as f32,
            (self.origin.y + self.scale * (uv.y - self.centre.y)) as f32,
        )
    }

    /// Unit vector from `p` towards the viewer.
    fn towards_viewer(&self, p: DVec3) -> DVec3 {
        match &self.view {
            View::Front => DVec3::Z,
            View::Side => DVec3::NEG_X,
            View::Camera(cam) => (cam.center() - p).normalize_or_zero(),
        }
    }

    /// How much nearer a depth must be to count as in front (1 cm).
    fn depth_tolerance(&self, p: DVec3) -> f32 {
        match &self.view {
            View::Camera(cam) => {
                let z = cam.to_camera(p).z.max(0.01);
                (0.01 / (z * z)) as f32
            }
            _ => 0.01,
        }
    }
}

/// Pixel rectangle of a panel: x, y of the top-left corner, width, height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

/// Where everything goes in a `width × height` image: the title band height, the label band
/// height and each panel's drawing rectangle (below its label).
#[derive(Debug, Clone)]
pub struct Layout {
    pub title: u32,
    pub label: u32,
    pub cells: Vec<Rect>,
}

/// The grid of `scene` in a `width × height` image.
pub fn layout(scene: &Scene, width: u32, height: u32) -> Layout {
    let columns = scene.columns.max(1) as u32;
    let rows = scene.panels.len().div_ceil(scene.columns.max(1)).max(1) as u32;
    let title = if scene.title.is_empty() {
        0
    } else {
        (height / 24).min(width / 28).clamp(12, 26)
    };
    let cell_w = width / columns;
    let cell_h = height.saturating_sub(title) / rows;
    let label = (cell_h / 14).min(cell_w / 14).clamp(10, 20);
    let cells = (0..scene.panels.len() as u32)
        .map(|i| {
            let (r, c) = (i / columns, i % columns);
            Rect {
                x: c * cell_w,
                y: title + r * cell_h + label,
                w: cell_w,
                h: cell_h.saturating_sub(label),
            }
        })
        .collect();
    Layout {
        title,
        label,
        cells,
    }
}

/// One orthographic scale for every orthographic panel: the largest that fits each panel's
/// content (meshes and world points) into its rectangle with a margin.
fn common_scale(scene: &Scene, cells: &[Rect]) -> f64 {
    let mut scale = f64::INFINITY;
    for (panel, cell) in scene.panels.iter().zip(cells) {
        if matches!(panel.view, View::Camera(_)) {
            continue;
        }
        if let Some((lo, hi)) = bounds(panel) {
            let ext = (hi - lo).max(DVec2::splat(1e-3));
            let margin = 0.06 * f64::from(cell.w.min(cell.h)) + 2.0;
            let sx = (f64::from(cell.w) - 2.0 * margin).max(1.0) / ext.x;
            let sy = (f64::from(cell.h) - 2.0 * margin).max(1.0) / ext.y;
            scale = scale.min(sx.min(sy));
        }
    }
    if scale.is_finite() { scale } else { 1.0 }
}

/// Orthographic (u, v) bounds of a panel's meshes and world points.
fn bounds(panel: &Panel) -> Option<(DVec2, DVec2)> {
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    let mut eat = |p: DVec3| {
        let (u, v, _) = ortho(&panel.view, p);
        if u.is_finite() && v.is_finite() {
            lo = lo.min(DVec2::new(u, v));
            hi = hi.max(DVec2::new(u, v));
        }
    };
    for (mesh, _) in &panel.meshes {
        mesh.iter().for_each(|p| eat(p.as_dvec3()));
    }
    for p in &panel.points {
        if let Point::World(p, _) = p {
            eat(*p);
        }
    }
    (lo.x <= hi.x).then_some((lo, hi))
}

/// Camera-image bounds of a camera panel's meshes (vertices in front of the camera) and 2D
/// points.
fn camera_bounds(panel: &Panel, cam: &Camera) -> Option<(DVec2, DVec2)> {
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    let mut eat = |uv: DVec2| {
        if uv.is_finite() {
            lo = lo.min(uv);
            hi = hi.max(uv);
        }
    };
    for (mesh, _) in &panel.meshes {
        for p in mesh {
            if let Some(uv) = cam.project(p.as_dvec3()) {
                eat(uv);
            }
        }
    }
    for p in &panel.points {
        if let Point::Pixel(uv, _) = p {
            eat(*uv);
        }
    }
    (lo.x <= hi.x).then_some((lo, hi))
}

fn projector(panel: &Panel, cell: &Rect, scale: f64) -> Projector {
    let half = DVec2::new(f64::from(cell.w), f64::from(cell.h)) / 2.0;
    match &panel.view {
        View::Camera(cam) => {
            // Zoomed on the content (meshes and 2D points) with a margin, but never out beyond
            // the whole camera image.
            let (cw, ch) = (f64::from(cam.width), f64::from(cam.height));
            let (pw, ph) = (f64::from(cell.w), f64::from(cell.h));
            let whole = (pw / cw).min(ph / ch);
            let (scale, centre) = match camera_bounds(panel, cam) {
                Some((lo, hi)) => {
                    let ext = (hi - lo).max(DVec2::splat(1.0));
                    let s = 0.88 * (pw / ext.x).min(ph / ext.y);
                    (s.max(whole), (lo + hi) / 2.0)
                }
                None => (whole, DVec2::new(cw / 2.0, ch / 2.0)),
            };
            Projector {
                view: panel.view.clone(),
                scale,
                origin: half,
                centre,
            }
        }
        view => {
            let centre = bounds(panel).map_or(DVec2::ZERO, |(lo, hi)| (lo + hi) / 2.0);
            Projector {
                view: view.clone(),
                scale,
                origin: half,
                centre,
            }
        }
    }
}

/// Rasterizes `mesh` (faces `faces`) into a `w × h` layer, Gouraud-shaded with a headlight:
/// colour × (0.3 + 0.7 |n · towards viewer|), two-sided.
fn rasterize(
    mesh: &[Vec3],
    faces: &[[u32; 3]],
    base: Rgb,
    proj: &Projector,
    w: u32,
    h: u32,
) -> Layer {
    let normals = vertex_normals(mesh, faces);
    let screen: Vec<Option<ScreenVertex>> = mesh
        .iter()
        .zip(&normals)
        .map(|(p, n)| {
            let p = p.as_dvec3();
            let (x, y, depth) = proj.project(p)?;
            let light = 0.3 + 0.7 * n.as_dvec3().dot(proj.towards_viewer(p)).abs();
            let color = base.map(|c| (f64::from(c) * light) as f32);
            Some(ScreenVertex { x, y, depth, color })
        })
        .collect();
    let mut layer = Layer::new(w, h);
    for f in faces {
        let get = |i: u32| screen.get(i as usize).copied().flatten();
        if let (Some(a), Some(b), Some(c)) = (get(f[0]), get(f[1]), get(f[2])) {
            layer.triangle([a, b, c]);
        }
    }
    layer
}

/// Radius of observation discs in a cell.
fn point_radius(cell: &Rect) -> f32 {
    (cell.w.min(cell.h) as f32 / 90.0).clamp(1.5, 6.0)
}

/// Draws `scene` (meshes with faces `faces`) into a `width × height` image.
pub fn draw(scene: &Scene, faces: &[[u32; 3]], width: u32, height: u32) -> anyhow::Result<Canvas> {
    let mut canvas = Canvas::new(width, height, BACKGROUND);
    let lay = layout(scene, width, height);
    let scale = common_scale(scene, &lay.cells);
    for (panel, cell) in scene.panels.iter().zip(&lay.cells) {
        if cell.w == 0 || cell.h == 0 {
            continue;
        }
        let proj = projector(panel, cell, scale);
        let (ox, oy) = (i64::from(cell.x), i64::from(cell.y));
        // A camera view: its image area slightly darker, and its foreground mask tinted.
        if let View::Camera(cam) = &panel.view {
            let (x0, y0) = proj.pixel_of_image(DVec2::ZERO);
            let (x1, y1) =
                proj.pixel_of_image(DVec2::new(f64::from(cam.width), f64::from(cam.height)));
            for y in (y0.round() as i64).max(0)..(y1.round() as i64).min(i64::from(cell.h)) {
                for x in (x0.round() as i64).max(0)..(x1.round() as i64).min(i64::from(cell.w)) {
                    let mut c = [238, 238, 238];
                    if let Some(mask) = &panel.mask {
                        let u = (f64::from(x as u32) + 0.5 - proj.origin.x) / proj.scale
                            + proj.centre.x;
                        let v = (f64::from(y as u32) + 0.5 - proj.origin.y) / proj.scale
                            + proj.centre.y;
                        let mx = (u * f64::from(mask.width) / f64::from(cam.width)).floor();
                        let my = (v * f64::from(mask.height) / f64::from(cam.height)).floor();
                        if mx >= 0.0
                            && my >= 0.0
                            && (mx as u32) < mask.width
                            && (my as u32) < mask.height
                            && mask.data[my as usize * mask.width as usize + mx as usize] != 0
                        {
                            c = [245, 200, 200];
                        }
                    }
                    canvas.set(ox + x, oy + y, c);
                }
            }
        }
        // Opaque meshes into one layer (nearest wins), the truth into its own.
        let mut opaque: Option<Layer> = None;
        let mut truth: Option<Layer> = None;
        for (mesh, role) in &panel.meshes {
            let base = match role {
                Role::Fit => FIT,
                Role::Body => BODY,
                Role::Truth => TRUTH,
            };
            let layer = rasterize(mesh, faces, base, &proj, cell.w, cell.h);
            let slot = if *role == Role::Truth {
                &mut truth
            } else {
                &mut opaque
            };
            *slot = Some(match slot.take() {
                None => layer,
                Some(mut acc) => {
                    for i in 0..acc.depth.len() {
                        if layer.depth[i] < acc.depth[i] {
                            acc.depth[i] = layer.depth[i];
                            acc.color[i] = layer.color[i];
                        }
                    }
                    acc
                }
            });
        }
        let tol = proj.depth_tolerance(DVec3::new(0.0, 1.0, 0.0));
        for y in 0..i64::from(cell.h) {
            for x in 0..i64::from(cell.w) {
                let i = y as usize * cell.w as usize + x as usize;
                let mut depth = f32::INFINITY;
                if let Some(o) = &opaque
                    && o.depth[i].is_finite()
                {
                    canvas.set(ox + x, oy + y, o.color[i]);
                    depth = o.depth[i];
                }
                if let Some(t) = &truth
                    && t.depth[i] < depth - tol
                {
                    let alpha = if depth.is_finite() { 0.55 } else { 0.45 };
                    canvas.blend(ox + x, oy + y, t.color[i], alpha);
                }
            }
        }
        if let Some(t) = &truth {
            for y in 0..i64::from(cell.h) {
                for x in 0..i64::from(cell.w) {
                    if t.is_outline(x, y) {
                        canvas.set(ox + x, oy + y, TRUTH_OUTLINE);
                    }
                }
            }
        }
        // Segments and points on top.
        let r = point_radius(cell);
        for (a, b, c) in &panel.segments {
            if let (Some(pa), Some(pb)) = (proj.project(*a), proj.project(*b)) {
                canvas.line(
                    (pa.0 + cell.x as f32, pa.1 + cell.y as f32),
                    (pb.0 + cell.x as f32, pb.1 + cell.y as f32),
                    (r / 2.0).max(1.0),
                    *c,
                );
            }
        }
        for p in &panel.points {
            let (x, y, hidden, color) = match p {
                Point::World(p, c) => {
                    let Some((x, y, d)) = proj.project(*p) else {
                        continue;
                    };
                    let behind = opaque.as_ref().is_some_and(|o| {
                        d > o.depth_at(x.floor() as i64, y.floor() as i64)
                            + 3.0 * proj.depth_tolerance(*p)
                    });
                    (x, y, behind, *c)
                }
                Point::Pixel(uv, c) => {
                    let (x, y) = proj.pixel_of_image(*uv);
                    (x, y, false, *c)
                }
            };
            let (x, y) = (x + cell.x as f32, y + cell.y as f32);
            // Keep the points inside their own panel.
            if x < cell.x as f32
                || y < cell.y as f32
                || x >= (cell.x + cell.w) as f32
                || y >= (cell.y + cell.h) as f32
            {
                continue;
            }
            if hidden {
                canvas.ring(x, y, r, (r / 2.5).max(1.0), color);
            } else {
                canvas.disc(x, y, r + 1.0, [255, 255, 255]);
                canvas.disc(x, y, r, color);
            }
        }
    }
    // Captions last, so nothing covers them.
    if lay.title > 0 {
        canvas.text(4, 2, lay.title.saturating_sub(4).max(8), &scene.title, TEXT)?;
    }
    for (panel, cell) in scene.panels.iter().zip(&lay.cells) {
        if !panel.label.is_empty() {
            canvas.text(
                cell.x as i32 + 4,
                (cell.y - lay.label) as i32 + 1,
                lay.label.saturating_sub(3).max(8),
                &panel.label,
                TEXT,
            )?;
        }
    }
    Ok(canvas)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lfit_model::body::default_template;
    use lfit_model::skinning::{SkinningMethod, pose_vertices};

    fn rest() -> (Vec<Vec3>, Vec<[u32; 3]>, lfit_model::template::Template) {
        let t = default_template();
        let v = pose_vertices(&t, &vec![0.0; t.layout().dim()], SkinningMethod::Linear);
        (v, t.faces.clone(), t)
    }

    /// Mean pixel (x, y) of the canvas pixels in `cell` whose colour is `pred`.
    fn centroid(c: &Canvas, cell: &Rect, pred: impl Fn(Rgb) -> bool) -> Option<(f64, f64)> {
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for y in cell.y..cell.y + cell.h {
            for x in cell.x..cell.x + cell.w {
                if pred(c.get(i64::from(x), i64::from(y))) {
                    sx += f64::from(x);
                    sy += f64::from(y);
                    n += 1.0;
                }
            }
        }
        (n > 0.0).then(|| (sx / n, sy / n))
    }

    fn is_body(c: Rgb) -> bool {
        c != BACKGROUND && c != TEXT && c[0] > c[2]
    }

    /// Pixel of a world point in panel `k` of `scene` drawn at `w × h`.
    fn pixel_of(scene: &Scene, k: usize, w: u32, h: u32, p: DVec3) -> (f64, f64) {
        let lay = layout(scene, w, h);
        let scale = common_scale(scene, &lay.cells);
        let cell = lay.cells[k];
        let proj = projector(&scene.panels[k], &cell, scale);
        let (x, y, _) = proj.project(p).unwrap();
        (
            f64::from(x) + f64::from(cell.x),
            f64::from(y) + f64::from(cell.y),
        )
    }

    #[test]
    fn the_front_view_of_the_template_has_head_above_pelvis_and_left_arm_on_image_right() {
        let (v, faces, t) = rest();
        let joints = t.joint_rest();
        let joint = |name: &str| {
            let j = t.rig.joints.iter().position(|j| j.name == name).unwrap();
            joints[j]
        };
        let mut front = Panel::new(View::Front, "front");
        front.meshes.push((v.clone(), Role::Body));
        let mut side = Panel::new(View::Side, "side");
        side.meshes.push((v.clone(), Role::Body));
        let scene = Scene {
            title: String::new(),
            columns: 2,
            panels: vec![front, side],
        };
        let (w, h) = (400, 300);
        let canvas = draw(&scene, &faces, w, h).unwrap();
        let lay = layout(&scene, w, h);
        let cell = lay.cells[0];
        // The body fills the panel's height (with a margin) and is centred horizontally.
        let rows: Vec<u32> = (cell.y..cell.y + cell.h)
            .filter(|&y| (cell.x..cell.x + cell.w).any(|x| is_body(canvas.get(x.into(), y.into()))))
            .collect();
        let (top, bottom) = (rows[0], rows[rows.len() - 1]);
        assert!(
            f64::from(bottom - top) > 0.7 * f64::from(cell.h),
            "body spans rows {top}..{bottom} of {}",
            cell.h
        );
        // Head pixels (around the head joint's projection) are body pixels above the pelvis.
        let head = pixel_of(&scene, 0, w, h, joint("head"));
        let pelvis = pixel_of(&scene, 0, w, h, joint("root"));
        assert!(
            head.1 < pelvis.1 - 0.2 * f64::from(cell.h),
            "{head:?} {pelvis:?}"
        );
        assert!(is_body(canvas.get(head.0 as i64, head.1 as i64)));
        assert!(is_body(canvas.get(pelvis.0 as i64, pelvis.1 as i64)));
        // The subject's left hand (+x) appears on the image's right, the right hand on its left.
        let l_hand = pixel_of(&scene, 0, w, h, joint("l_hand"));
        let r_hand = pixel_of(&scene, 0, w, h, joint("r_hand"));
        assert!(l_hand.0 > pelvis.0 + 10.0 && r_hand.0 < pelvis.0 - 10.0);
        assert!(is_body(canvas.get(l_hand.0 as i64, l_hand.1 as i64)));
        assert!(is_body(canvas.get(r_hand.0 as i64, r_hand.1 as i64)));
        // Body pixels right of the pelvis column near hand height exist (the left arm).
        let arm_row = l_hand.1 as u32;
        let right_of = (pelvis.0 as u32 + 20..cell.x + cell.w)
            .filter(|&x| is_body(canvas.get(x.into(), arm_row.into())))
            .count();
        assert!(right_of > 3, "no left-arm pixels at row {arm_row}");
        // The side view is narrower than the front view (a body is wider than deep).
        let width_of = |cell: &Rect| {
            (cell.x..cell.x + cell.w)
                .filter(|&x| {
                    (cell.y..cell.y + cell.h).any(|y| is_body(canvas.get(x.into(), y.into())))
                })
                .count()
        };
        assert!(width_of(&lay.cells[1]) * 2 < width_of(&lay.cells[0]));
    }

    #[test]
    fn front_view_depth_shows_the_nearer_body_and_side_view_puts_the_face_on_the_right() {
        let (v, faces, t) = rest();
        // Two copies: the fit moved 1 m towards the front camera (+z), the body stays. From the
        // front the fit (nearer) must cover the body wherever both are.
        let forward: Vec<Vec3> = v.iter().map(|p| *p + Vec3::new(0.0, 0.0, 1.0)).collect();
        let mut front = Panel::new(View::Front, "");
        front.meshes.push((v.clone(), Role::Body));
        front.meshes.push((forward.clone(), Role::Fit));
        let scene = Scene {
            title: String::new(),
            columns: 1,
            panels: vec![front],
        };
        let canvas = draw(&scene, &faces, 200, 300).unwrap();
        let cell = layout(&scene, 200, 300).cells[0];
        let fit_pixels = centroid(&canvas, &cell, |c| i32::from(c[2]) > i32::from(c[0]) + 30);
        let body_pixels = centroid(&canvas, &cell, is_body);
        assert!(fit_pixels.is_some(), "the nearer (fit) body is visible");
        assert!(
            body_pixels.is_none(),
            "the farther body is hidden everywhere"
        );
        // Moved 1 m backwards instead, the body is in front and the fit hidden.
        let back: Vec<Vec3> = v.iter().map(|p| *p - Vec3::new(0.0, 0.0, 1.0)).collect();
        let mut scene = scene;
        scene.panels[0].meshes[1].0 = back;
        let canvas = draw(&scene, &faces, 200, 300).unwrap();
        assert!(centroid(&canvas, &cell, |c| i32::from(c[2]) > i32::from(c[0]) + 30).is_none());
        // Side view: the nose side (+z) is on the image's right: a marker on the face projects
        // right of one on the back of the head.
        let head = t.joint_rest()[t.rig.joints.iter().position(|j| j.name == "head").unwrap()];
        let mut side = Panel::new(View::Side, "");
        side.meshes.push((v, Role::Body));
        let scene = Scene {
            title: String::new(),
            columns: 1,
            panels: vec![side],
        };
        let face = pixel_of(&scene, 0, 200, 300, head + DVec3::new(0.0, 0.0, 0.1));
        let back = pixel_of(&scene, 0, 200, 300, head - DVec3::new(0.0, 0.0, 0.1));
        assert!(face.0 > back.0 + 5.0);
    }

    #[test]
    fn points_behind_the_body_are_rings_and_in_front_are_discs() {
        let (v, faces, t) = rest();
        let pelvis = t.joint_rest()[0];
        let mut front = Panel::new(View::Front, "");
        front.meshes.push((v, Role::Body));
        let before = pelvis + DVec3::new(0.0, 0.0, 0.5);
        let behind = pelvis + DVec3::new(0.0, 0.3, -0.5);
        front.points.push(Point::World(before, OBSERVED));
        front.points.push(Point::World(behind, OBSERVED));
        let scene = Scene {
            title: String::new(),
            columns: 1,
            panels: vec![front],
        };
        let canvas = draw(&scene, &faces, 300, 400).unwrap();
        let a = pixel_of(&scene, 0, 300, 400, before);
        let b = pixel_of(&scene, 0, 300, 400, behind);
        assert_eq!(canvas.get(a.0 as i64, a.1 as i64), OBSERVED, "filled disc");
        assert_ne!(
            canvas.get(b.0 as i64, b.1 as i64),
            OBSERVED,
            "ring: centre not filled"
        );
        assert!(is_body(canvas.get(b.0 as i64, b.1 as i64)));
    }
}
