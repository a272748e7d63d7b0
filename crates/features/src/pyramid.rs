//! 8-bit single-channel planes, bilinear down-sampling and the 7x7 Gaussian
//! blur applied before computing descriptors.
//!
//! Everything works on `u8` rows with fixed-point arithmetic and reusable row
//! buffers, written as plain loops over slices so the compiler vectorises them.

/// A gray 8-bit plane, row-major, `data.len() == width * height`.
#[derive(Debug, Clone)]
pub(crate) struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl Plane {
    /// Row `y`; `y < height`.
    #[inline]
    pub fn row(&self, y: usize) -> &[u8] {
        &self.data[y * self.width..(y + 1) * self.width]
    }
}

/// Fractional bits of the bilinear weights (8: a weighted pixel fits u16).
const RESIZE_BITS: u32 = 8;
/// `1.0` in bilinear weight units.
const RESIZE_ONE: u16 = 1 << RESIZE_BITS;

/// Per destination coordinate: the two source indices and the weight of the
/// second, for pixel-centre aligned sampling (`s = (d + 0.5) * scale - 0.5`,
/// clamped to the source).
fn resize_taps(dst_len: usize, src_len: usize) -> Vec<(usize, usize, u16)> {
    let scale = src_len as f64 / dst_len as f64;
    let last = src_len.saturating_sub(1);
    (0..dst_len)
        .map(|d| {
            let s = ((d as f64 + 0.5) * scale - 0.5).clamp(0.0, last as f64);
            let i = (s.floor() as usize).min(last);
            let frac = ((s - i as f64) * RESIZE_ONE as f64).round() as u16;
            (i, (i + 1).min(last), frac.min(RESIZE_ONE))
        })
        .collect()
}

/// Bilinear resize of `src` to `width x height`, pixel centres aligned as
/// OpenCV's `INTER_LINEAR`. Vertical blend first (vectorised, u16), then
/// the horizontal one per destination pixel.
pub(crate) fn resize_bilinear(src: &Plane, width: usize, height: usize) -> Plane {
    let mut out = vec![0u8; width * height];
    if src.width == 0 || src.height == 0 || width == 0 || height == 0 {
        return Plane { width, height, data: out };
    }
    let xt = resize_taps(width, src.width);
    let yt = resize_taps(height, src.height);
    let mut vrow = vec![0u16; src.width];
    let round = 1u32 << (2 * RESIZE_BITS - 1);
    for (dy, &(y0, y1, fy)) in yt.iter().enumerate() {
        let (r0, r1) = (src.row(y0), src.row(y1));
        blend_rows(r0, r1, fy, &mut vrow);
        let dst = &mut out[dy * width..(dy + 1) * width];
        for (d, &(x0, x1, fx)) in dst.iter_mut().zip(&xt) {
            // x0, x1 < src.width by construction of the taps.
            let a = vrow.get(x0).copied().unwrap_or(0) as u32;
            let b = vrow.get(x1).copied().unwrap_or(0) as u32;
            *d = ((a * (RESIZE_ONE - fx) as u32 + b * fx as u32 + round) >> (2 * RESIZE_BITS)) as u8;
        }
    }
    Plane { width, height, data: out }
}

/// Radius of the descriptor smoothing kernel (7x7).
pub(crate) const BLUR_RADIUS: usize = 3;
/// Gaussian weights for sigma = 2, 7 taps, in 1/256 units (sum 256):
/// exp(-x^2 / 8) normalised is 0.0702, 0.1311, 0.1907, 0.2166, ... (each
/// weight within 0.6/256 of it).
const BLUR_WEIGHTS: [u16; 2 * BLUR_RADIUS + 1] = [18, 33, 49, 56, 49, 33, 18];
/// Fixed-point shift of [`BLUR_WEIGHTS`].
const BLUR_SHIFT: u32 = 8;

/// One row of the 7-tap blur: `dst[i] = sum_k BLUR_WEIGHTS[k] * taps[k][i]`,
/// rounded. The kernel is symmetric: 4 multiplies per output instead of 7,
/// and one pass over the taps (no accumulator traffic). In u16:
/// 255 * 256 + 128 < 2^16, and every partial sum is below the total.
#[inline(always)]
fn blur_row_kernel(taps: [&[u8]; 7], dst: &mut [u8]) {
    let [k0, k1, k2, k3, ..] = BLUR_WEIGHTS;
    let round = 1u16 << (BLUR_SHIFT - 1);
    let n = dst.len();
    let [t0, t1, t2, t3, t4, t5, t6] = taps.map(|s| &s[..n]);
    for i in 0..n {
        let v = k0 * (t0[i] as u16 + t6[i] as u16)
            + k1 * (t1[i] as u16 + t5[i] as u16)
            + k2 * (t2[i] as u16 + t4[i] as u16)
            + k3 * t3[i] as u16
            + round;
        dst[i] = (v >> BLUR_SHIFT) as u8;
    }
}

crate::simd::multiversion!(blur_row, blur_row_kernel, (taps: [&[u8]; 7], dst: &mut [u8]));

/// Vertical bilinear blend of two rows into u16 (weights in 1/256).
#[inline(always)]
fn blend_rows_kernel(r0: &[u8], r1: &[u8], fy: u16, out: &mut [u16]) {
    let w0 = RESIZE_ONE - fy;
    for ((v, &a), &b) in out.iter_mut().zip(r0).zip(r1) {
        // a * w0 + b * fy <= 255 * 256 < 2^16.
        *v = a as u16 * w0 + b as u16 * fy;
    }
}

