//! Sampling a coarse map at full-resolution keypoint positions exactly as the
//! reference does: positions are normalised with `2 * p / (full - 1) - 1`
//! (XFeat's `InterpolateSparse2d`) and then read by PyTorch's
//! `grid_sample(align_corners=False, padding_mode='zeros')`, which maps the
//! normalised value back with `(g + 1) * size / 2 - 0.5`. Taps outside the
//! map read zero. All arithmetic is `f32` in the reference's order so that
//! rounding decisions (nearest mode) agree.

use crate::nn::Map;

/// PyTorch's bicubic convolution constant (`A = -0.75`).
const CUBIC_A: f32 = -0.75;

/// Map coordinate (in map pixels, centre of pixel 0 at 0) of full-image
/// position `p` for a full size `full` and a map size `size`.
#[inline]
pub(crate) fn map_coord(p: f32, full: usize, size: usize) -> f32 {
    let g = 2.0 * (p / (full as f32 - 1.0)) - 1.0;
    (g + 1.0) * (size as f32 / 2.0) - 0.5
}

/// Value of channel `k` at integer `(x, y)`, zero outside.
#[inline]
fn tap(m: &Map, k: usize, x: i64, y: i64) -> f32 {
    if x >= 0 && y >= 0 && (x as usize) < m.w && (y as usize) < m.h { m.at(k, y as usize, x as usize) } else { 0.0 }
}

/// Nearest-neighbour sample (round half to even, as `nearbyint`).
pub(crate) fn nearest(m: &Map, k: usize, ix: f32, iy: f32) -> f32 {
    tap(m, k, ix.round_ties_even() as i64, iy.round_ties_even() as i64)
}

/// Bilinear sample.
pub(crate) fn bilinear(m: &Map, k: usize, ix: f32, iy: f32) -> f32 {
    let (x0, y0) = (ix.floor(), iy.floor());
    let (x1, y1) = (x0 + 1.0, y0 + 1.0);
    let nw = (x1 - ix) * (y1 - iy);
    let ne = (ix - x0) * (y1 - iy);
    let sw = (x1 - ix) * (iy - y0);
    let se = (ix - x0) * (iy - y0);
    let (xa, ya) = (x0 as i64, y0 as i64);
    tap(m, k, xa, ya) * nw + tap(m, k, xa + 1, ya) * ne + tap(m, k, xa, ya + 1) * sw + tap(m, k, xa + 1, ya + 1) * se
}

/// The four cubic-convolution weights for fractional offset `t`.
fn cubic_coeffs(t: f32) -> [f32; 4] {
    let c1 = |x: f32| ((CUBIC_A + 2.0) * x - (CUBIC_A + 3.0)) * x * x + 1.0;
    let c2 = |x: f32| ((CUBIC_A * x - 5.0 * CUBIC_A) * x + 8.0 * CUBIC_A) * x - 4.0 * CUBIC_A;
    [c2(t + 1.0), c1(t), c1(1.0 - t), c2(2.0 - t)]
}

/// Bicubic sample of every channel into `out` (`out.len() == m.c`).
pub(crate) fn bicubic_all(m: &Map, ix: f32, iy: f32, out: &mut [f32]) {
    let (fx, fy) = (ix.floor(), iy.floor());
    let cx = cubic_coeffs(ix - fx);
    let cy = cubic_coeffs(iy - fy);
    let (x0, y0) = (fx as i64 - 1, fy as i64 - 1);
    for (k, o) in out.iter_mut().enumerate().take(m.c) {
        let mut acc = 0.0f32;
        for (j, wy) in cy.iter().enumerate() {
            let y = y0 + j as i64;
            let row = cx[0] * tap(m, k, x0, y)
                + cx[1] * tap(m, k, x0 + 1, y)
                + cx[2] * tap(m, k, x0 + 2, y)
                + cx[3] * tap(m, k, x0 + 3, y);
            acc += wy * row;
        }
        *o = acc;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_reproduces_linear_and_constant_data() {
        // A map that is linear in x: bilinear reproduces it; PyTorch's
        // bicubic (A = -0.75) does not quite: at t = 0.3 its weights are
        // [-0.11025, 0.83125, 0.32625, -0.04725] (worked by hand), giving
        // 7.684 from the samples 5, 7, 9, 11. Cubic weights sum to 1.
        let (h, w) = (6, 9);
        let m = Map { c: 1, h, w, data: (0..h * w).map(|i| (i % w) as f32 * 2.0 + 1.0).collect() };
        let (ix, iy) = (3.3f32, 2.6f32);
        assert!((bilinear(&m, 0, ix, iy) - (ix * 2.0 + 1.0)).abs() < 1e-5);
        let mut out = [0.0f32];
        bicubic_all(&m, ix, iy, &mut out);
        assert!((out[0] - 7.684).abs() < 1e-4, "{}", out[0]);
        for t in [0.0f32, 0.25, 0.5, 0.9] {
            let s: f32 = cubic_coeffs(t).iter().sum();
            assert!((s - 1.0).abs() < 1e-6);
        }
        // Outside the map reads zero; the nearest rounding is half-to-even.
        assert_eq!(nearest(&m, 0, 9.0, 0.0), 0.0);
        assert_eq!(nearest(&m, 0, 8.5, 0.0), m.at(0, 0, 8));
        assert_eq!(nearest(&m, 0, 7.5, 0.0), m.at(0, 0, 8));
        assert_eq!(nearest(&m, 0, 6.5, 0.0), m.at(0, 0, 6));
        assert_eq!(map_coord(639.0, 640, 640), 639.5);
    }
}
