//! Sub-pixel keypoint positions: a 2D quadratic fit of the Harris response
//! around a detection of a pyramid level.
//!
//! FAST and the non-maximum suppression place a corner on the pixel grid of
//! its level, so at level `l` its position at full resolution is quantised
//! to `scale^l` pixels (up to half of that off). The Harris response is a
//! smooth function of position (a windowed sum of gradient products), so
//! the second-order Taylor expansion of its 3x3 neighbourhood locates the
//! maximum between the pixels, as SIFT refines its extrema (Lowe, IJCV 2004,
//! section 4) and OpenCV's `cornerSubPix` refines corners (there with the
//! gradient-orthogonality condition instead of a fit).

use crate::pyramid::Plane;

/// Half-size of the Harris window; the same 7x7 window as the detection
/// score (`orb::harris_response`), so the refined maximum is the maximum of
/// the score that ranked the corner.
const HALF_BLOCK: usize = 3;
/// Side of the grid of Sobel gradients covering the 3x3 neighbourhood's
/// windows: `2 * HALF_BLOCK + 1 + 2`.
const GRID: usize = 2 * HALF_BLOCK + 3;
/// Largest offset of the refined position from the detected pixel, in level
/// pixels: a larger step means the maximum belongs to the neighbour, which
/// the suppression did not pick, so the fit is not trusted beyond the
/// pixel's own cell.
pub const MAX_OFFSET: f64 = 0.5;
/// Smallest pixel distance from the border of the plane a refined keypoint
/// needs (`GRID / 2` gradients, plus one pixel for the Sobel stencil).
pub const MIN_BORDER: usize = GRID / 2 + 1;

/// Harris responses (7x7 window, 3x3 Sobel, `k`) at the 3x3 pixels centred
/// on `(x, y)`, `r[dy + 1][dx + 1]`, normalised as the detection score.
/// `None` when the stencil leaves the plane (closer than [`MIN_BORDER`]).
pub(crate) fn harris_3x3(p: &Plane, x: usize, y: usize, k: f64) -> Option<[[f64; 3]; 3]> {
    let w = p.width;
    let (left, top) = (x.checked_sub(GRID / 2 + 1)?, y.checked_sub(GRID / 2 + 1)?);
    if left + GRID + 2 > w || top + GRID + 2 > p.height {
        return None;
    }
    let px = |xx: usize, yy: usize| p.data.get((top + yy) * w + left + xx).map_or(0, |&v| v as i32);
    // Gradient products at the GRID x GRID pixels around (x, y).
    let mut prod = [[0i64; 3]; GRID * GRID];
    for gy in 0..GRID {
        for gx in 0..GRID {
            let (cx, cy) = (gx + 1, gy + 1);
            let ix = (px(cx + 1, cy) - px(cx - 1, cy)) * 2 + (px(cx + 1, cy - 1) - px(cx - 1, cy - 1))
                + (px(cx + 1, cy + 1) - px(cx - 1, cy + 1));
            let iy = (px(cx, cy + 1) - px(cx, cy - 1)) * 2 + (px(cx - 1, cy + 1) - px(cx - 1, cy - 1))
                + (px(cx + 1, cy + 1) - px(cx + 1, cy - 1));
            if let Some(slot) = prod.get_mut(gy * GRID + gx) {
                *slot = [(ix * ix) as i64, (iy * iy) as i64, (ix * iy) as i64];
            }
        }
    }
    let side = (2 * HALF_BLOCK + 1) as f64;
    // Sobel's largest response is 4 * 255 (as `orb::harris_kernel`).
    let norm = 1.0 / (side * side * (4.0 * 255.0) * (4.0 * 255.0));
    let mut out = [[0f64; 3]; 3];
    for (oy, row) in out.iter_mut().enumerate() {
        for (ox, r) in row.iter_mut().enumerate() {
            let mut s = [0i64; 3];
            for wy in oy..oy + 2 * HALF_BLOCK + 1 {
                for wx in ox..ox + 2 * HALF_BLOCK + 1 {
                    let v = prod.get(wy * GRID + wx).copied().unwrap_or([0; 3]);
                    s[0] += v[0];
                    s[1] += v[1];
                    s[2] += v[2];
                }
            }
            let (a, b, c) = (s[0] as f64 * norm, s[1] as f64 * norm, s[2] as f64 * norm);
            *r = a * b - c * c - k * (a + b) * (a + b);
        }
    }
    Some(out)
}