crate::simd::multiversion!(blend_rows, blend_rows_kernel, (r0: &[u8], r1: &[u8], fy: u16, out: &mut [u16]));

/// Reflect-101 border index (`-1 -> 1`, `n -> n - 2`), clamped so that it is
/// always in range even for planes smaller than the kernel.
#[inline]
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    let mut j = if i < 0 { -i } else { i };
    if j >= n {
        j = 2 * (n - 1) - j;
    }
    j.clamp(0, (n - 1).max(0)) as usize
}

/// 7x7 Gaussian blur (sigma 2) with reflect-101 borders, as ORB-SLAM and
/// OpenCV's ORB smooth each level before sampling the descriptor pattern.
pub(crate) fn gaussian_blur7(src: &Plane) -> Plane {
    let (w, h) = (src.width, src.height);
    let mut tmp = vec![0u8; w * h];
    let mut out = vec![0u8; w * h];
    if w == 0 || h == 0 {
        return Plane { width: w, height: h, data: out };
    }
    let r = BLUR_RADIUS;
    let round = 1u16 << (BLUR_SHIFT - 1);
    // Horizontal pass.
    for y in 0..h {
        let row = src.row(y);
        let dst = &mut tmp[y * w..(y + 1) * w];
        if w > 2 * r {
            let n = w - 2 * r;
            let taps: [&[u8]; 7] = std::array::from_fn(|k| &row[k..k + n]);
            blur_row(taps, &mut dst[r..r + n]);
        }
        // Border columns (all of them when the row is shorter than the kernel).
        let (left, right) = if w > 2 * r { (0..r, w - r..w) } else { (0..w, w..w) };
        for x in left.chain(right) {
            let mut s = round;
            for (k, &wk) in BLUR_WEIGHTS.iter().enumerate() {
                let xi = reflect101(x as isize + k as isize - r as isize, w);
                s += row[xi] as u16 * wk;
            }
            dst[x] = (s >> BLUR_SHIFT) as u8;
        }
    }
    // Vertical pass.
    for y in 0..h {
        let taps: [&[u8]; 7] = std::array::from_fn(|k| {
            let yi = reflect101(y as isize + k as isize - r as isize, h);
            &tmp[yi * w..(yi + 1) * w]
        });
        blur_row(taps, &mut out[y * w..(y + 1) * w]);
    }
    Plane { width: w, height: h, data: out }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_weights_sum_to_one() {
        assert_eq!(BLUR_WEIGHTS.iter().map(|&w| w as u32).sum::<u32>(), 1 << BLUR_SHIFT);
        // Within 1/256 of the exact normalised Gaussian.
        let g: Vec<f64> = (-3..=3).map(|x: i32| (-(x * x) as f64 / 8.0).exp()).collect();
        let s: f64 = g.iter().sum();
        for (w, gi) in BLUR_WEIGHTS.iter().zip(&g) {
            assert!((*w as f64 / 256.0 - gi / s).abs() < 1.0 / 256.0);
        }
    }

    #[test]
    fn blur_keeps_constant_and_smooths_impulse() {
        let p = Plane { width: 20, height: 15, data: vec![100; 300] };
        assert!(gaussian_blur7(&p).data.iter().all(|&v| v == 100));
        let mut q = Plane { width: 21, height: 21, data: vec![0; 441] };
        q.data[10 * 21 + 10] = 255;
        let b = gaussian_blur7(&q);
        let c = b.data[10 * 21 + 10];
        assert!(c > 5 && c < 20, "{c}"); // 255 * 0.216^2 = 11.9
        assert_eq!(b.data[10 * 21 + 14], 0); // outside the 7x7 support
        // Tiny planes must not panic.
        for (w, h) in [(1, 1), (2, 3), (5, 1), (7, 7)] {
            let t = Plane { width: w, height: h, data: vec![9; w * h] };
            assert!(gaussian_blur7(&t).data.iter().all(|&v| v == 9));
        }
    }

    #[test]
    fn resize_constant_and_ramp() {
        let p = Plane { width: 40, height: 30, data: vec![77; 1200] };
        let r = resize_bilinear(&p, 33, 25);
        assert!(r.data.iter().all(|&v| v == 77));
        // A horizontal ramp v = 2x: pixel-centre aligned resampling gives
        // 2 * ((d + 0.5) * s - 0.5).
        let ramp: Vec<u8> = (0..30).flat_map(|_| (0..40).map(|x| (2 * x) as u8)).collect();
        let p = Plane { width: 40, height: 30, data: ramp };
        let r = resize_bilinear(&p, 32, 24);
        let s = 40.0 / 32.0;
        for d in 1..31 {
            let want = 2.0 * ((d as f64 + 0.5) * s - 0.5);
            let got = r.data[5 * 32 + d] as f64;
            assert!((got - want).abs() <= 0.6, "d={d} got {got} want {want}");
        }
        // Degenerate sizes do not panic.
        let one = Plane { width: 1, height: 1, data: vec![5] };
        assert_eq!(resize_bilinear(&one, 3, 2).data, vec![5; 6]);
    }
}
