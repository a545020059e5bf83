//! The rasterizer: an RGB canvas, z-buffered triangles with Gouraud colours, discs, rings and
//! lines, captions (through plotters' bitmap backend and the embedded DejaVu Sans font) and PNG
//! encoding. Written for `lfit render`; no Burn, no I/O except [`Canvas::to_png`]'s bytes.
//!
//! Pixel `(i, j)` covers `[i, i + 1) × [j, j + 1)`; a triangle covers a pixel when the pixel's
//! centre `(i + ½, j + ½)` lies inside it or on its edge. Depth is any quantity that varies
//! linearly over the screen (orthographic view depth, or `−1/z` of a pinhole camera); smaller is
//! nearer.

use std::sync::OnceLock;

use anyhow::{Result, anyhow};

/// An RGB colour.
pub type Rgb = [u8; 3];

/// A vertex on the screen: pixel position, depth (smaller = nearer) and colour (0–255 floats).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScreenVertex {
    pub x: f32,
    pub y: f32,
    pub depth: f32,
    pub color: [f32; 3],
}

/// A z-buffered colour layer: what one mesh looks like in one panel. Empty pixels have depth +∞.
#[derive(Debug, Clone)]
pub struct Layer {
    pub width: u32,
    pub height: u32,
    pub depth: Vec<f32>,
    pub color: Vec<Rgb>,
}

impl Layer {
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            depth: vec![f32::INFINITY; n],
            color: vec![[0, 0, 0]; n],
        }
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        (x >= 0 && y >= 0 && x < i64::from(self.width) && y < i64::from(self.height))
            .then(|| y as usize * self.width as usize + x as usize)
    }

    /// Whether a triangle covers pixel `(x, y)`.
    pub fn covered(&self, x: i64, y: i64) -> bool {
        self.index(x, y).is_some_and(|i| self.depth[i].is_finite())
    }

    /// Depth at pixel `(x, y)` (+∞ where empty or outside).
    pub fn depth_at(&self, x: i64, y: i64) -> f32 {
        self.index(x, y).map_or(f32::INFINITY, |i| self.depth[i])
    }

    /// Number of covered pixels.
    pub fn coverage(&self) -> usize {
        self.depth.iter().filter(|d| d.is_finite()).count()
    }

    /// Draws one triangle: every pixel whose centre is inside (or on an edge) and nearer than
    /// what the layer holds gets the barycentric mix of the vertex colours. Degenerate and
    /// non-finite triangles draw nothing; both windings are drawn (no back-face culling).
    pub fn triangle(&mut self, v: [ScreenVertex; 3]) {
        let finite = v
            .iter()
            .all(|p| p.x.is_finite() && p.y.is_finite() && p.depth.is_finite());
        if !finite {
            return;
        }
        let edge = |a: &ScreenVertex, b: &ScreenVertex, x: f32, y: f32| {
            (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x)
        };
        let area = edge(&v[0], &v[1], v[2].x, v[2].y);
        if area.abs() < 1e-12 {
            return;
        }
        let min_x = v.iter().map(|p| p.x).fold(f32::INFINITY, f32::min);
        let max_x = v.iter().map(|p| p.x).fold(f32::NEG_INFINITY, f32::max);
        let min_y = v.iter().map(|p| p.y).fold(f32::INFINITY, f32::min);
        let max_y = v.iter().map(|p| p.y).fold(f32::NEG_INFINITY, f32::max);
        // Pixels whose centres can be inside: centre i + ½ ∈ [min, max].
        let x0 = ((min_x - 0.5).ceil() as i64).max(0);
        let x1 = ((max_x - 0.5).floor() as i64).min(i64::from(self.width) - 1);
        let y0 = ((min_y - 0.5).ceil() as i64).max(0);
        let y1 = ((max_y - 0.5).floor() as i64).min(i64::from(self.height) - 1);
        for y in y0..=y1 {
            let cy = y as f32 + 0.5;
            for x in x0..=x1 {
                let cx = x as f32 + 0.5;
                let b0 = edge(&v[1], &v[2], cx, cy) / area;
                let b1 = edge(&v[2], &v[0], cx, cy) / area;
                let b2 = edge(&v[0], &v[1], cx, cy) / area;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                let depth = b0 * v[0].depth + b1 * v[1].depth + b2 * v[2].depth;
                let i = y as usize * self.width as usize + x as usize;
                if depth < self.depth[i] {
                    self.depth[i] = depth;
                    let c = |k: usize| {
                        (b0 * v[0].color[k] + b1 * v[1].color[k] + b2 * v[2].color[k])
                            .round()
                            .clamp(0.0, 255.0) as u8
                    };
                    self.color[i] = [c(0), c(1), c(2)];
                }
            }
        }
    }

    /// Whether pixel `(x, y)` is covered and one of its 4-neighbours is not: the silhouette.
    pub fn is_outline(&self, x: i64, y: i64) -> bool {
        self.covered(x, y)
            && [(-1, 0), (1, 0), (0, -1), (0, 1)]
                .iter()
                .any(|(dx, dy)| !self.covered(x + dx, y + dy))
    }
}

