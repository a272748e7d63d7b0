//! A small RGB rasteriser: anti-aliased thick lines and discs (coverage from
//! the exact distance of each pixel centre to the shape), filled rectangles
//! and bitmap text.

use super::font;
use colslam_image::Image;

/// An RGB colour.
pub type Rgb = [u8; 3];

/// Floating-point RGB canvas; converted to an 8-bit [`Image`] at the end.
pub struct Canvas {
    width: usize,
    height: usize,
    px: Vec<[f32; 3]>,
}

/// Half a pixel: pixel `(x, y)` covers `[x, x + 1) x [y, y + 1)`, its
/// centre is at `+ PIXEL_CENTRE`.
const PIXEL_CENTRE: f64 = 0.5;

impl Canvas {
    /// A canvas filled with `background`.
    pub fn new(width: usize, height: usize, background: Rgb) -> Self {
        let bg = background.map(f32::from);
        Self { width, height, px: vec![bg; width * height] }
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Blends `color` into pixel `(x, y)` with opacity `alpha` in [0, 1];
    /// pixels outside the canvas are ignored.
    pub fn blend(&mut self, x: i64, y: i64, color: Rgb, alpha: f64) {
        if x < 0 || y < 0 || alpha <= 0.0 {
            return;
        }
        let (x, y) = (x as usize, y as usize);
        if x >= self.width || y >= self.height {
            return;
        }
        let a = alpha.min(1.0) as f32;
        // In range: x < width and y < height were checked above.
        let p = &mut self.px[y * self.width + x];
        for (c, &t) in p.iter_mut().zip(&color) {
            *c = *c * (1.0 - a) + f32::from(t) * a;
        }
    }

    /// Fills the pixels whose centres lie in `[x0, x1) x [y0, y1)`.
    pub fn fill_rect(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, color: Rgb) {
        let (xa, xb) = (x0.round() as i64, x1.round() as i64);
        let (ya, yb) = (y0.round() as i64, y1.round() as i64);
        for y in ya..yb {
            for x in xa..xb {
                self.blend(x, y, color, 1.0);
            }
        }
    }

    /// An anti-aliased segment of the given width (pixels).
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), width: f64, color: Rgb) {
        if ![a.0, a.1, b.0, b.1, width].iter().all(|v| v.is_finite()) {
            return;
        }
        let hw = 0.5 * width;
        let reach = hw + 1.0;
        let x0 = (a.0.min(b.0) - reach).floor().max(-1.0) as i64;
        let x1 = (a.0.max(b.0) + reach).ceil().min(self.width as f64 + 1.0) as i64;
        let y0 = (a.1.min(b.1) - reach).floor().max(-1.0) as i64;
        let y1 = (a.1.max(b.1) + reach).ceil().min(self.height as f64 + 1.0) as i64;
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len2 = dx * dx + dy * dy;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (cx, cy) = (x as f64 + PIXEL_CENTRE, y as f64 + PIXEL_CENTRE);
                let t = if len2 > 0.0 { (((cx - a.0) * dx + (cy - a.1) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
                let d = ((cx - a.0 - t * dx).powi(2) + (cy - a.1 - t * dy).powi(2)).sqrt();
                // Coverage ramps from 1 (centre within hw - 0.5) to 0 over one pixel.
                let cover = (hw + 0.5 - d).clamp(0.0, 1.0);
                if cover > 0.0 {
                    self.blend(x, y, color, cover);
                }
            }
        }
    }

    /// A polyline through `points`.
    pub fn polyline(&mut self, points: &[(f64, f64)], width: f64, color: Rgb) {
        for w in points.windows(2) {
            self.line(w[0], w[1], width, color);
        }
    }

    /// An anti-aliased filled disc.
    pub fn disc(&mut self, c: (f64, f64), radius: f64, color: Rgb) {
        if !(c.0.is_finite() && c.1.is_finite()) {
            return;
        }
        let r = radius + 1.0;
        for y in (c.1 - r).floor() as i64..=(c.1 + r).ceil() as i64 {
            for x in (c.0 - r).floor() as i64..=(c.0 + r).ceil() as i64 {
                let d = ((x as f64 + PIXEL_CENTRE - c.0).powi(2) + (y as f64 + PIXEL_CENTRE - c.1).powi(2)).sqrt();
                let cover = (radius + 0.5 - d).clamp(0.0, 1.0);
                if cover > 0.0 {
                    self.blend(x, y, color, cover);
                }
            }
        }
    }

    /// Width in pixels of `text` drawn at `scale`.
    pub fn text_width(text: &str, scale: usize) -> f64 {
        let n = text.chars().count();
        if n == 0 { 0.0 } else { ((n * font::ADVANCE - 1) * scale) as f64 }
    }

    /// Height in pixels of a line of text at `scale`.
    pub fn text_height(scale: usize) -> f64 {
        (font::GLYPH_H * scale) as f64
    }

    /// Draws `text` with its top-left corner at `(x, y)`; each font cell is
    /// a `scale` x `scale` block (crisp, no anti-aliasing).
    pub fn text(&mut self, x: f64, y: f64, text: &str, scale: usize, color: Rgb) {
        let (x0, y0) = (x.round() as i64, y.round() as i64);
        let s = scale as i64;
        for (k, c) in text.chars().enumerate() {
            let gx = x0 + (k * font::ADVANCE) as i64 * s;
            let gy = if font::DESCENDERS.contains(c) { y0 + (font::DESCENDER_SHIFT as i64) * s } else { y0 };
            for (row, bits) in font::glyph(c).iter().enumerate() {
                for (col, cell) in bits.bytes().enumerate() {
                    if cell != b'#' {
                        continue;
                    }
                    for dy in 0..s {
                        for dx in 0..s {
                            self.blend(gx + col as i64 * s + dx, gy + row as i64 * s + dy, color, 1.0);
                        }
                    }
                }
            }
        }
    }

    /// Draws `text` centred horizontally on `cx`, top at `y`.
    pub fn text_centered(&mut self, cx: f64, y: f64, text: &str, scale: usize, color: Rgb) {
        self.text(cx - 0.5 * Self::text_width(text, scale), y, text, scale, color);
    }

    /// Draws `text` right-aligned at `right`, vertically centred on `cy`.
    pub fn text_right(&mut self, right: f64, cy: f64, text: &str, scale: usize, color: Rgb) {
        self.text(right - Self::text_width(text, scale), cy - 0.5 * Self::text_height(scale), text, scale, color);
    }

    /// The 8-bit RGB image.
    pub fn into_image(self) -> Image {
        let data: Vec<u8> = self.px.iter().flat_map(|p| p.map(|v| v.round().clamp(0.0, 255.0) as u8)).collect();
        let mut img = Image::new(self.width, self.height, 3);
        img.data_mut().copy_from_slice(&data);
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thick_line_has_exact_core_and_soft_edges() {
        let mut c = Canvas::new(20, 10, [255, 255, 255]);
        c.line((2.0, 5.25), (18.0, 5.25), 2.0, [10, 20, 30]);
        let img = c.into_image();
        let px = |x: usize, y: usize| [img.get(x, y, 0), img.get(x, y, 1), img.get(x, y, 2)];
        // Row 5 (centre 5.5, 0.25 px away) is fully covered.
        assert_eq!(px(10, 5), [10, 20, 30]);
        assert_eq!(px(10, 3), [255, 255, 255]);
        assert_eq!(px(10, 8), [255, 255, 255]);
        // Row 4 (0.75 px away) is 3/4 covered, row 6 (1.25 px away) 1/4.
        assert_eq!(px(10, 4)[0], (255.0 * 0.25 + 10.0 * 0.75f64).round() as u8);
        assert_eq!(px(10, 6)[0], (255.0 * 0.75 + 10.0 * 0.25f64).round() as u8);
    }

    #[test]
    fn text_draws_ink_inside_its_box() {
        let mut c = Canvas::new(40, 20, [255, 255, 255]);
        c.text(1.0, 1.0, "8.", 2, [0, 0, 0]);
        let img = c.into_image();
        let ink = (0..20).flat_map(|y| (0..40).map(move |x| (x, y))).filter(|&(x, y)| img.get(x, y, 0) == 0);
        let mut n = 0;
        for (x, y) in ink {
            n += 1;
            assert!((1..1 + Canvas::text_width("8.", 2) as usize).contains(&x) && (1..15).contains(&y));
        }
        assert!(n > 40, "{n}");
    }
}