/// Offset `(dx, dy)` of the maximum of the quadratic through the 3x3 samples
/// `r` (central differences), each clamped to `[-MAX_OFFSET, MAX_OFFSET]`.
/// Where the 2D quadratic has no maximum (a ridge or a saddle), each axis
/// with a negative curvature is fitted alone; an axis without one stays at 0.
pub(crate) fn quadratic_peak(r: &[[f64; 3]; 3]) -> (f64, f64) {
    let gx = 0.5 * (r[1][2] - r[1][0]);
    let gy = 0.5 * (r[2][1] - r[0][1]);
    let hxx = r[1][2] - 2.0 * r[1][1] + r[1][0];
    let hyy = r[2][1] - 2.0 * r[1][1] + r[0][1];
    let hxy = 0.25 * (r[2][2] - r[2][0] - r[0][2] + r[0][0]);
    let det = hxx * hyy - hxy * hxy;
    let clamp = |v: f64| if v.is_finite() { v.clamp(-MAX_OFFSET, MAX_OFFSET) } else { 0.0 };
    if hxx < 0.0 && det > 0.0 {
        // Solve H d = -g.
        let dx = (-gx * hyy + gy * hxy) / det;
        let dy = (-gy * hxx + gx * hxy) / det;
        return (clamp(dx), clamp(dy));
    }
    let axis = |g: f64, h: f64| if h < 0.0 { clamp(-g / h) } else { 0.0 };
    (axis(gx, hxx), axis(gy, hyy))
}

/// The refined position of a corner detected at `(x, y)` of a level, in
/// level pixels; the detected pixel itself where the stencil would leave the
/// plane.
pub(crate) fn refine(p: &Plane, x: usize, y: usize, k: f64) -> (f64, f64) {
    match harris_3x3(p, x, y, k) {
        Some(r) => {
            let (dx, dy) = quadratic_peak(&r);
            (x as f64 + dx, y as f64 + dy)
        }
        None => (x as f64, y as f64),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_peak_recovers_a_paraboloid_maximum() {
        // r(x, y) = 5 - (x - 0.3)^2 - 2 (y + 0.2)^2 + 0.5 (x - 0.3)(y + 0.2)
        let f = |x: f64, y: f64| {
            let (u, v) = (x - 0.3, y + 0.2);
            5.0 - u * u - 2.0 * v * v + 0.5 * u * v
        };
        let r: [[f64; 3]; 3] = std::array::from_fn(|j| std::array::from_fn(|i| f(i as f64 - 1.0, j as f64 - 1.0)));
        let (dx, dy) = quadratic_peak(&r);
        assert!((dx - 0.3).abs() < 1e-12 && (dy + 0.2).abs() < 1e-12, "{dx} {dy}");
        // A maximum beyond the cell is clamped to it.
        let g = |x: f64, y: f64| -(x - 2.0) * (x - 2.0) - y * y;
        let r: [[f64; 3]; 3] = std::array::from_fn(|j| std::array::from_fn(|i| g(i as f64 - 1.0, j as f64 - 1.0)));
        assert_eq!(quadratic_peak(&r), (MAX_OFFSET, 0.0));
        // A saddle: only the axis with a maximum moves.
        let s = |x: f64, y: f64| -(x - 0.25) * (x - 0.25) + y * y;
        let r: [[f64; 3]; 3] = std::array::from_fn(|j| std::array::from_fn(|i| s(i as f64 - 1.0, j as f64 - 1.0)));
        let (dx, dy) = quadratic_peak(&r);
        assert!((dx - 0.25).abs() < 1e-12 && dy == 0.0, "{dx} {dy}");
    }

    #[test]
    fn stencil_stays_inside_the_plane() {
        let p = Plane { width: 20, height: 20, data: vec![7; 400] };
        assert!(harris_3x3(&p, MIN_BORDER, MIN_BORDER, 0.04).is_some());
        assert!(harris_3x3(&p, MIN_BORDER - 1, MIN_BORDER, 0.04).is_none());
        assert!(harris_3x3(&p, 20 - MIN_BORDER - 1, 20 - MIN_BORDER - 1, 0.04).is_some());
        assert!(harris_3x3(&p, 20 - MIN_BORDER, 10, 0.04).is_none());
        assert_eq!(refine(&p, 2, 2, 0.04), (2.0, 2.0));
    }
}