/// An RGB image, row-major, 3 bytes per pixel (the layout plotters' bitmap backend draws on).
#[derive(Debug, Clone)]
pub struct Canvas {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Name under which the embedded font is registered with plotters (as `crate::study::plots` does).
const FONT: &str = "sans-serif";

fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font(
                FONT,
                plotters::style::FontStyle::Normal,
                dejavu::sans::regular(),
            )
            .map_err(|_| "the embedded DejaVu Sans font could not be parsed".to_string())
        })
        .clone()
        .map_err(|e| anyhow!(e))
}

impl Canvas {
    pub fn new(width: u32, height: u32, background: Rgb) -> Self {
        let n = width as usize * height as usize;
        let mut rgb = Vec::with_capacity(3 * n);
        for _ in 0..n {
            rgb.extend_from_slice(&background);
        }
        Self { width, height, rgb }
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        (x >= 0 && y >= 0 && x < i64::from(self.width) && y < i64::from(self.height))
            .then(|| 3 * (y as usize * self.width as usize + x as usize))
    }

    /// The colour at `(x, y)`; black outside.
    pub fn get(&self, x: i64, y: i64) -> Rgb {
        self.index(x, y).map_or([0, 0, 0], |i| {
            [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
        })
    }

    /// Sets `(x, y)`; outside is ignored.
    pub fn set(&mut self, x: i64, y: i64, c: Rgb) {
        if let Some(i) = self.index(x, y) {
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    /// Mixes `c` into `(x, y)` with weight `alpha` ∈ [0, 1].
    pub fn blend(&mut self, x: i64, y: i64, c: Rgb, alpha: f32) {
        let old = self.get(x, y);
        let mix = |k: usize| {
            (f32::from(old[k]) * (1.0 - alpha) + f32::from(c[k]) * alpha)
                .round()
                .clamp(0.0, 255.0) as u8
        };
        self.set(x, y, [mix(0), mix(1), mix(2)]);
    }

    /// Fills the rectangle `[x0, x1) × [y0, y1)`.
    pub fn fill_rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: Rgb) {
        for y in y0..y1 {
            for x in x0..x1 {
                self.set(x, y, c);
            }
        }
    }

    /// A filled disc of radius `r` pixels centred at `(cx, cy)` (pixel centres inside).
    pub fn disc(&mut self, cx: f32, cy: f32, r: f32, c: Rgb) {
        self.annulus(cx, cy, 0.0, r, c);
    }

    /// A ring: pixel centres at distance in `[r − width, r]` from `(cx, cy)`.
    pub fn ring(&mut self, cx: f32, cy: f32, r: f32, width: f32, c: Rgb) {
        self.annulus(cx, cy, (r - width).max(0.0), r, c);
    }

    fn annulus(&mut self, cx: f32, cy: f32, r0: f32, r1: f32, c: Rgb) {
        if !(cx.is_finite() && cy.is_finite()) {
            return;
        }
        let (x0, x1) = ((cx - r1).floor() as i64, (cx + r1).ceil() as i64);
        let (y0, y1) = ((cy - r1).floor() as i64, (cy + r1).ceil() as i64);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let d = ((x as f32 + 0.5 - cx).powi(2) + (y as f32 + 0.5 - cy).powi(2)).sqrt();
                if d <= r1 && d >= r0 {
                    self.set(x, y, c);
                }
            }
        }
    }

