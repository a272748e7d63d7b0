//! Sub-pixel keypoint positions by gradient-based corner refinement.
//!
//! FAST and the non-maximum suppression place a corner on the pixel grid of
//! its level, so at level `l` its position at full resolution is quantised
//! to `scale^l` pixels, and the chosen pixel is only one of the pixels near
//! the corner that pass the test. The refinement moves it to the point `q`
//! that every image gradient in a window around it is orthogonal to, i.e.
//! the least-squares solution of `sum_p w(p) g(p) g(p)^T (q - p) = 0`:
//! the vertex of a corner or of a saddle (Förstner & Gülch 1987; the
//! condition of OpenCV's `cornerSubPix`), solved once more with the window
//! re-centred on the estimate (bilinear samples).
//!
//! Measured against the synthetic generator's exact geometry this more than
//! halves the median localisation error of matched keypoints, where a
//! quadratic fit of the Harris response around the detected pixel (SIFT's
//! refinement of its extrema) gained under 5 %; on the real sequences the
//! runs got less accurate, so it is off by default (docs/benchmarks.md,
//! "Precision (issue 14)").

use crate::pyramid::Plane;

/// Half-size of the refinement window, level pixels (9x9 samples).
const HALF_WINDOW: isize = 4;
/// Standard deviation of the Gaussian weight of the window's samples,
/// level pixels: the gradients near the estimate count most.
const WINDOW_SIGMA: f64 = 2.5;
/// Iterations: the first solves over the window around the detected
/// pixel, the second over the window re-centred on that estimate. More
/// iterations let the estimate drift off blobs, whose centre is not a
/// stable point of the re-centred iteration: on the synthetic sequence's
/// matches, 2 gave the lowest RMS error and kept the most matches within
/// tolerance of 1, 2, 5 and 20 (docs/benchmarks.md).
const MAX_ITERATIONS: usize = 2;
/// The iteration stops once a step is shorter than this, level pixels.
const CONVERGED: f64 = 0.01;
/// Farthest the refined position may lie from the detected pixel on either
/// axis, level pixels: the descriptor, computed at the detected pixel,
/// still describes the neighbourhood, and a corner farther off is another
/// structure than the one detected.
pub const MAX_OFFSET: f64 = 3.0;
/// Side of the block of bilinear samples one iteration reads: the window
/// plus one sample on each side for the central-difference gradients.
const BLOCK: usize = (2 * HALF_WINDOW + 3) as usize;

/// Refined position of a corner detected at pixel `(x, y)` of a level, in
/// level pixels; the detected pixel itself where the window would leave the
/// plane or the gradients do not constrain both axes (a flat or straight
/// edge patch).
pub(crate) fn refine(p: &Plane, x: usize, y: usize) -> (f64, f64) {
    let weights = window_weights();
    let (x0, y0) = (x as f64, y as f64);
    let (mut cx, mut cy) = (x0, y0);
    let mut block = [0f64; BLOCK * BLOCK];
    for _ in 0..MAX_ITERATIONS {
        if !sample_block(p, cx, cy, &mut block) {
            return (x0, y0);
        }
        let Some((nx, ny)) = solve_step(&block, &weights, cx, cy) else { return (x0, y0) };
        let (nx, ny) = (nx.clamp(x0 - MAX_OFFSET, x0 + MAX_OFFSET), ny.clamp(y0 - MAX_OFFSET, y0 + MAX_OFFSET));
        let step = (nx - cx).hypot(ny - cy);
        (cx, cy) = (nx, ny);
        if step < CONVERGED {
            break;
        }
    }
    (cx, cy)
}

/// Gaussian weights of the window's samples, row-major.
fn window_weights() -> [f64; ((2 * HALF_WINDOW + 1) * (2 * HALF_WINDOW + 1)) as usize] {
    let side = 2 * HALF_WINDOW + 1;
    std::array::from_fn(|i| {
        let (dx, dy) = ((i as isize % side) - HALF_WINDOW, (i as isize / side) - HALF_WINDOW);
        (-((dx * dx + dy * dy) as f64) / (2.0 * WINDOW_SIGMA * WINDOW_SIGMA)).exp()
    })
}

