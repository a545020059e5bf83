//! The `silhouettes` observation model (papers/001 §3.2): the foreground mask of every camera,
//! one prediction entry per pixel (0 or 1), compared by papers/001's overlap fitness.

use glam::Vec3;
use rand::{Rng, RngCore};

use super::{ObservationModel, PoseJacobian, PosedView, ResidualGroup, SilhouetteSetup};
use crate::error::{ModelError, Result};
use crate::noise::NoiseConfig;
use crate::observe::Scales;
use crate::scan::{Mask, render_silhouette};
use crate::template::Template;

impl SilhouetteSetup {
    /// The same cameras rendered `width` pixels wide (heights keep each camera's aspect ratio):
    /// the resolution the energy compares at.
    pub fn at_width(&self, width: u32) -> SilhouetteSetup {
        let cameras = self
            .cameras
            .iter()
            .map(|cam| {
                let s = f64::from(width) / f64::from(cam.width.max(1));
                let mut c = *cam;
                c.fx *= s;
                c.fy *= s;
                c.cx *= s;
                c.cy *= s;
                c.width = width;
                c.height = ((f64::from(cam.height) * s).round() as u32).max(1);
                c
            })
            .collect();
        SilhouetteSetup { cameras }
    }

    /// Pixels per camera, in prediction order.
    fn sizes(&self) -> impl Iterator<Item = usize> + '_ {
        self.cameras
            .iter()
            .map(|c| c.width as usize * c.height as usize)
    }

    /// A prediction (or observation) vector as one mask per camera.
    pub fn masks(&self, values: &[f64]) -> Vec<Mask> {
        let mut start = 0;
        self.cameras
            .iter()
            .zip(self.sizes())
            .map(|(c, n)| {
                let data = values[start..start + n]
                    .iter()
                    .map(|&v| u8::from(v != 0.0))
                    .collect();
                start += n;
                Mask {
                    width: c.width,
                    height: c.height,
                    data,
                }
            })
            .collect()
    }

    /// Masks (one per camera, each of its camera's size) as a vector of 0/1 entries.
    pub fn values(&self, masks: &[Mask]) -> Vec<f64> {
        masks
            .iter()
            .flat_map(|m| m.data.iter().map(|&p| f64::from(u8::from(p != 0))))
            .collect()
    }
}

impl ObservationModel for SilhouetteSetup {
    fn name(&self) -> &str {
        "silhouettes"
    }

    fn validate(&self, _: &Template) -> Result<()> {
        if self.cameras.is_empty() {
            return Err(ModelError::Config(
                "the silhouettes modality needs at least one camera".into(),
            ));
        }
        self.cameras
            .iter()
            .enumerate()
            .try_for_each(|(i, c)| c.validate(i))
    }

    fn dim(&self, _: &Template) -> usize {
        self.sizes().sum()
    }

    /// One group per camera (the data term is the overlap fitness, not these groups).
    fn groups(&self, _: &Template, _: &Scales) -> Vec<ResidualGroup> {
        let mut start = 0;
        self.sizes()
            .map(|len| {
                let g = ResidualGroup {
                    start,
                    len,
                    sigma: 1.0,
                };
                start += len;
                g
            })
            .collect()
    }

    /// The posed mesh rasterised in every camera: 1 inside the silhouette, 0 outside.
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        let template = posed.template();
        let vertices: Vec<Vec3> = (0..template.num_vertices())
            .map(|v| posed.vertex(v).as_vec3())
            .collect();
        let mut start = 0;
        for cam in &self.cameras {
            let mask = render_silhouette(cam, &vertices, &template.faces);
            for (o, &p) in values[start..start + mask.data.len()]
                .iter_mut()
                .zip(&mask.data)
            {
                *o = f64::from(p);
            }
            start += mask.data.len();
        }
        visible.fill(true);
    }

    /// Pixel counts have no derivative ([`Self::no_gradient`]): zeros.
    fn jacobian(&self, _: &PosedView<'_>, _: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        out.fill(0.0);
    }

    fn backprop(&self, _: &PosedView<'_>, _: &[f64], _: &mut super::PoseGradient<'_, '_>) {}

    /// Background-subtraction speckle: every pixel flips with the outlier rate.
    fn corrupt(
        &self,
        values: &mut [f64],
        _: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        for v in values {
            if rng.random::<f64>() < noise.outlier_rate {
                *v = if *v == 0.0 { 1.0 } else { 0.0 };
            }
        }
    }

    fn no_gradient(&self) -> Option<String> {
        Some("the silhouettes energy has no gradient (papers/001's overlap fitness counts pixels): use a zeroth-order method".into())
    }

    /// papers/001 eq. (4)–(5): per view `½ |M \ F| / |M| + ½ |F \ M| / |F|` (model silhouette M,
    /// foreground F), averaged over the views: 0 when the masks coincide, 1 when they do not
    /// overlap. A view where the model renders nothing scores ½ + ½ (as if nothing overlapped);
    /// an empty foreground contributes only the first half.
    fn data_term(&self, predicted: &[f64], observed: &[f64]) -> Option<f64> {
        let mut start = 0;
        let mut sum = 0.0;
        for n in self.sizes() {
            let (mut m, mut f, mut m_not_f, mut f_not_m) = (0u64, 0u64, 0u64, 0u64);
            for (&a, &b) in predicted[start..start + n]
                .iter()
                .zip(&observed[start..start + n])
            {
                let (a, b) = (a != 0.0, b != 0.0);
                m += u64::from(a);
                f += u64::from(b);
                m_not_f += u64::from(a && !b);
                f_not_m += u64::from(b && !a);
            }
            let first = if m > 0 {
                m_not_f as f64 / m as f64
            } else {
                1.0
            };
            let second = if f > 0 {
                f_not_m as f64 / f as f64
            } else {
                0.0
            };
            sum += 0.5 * first + 0.5 * second;
            start += n;
        }
        Some(sum / self.cameras.len().max(1) as f64)
    }
}