    /// A line of `width` pixels from `(x0, y0)` to `(x1, y1)` (pixel centres within width/2).
    pub fn line(&mut self, (x0, y0): (f32, f32), (x1, y1): (f32, f32), width: f32, c: Rgb) {
        if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) {
            return;
        }
        let h = width / 2.0;
        let (dx, dy) = (x1 - x0, y1 - y0);
        let len2 = dx * dx + dy * dy;
        let (bx0, bx1) = (
            (x0.min(x1) - h).floor() as i64,
            (x0.max(x1) + h).ceil() as i64,
        );
        let (by0, by1) = (
            (y0.min(y1) - h).floor() as i64,
            (y0.max(y1) + h).ceil() as i64,
        );
        for y in by0..=by1 {
            for x in bx0..=bx1 {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let t = if len2 > 0.0 {
                    (((px - x0) * dx + (py - y0) * dy) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let (qx, qy) = (x0 + t * dx, y0 + t * dy);
                if (px - qx).powi(2) + (py - qy).powi(2) <= h * h {
                    self.set(x, y, c);
                }
            }
        }
    }

    /// Writes `text` with its top-left corner at `(x, y)`, `size` pixels high.
    pub fn text(&mut self, x: i32, y: i32, size: u32, text: &str, c: Rgb) -> Result<()> {
        use plotters::prelude::*;
        ensure_font()?;
        let (w, h) = (self.width, self.height);
        let root = BitMapBackend::with_buffer(&mut self.rgb, (w, h)).into_drawing_area();
        let style = (FONT, size).into_font().color(&RGBColor(c[0], c[1], c[2]));
        root.draw_text(text, &style, (x, y))
            .map_err(|e| anyhow!("cannot draw the caption '{text}': {e}"))?;
        root.present()
            .map_err(|e| anyhow!("cannot draw the caption '{text}': {e}"))?;
        Ok(())
    }

    /// The image as PNG bytes (8-bit RGB).
    pub fn to_png(&self) -> Result<Vec<u8>> {
        let mut bytes = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut bytes, self.width, self.height);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder
                .write_header()
                .map_err(|e| anyhow!("PNG encoding failed: {e}"))?;
            writer
                .write_image_data(&self.rgb)
                .map_err(|e| anyhow!("PNG encoding failed: {e}"))?;
            writer
                .finish()
                .map_err(|e| anyhow!("PNG encoding failed: {e}"))?;
        }
        Ok(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32, depth: f32, color: [f32; 3]) -> ScreenVertex {
        ScreenVertex { x, y, depth, color }
    }

    #[test]
    fn a_triangle_covers_exactly_the_pixels_whose_centres_are_inside() {
        // Right triangle with legs along the axes: (0,0), (8,0), (0,8). Pixel (i, j) has its
        // centre (i + ½, j + ½) inside iff i + j + 1 ≤ 8, i.e. i + j ≤ 7.
        let mut layer = Layer::new(12, 12);
        let red = [255.0, 0.0, 0.0];
        layer.triangle([
            v(0.0, 0.0, 1.0, red),
            v(8.0, 0.0, 1.0, red),
            v(0.0, 8.0, 1.0, red),
        ]);
        for j in 0..12 {
            for i in 0..12 {
                assert_eq!(layer.covered(i, j), i + j <= 7, "pixel ({i}, {j})");
            }
        }
        assert_eq!(layer.coverage(), 36);
        assert_eq!(layer.color[0], [255, 0, 0]);
        // The other winding covers the same pixels.
        let mut other = Layer::new(12, 12);
        other.triangle([
            v(0.0, 0.0, 1.0, red),
            v(0.0, 8.0, 1.0, red),
            v(8.0, 0.0, 1.0, red),
        ]);
        assert_eq!(other.depth, layer.depth);
    }

    #[test]
    fn colours_and_depth_interpolate_barycentrically() {
        let mut layer = Layer::new(100, 2);
        // A long thin quad from x = 0 (black, depth 0) to x = 100 (white, depth 10).
        let (a, b) = ([0.0; 3], [255.0; 3]);
        layer.triangle([
            v(0.0, 0.0, 0.0, a),
            v(100.0, 0.0, 10.0, b),
            v(0.0, 2.0, 0.0, a),
        ]);
        layer.triangle([
            v(100.0, 0.0, 10.0, b),
            v(100.0, 2.0, 10.0, b),
            v(0.0, 2.0, 0.0, a),
        ]);
        assert_eq!(layer.coverage(), 200);
        // Pixel 49's centre is at x = 49.5: colour 0.495 × 255 ≈ 126, depth 4.95.
        let i = 49;
        assert_eq!(layer.color[i], [126, 126, 126]);
        assert!((layer.depth[i] - 4.95).abs() < 1e-4);
    }