/// Bilinear samples of `p` at `(cx + i, cy + j)` for `i, j` in
/// `-HALF_WINDOW - 1 ..= HALF_WINDOW + 1`, row-major into `block`. All
/// samples share the fractional part of `(cx, cy)`, so they share one set
/// of weights. False when a sample would leave the plane.
fn sample_block(p: &Plane, cx: f64, cy: f64, block: &mut [f64; BLOCK * BLOCK]) -> bool {
    let r = HALF_WINDOW + 1;
    let (fx, fy) = (cx.floor(), cy.floor());
    let (ax, ay) = (cx - fx, cy - fy);
    let (left, top) = (fx as isize - r, fy as isize - r);
    // Taps reach one pixel right of and below the block.
    if left < 0
        || top < 0
        || left + BLOCK as isize + 1 > p.width as isize
        || top + BLOCK as isize + 1 > p.height as isize
    {
        return false;
    }
    let (left, top, w) = (left as usize, top as usize, p.width);
    let (w00, w10, w01, w11) = ((1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay);
    for (j, row) in block.chunks_exact_mut(BLOCK).enumerate() {
        let (Some(r0), Some(r1)) = (
            p.data.get((top + j) * w + left..(top + j) * w + left + BLOCK + 1),
            p.data.get((top + j + 1) * w + left..(top + j + 1) * w + left + BLOCK + 1),
        ) else {
            return false;
        };
        for (i, v) in row.iter_mut().enumerate() {
            let (a, b, c, d) = (r0[i] as f64, r0[i + 1] as f64, r1[i] as f64, r1[i + 1] as f64);
            *v = w00 * a + w10 * b + w01 * c + w11 * d;
        }
    }
    true
}

/// One step: the `q` solving `sum w g g^T (q - p) = 0` over the window
/// centred on `(cx, cy)`, from the block's central-difference gradients.
/// `None` when the structure tensor is (near) singular.
fn solve_step(block: &[f64; BLOCK * BLOCK], weights: &[f64], cx: f64, cy: f64) -> Option<(f64, f64)> {
    let side = (2 * HALF_WINDOW + 1) as usize;
    let (mut a, mut b, mut c, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for j in 0..side {
        for i in 0..side {
            let at = |di: usize, dj: usize| block.get((j + dj) * BLOCK + i + di).copied().unwrap_or(0.0);
            let gx = 0.5 * (at(2, 1) - at(0, 1));
            let gy = 0.5 * (at(1, 2) - at(1, 0));
            let wgt = weights.get(j * side + i).copied().unwrap_or(0.0);
            let (gxx, gxy, gyy) = (wgt * gx * gx, wgt * gx * gy, wgt * gy * gy);
            // Sample position relative to the window centre.
            let (px, py) = (i as f64 - HALF_WINDOW as f64, j as f64 - HALF_WINDOW as f64);
            a += gxx;
            b += gxy;
            c += gyy;
            bx += gxx * px + gxy * py;
            by += gxy * px + gyy * py;
        }
    }
    let det = a * c - b * b;
    // Relative to the tensor's scale: a straight edge has one zero eigenvalue.
    if det.is_nan() || det <= 1e-6 * (a + c) * (a + c) {
        return None;
    }
    let (qx, qy) = ((c * bx - b * by) / det, (a * by - b * bx) / det);
    Some((cx + qx, cy + qy))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane from a function of continuous position.
    fn plane(w: usize, h: usize, f: impl Fn(f64, f64) -> f64) -> Plane {
        let data = (0..w * h).map(|k| f((k % w) as f64, (k / w) as f64).round().clamp(0.0, 255.0) as u8).collect();
        Plane { width: w, height: h, data }
    }

    #[test]
    fn refines_a_saddle_and_a_corner_vertex() {
        // A checkerboard saddle at (20.3, 19.6), detected 0.86 px off.
        let t = |v: f64| (v / 0.8).tanh();
        let saddle = plane(40, 40, |x, y| 128.0 + 100.0 * t(x - 20.3) * t(y - 19.6));
        let (x, y) = refine(&saddle, 21, 19);
        assert!((x - 20.3).hypot(y - 19.6) < 0.05, "{x} {y}");
        // A smoothed right-angle corner: the refinement comes within the
        // inward bias by which the smoothing rounds the corner.
        let s = |v: f64| 1.0 / (1.0 + (-v / 0.7).exp());
        let corner = plane(40, 40, |x, y| 40.0 + 180.0 * s(x - 20.3) * s(y - 19.6));
        let (x, y) = refine(&corner, 21, 19);
        assert!((x - 20.3).hypot(y - 19.6) < 0.4, "{x} {y}");
    }

    #[test]
    fn keeps_the_pixel_near_the_border_and_on_flat_or_edge_patches() {
        let flat = Plane { width: 30, height: 30, data: vec![7; 900] };
        assert_eq!(refine(&flat, 15, 15), (15.0, 15.0));
        let edge = plane(30, 30, |x, _| if x < 14.5 { 30.0 } else { 200.0 });
        assert_eq!(refine(&edge, 15, 15), (15.0, 15.0));
        let blob = plane(30, 30, |x, y| 40.0 + 180.0 * (-((x - 3.4).powi(2) + (y - 3.4).powi(2)) / 8.0).exp());
        assert_eq!(refine(&blob, 3, 3), (3.0, 3.0));
    }
}