    #[test]
    fn the_z_buffer_keeps_the_nearer_of_two_overlapping_triangles_in_either_order() {
        let near = [0.0, 0.0, 255.0];
        let far = [255.0, 0.0, 0.0];
        let tri = |depth: f32, c| {
            [
                v(1.0, 1.0, depth, c),
                v(19.0, 1.0, depth, c),
                v(10.0, 19.0, depth, c),
            ]
        };
        for order in [[0.5, 2.0], [2.0, 0.5]] {
            let mut layer = Layer::new(20, 20);
            for d in order {
                layer.triangle(tri(d, if d < 1.0 { near } else { far }));
            }
            assert!(layer.coverage() > 100);
            for (c, d) in layer.color.iter().zip(&layer.depth) {
                if d.is_finite() {
                    assert_eq!(*c, [0, 0, 255]);
                    assert!((*d - 0.5).abs() < 1e-6);
                }
            }
        }
        // Two crossing triangles: each wins where it is nearer.
        let mut layer = Layer::new(20, 20);
        let quad = |d_left: f32, d_right: f32, c| {
            [
                [
                    v(0.0, 0.0, d_left, c),
                    v(20.0, 0.0, d_right, c),
                    v(0.0, 20.0, d_left, c),
                ],
                [
                    v(20.0, 0.0, d_right, c),
                    v(20.0, 20.0, d_right, c),
                    v(0.0, 20.0, d_left, c),
                ],
            ]
        };
        for t in quad(0.0, 2.0, near).into_iter().chain(quad(2.0, 0.0, far)) {
            layer.triangle(t);
        }
        let at = |x: usize, y: usize| layer.color[y * 20 + x];
        assert_eq!(at(2, 10), [0, 0, 255], "left: the blue plane is nearer");
        assert_eq!(at(17, 10), [255, 0, 0], "right: the red plane is nearer");
    }

    #[test]
    fn degenerate_or_offscreen_triangles_draw_nothing_and_do_not_panic() {
        let c = [1.0; 3];
        let mut layer = Layer::new(10, 10);
        layer.triangle([
            v(1.0, 1.0, 0.0, c),
            v(5.0, 5.0, 0.0, c),
            v(9.0, 9.0, 0.0, c),
        ]);
        layer.triangle([
            v(-50.0, -50.0, 0.0, c),
            v(-40.0, -50.0, 0.0, c),
            v(-50.0, -40.0, 0.0, c),
        ]);
        layer.triangle([
            v(f32::NAN, 1.0, 0.0, c),
            v(5.0, 5.0, 0.0, c),
            v(1.0, 9.0, 0.0, c),
        ]);
        assert_eq!(layer.coverage(), 0);
        // Partly outside: clipped to the layer.
        layer.triangle([
            v(-100.0, -100.0, 0.0, c),
            v(100.0, -100.0, 0.0, c),
            v(0.0, 100.0, 0.0, c),
        ]);
        assert!(layer.coverage() > 0 && layer.coverage() <= 100);
    }

    #[test]
    fn discs_rings_and_lines_cover_what_they_should() {
        let mut c = Canvas::new(20, 20, [255; 3]);
        c.disc(10.0, 10.0, 3.0, [0, 0, 0]);
        assert_eq!(c.get(10, 10), [0, 0, 0]);
        assert_eq!(c.get(10, 14), [255; 3]);
        c.ring(10.0, 10.0, 8.0, 1.0, [1, 2, 3]);
        assert_eq!(c.get(10, 17), [1, 2, 3]);
        assert_eq!(c.get(10, 15), [255; 3]);
        c.line((0.0, 1.5), (20.0, 1.5), 1.0, [9, 9, 9]);
        assert!((0..20).all(|x| c.get(x, 1) == [9, 9, 9]));
        assert_eq!(c.get(5, 0), [255; 3]);
        assert_eq!(c.get(5, 2), [255; 3]);
    }

    #[test]
    fn png_bytes_decode_to_the_canvas() {
        let mut c = Canvas::new(7, 5, [10, 20, 30]);
        c.set(3, 2, [200, 100, 50]);
        c.text(0, 0, 10, "x", [0, 0, 0]).unwrap();
        let bytes = c.to_png().unwrap();
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (7, 5));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(&buf[..info.buffer_size()], c.rgb.as_slice());
    }
}
