//! The few neural-network operations XFeat needs, on single images stored
//! channel-major (`C x H x W`, row-major inside a channel): 2-D convolution
//! as im2col + SGEMM (`matrixmultiply`), with the BatchNorm folded in at
//! load time, plus pooling, bilinear resizing (PyTorch's
//! `align_corners=False` rule), instance normalisation and 8x8
//! pixel-unshuffle. Work is split over output pixels with rayon.

use rayon::prelude::*;

/// A `c x h x w` feature map.
#[derive(Debug, Clone, PartialEq)]
pub struct Map {
    /// Channels.
    pub c: usize,
    /// Rows.
    pub h: usize,
    /// Columns.
    pub w: usize,
    /// `c * h * w` values: channel, then row, then column.
    pub data: Vec<f32>,
}

impl Map {
    /// A zero map.
    pub fn zeros(c: usize, h: usize, w: usize) -> Self {
        Self { c, h, w, data: vec![0.0; c * h * w] }
    }

    /// Pixels per channel.
    pub fn plane(&self) -> usize {
        self.h * self.w
    }

    /// One channel as a slice (`k < c`).
    pub fn channel(&self, k: usize) -> &[f32] {
        let n = self.plane();
        &self.data[k * n..(k + 1) * n]
    }

    /// Value at (channel, row, column), all in range.
    #[inline]
    pub fn at(&self, k: usize, y: usize, x: usize) -> f32 {
        self.data[(k * self.h + y) * self.w + x]
    }
}

/// A 2-D convolution with bias and optional ReLU (a folded
/// Conv -> BatchNorm -> ReLU block, or a plain biased Conv).
#[derive(Debug, Clone)]
pub struct Conv {
    /// Output channels.
    pub cout: usize,
    /// Input channels.
    pub cin: usize,
    /// Square kernel size.
    pub k: usize,
    /// Stride.
    pub stride: usize,
    /// Zero padding on every side.
    pub pad: usize,
    /// `cout x (cin * k * k)` weights, PyTorch's `[cout, cin, k, k]` layout.
    pub weight: Vec<f32>,
    /// `cout` biases.
    pub bias: Vec<f32>,
    /// Apply ReLU after the bias.
    pub relu: bool,
}

/// Target number of `f32`s in one task's im2col block (about L2-sized).
const COL_BLOCK_FLOATS: usize = 1 << 16;
/// Smallest number of output pixels per task.
const MIN_COLS_PER_TASK: usize = 256;

impl Conv {
    /// Output size along one axis for input size `n`.
    pub fn out_len(&self, n: usize) -> usize {
        (n + 2 * self.pad).saturating_sub(self.k) / self.stride + 1
    }

    /// Applies the convolution. The caller guarantees `x.c == self.cin` and
    /// a non-empty input at least as large as the kernel after padding.
    pub fn forward(&self, x: &Map) -> Map {
        debug_assert_eq!(x.c, self.cin);
        let (ho, wo) = (self.out_len(x.h), self.out_len(x.w));
        let n = ho * wo;
        let kk = self.cin * self.k * self.k;
        let mut out = Map::zeros(self.cout, ho, wo);
        if n == 0 || self.cout == 0 {
            return out;
        }
        // Tasks cover whole output rows so im2col can copy row segments.
        let rows_per_task = (COL_BLOCK_FLOATS / kk.max(1)).max(MIN_COLS_PER_TASK).div_ceil(wo).min(ho);
        let direct = self.k == 1 && self.stride == 1 && self.pad == 0;
        // Each task computes `cout x nb` outputs for its pixel range into its own buffer.
        let blocks: Vec<(usize, Vec<f32>)> = (0..ho)
            .step_by(rows_per_task)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|oy0| {
                let rows = rows_per_task.min(ho - oy0);
                let (j0, nb) = (oy0 * wo, rows * wo);
                let mut block = vec![0.0f32; self.cout * nb];
                if direct {
                    // B is the input itself: rows = input channels, row stride = n.
                    gemm(self.cout, kk, nb, &self.weight, &x.data[j0..], n, &mut block);
                } else {
                    let col = self.im2col(x, wo, oy0, rows);
                    gemm(self.cout, kk, nb, &self.weight, &col, nb, &mut block);
                }
                for (o, row) in block.chunks_exact_mut(nb).enumerate() {
                    let b = self.bias[o];
                    if self.relu {
                        row.iter_mut().for_each(|v| *v = (*v + b).max(0.0));
                    } else {
                        row.iter_mut().for_each(|v| *v += b);
                    }
                }
                (j0, block)
            })
            .collect();
        for (j0, block) in blocks {
            let nb = block.len() / self.cout;
            for (o, row) in block.chunks_exact(nb).enumerate() {
                out.data[o * n + j0..o * n + j0 + nb].copy_from_slice(row);
            }
        }
        out
    }

    /// The im2col block for output rows `oy0 .. oy0 + rows`:
    /// `(cin*k*k) x (rows*wo)`; taps in the zero padding stay 0.
    fn im2col(&self, x: &Map, wo: usize, oy0: usize, rows: usize) -> Vec<f32> {
        let kk = self.cin * self.k * self.k;
        let nb = rows * wo;
        let mut col = vec![0.0f32; kk * nb];
        let (s, p) = (self.stride, self.pad);
        for ci in 0..self.cin {
            let src = x.channel(ci);
            for ky in 0..self.k {
                for kx in 0..self.k {
                    let r = (ci * self.k + ky) * self.k + kx;
                    let dst = &mut col[r * nb..(r + 1) * nb];
                    // Output columns whose tap ix = ox*s + kx - p lies in [0, w).
                    let ox_lo = (p.saturating_sub(kx)).div_ceil(s);
                    let ox_hi = ((x.w + p).saturating_sub(kx)).div_ceil(s).min(wo);
                    if ox_lo >= ox_hi {
                        continue;
                    }
                    for (t, drow) in dst.chunks_exact_mut(wo).enumerate() {
                        let iy = (oy0 + t) * s + ky;
                        if iy < p || iy - p >= x.h {
                            continue;
                        }
                        let srow = &src[(iy - p) * x.w..(iy - p + 1) * x.w];
                        let ix0 = ox_lo * s + kx - p;
                        if s == 1 {
                            drow[ox_lo..ox_hi].copy_from_slice(&srow[ix0..ix0 + (ox_hi - ox_lo)]);
                        } else {
                            for (d, v) in drow[ox_lo..ox_hi].iter_mut().zip(srow[ix0..].iter().step_by(s)) {
                                *d = *v;
                            }
                        }
                    }
                }
            }
        }
        col
    }
}

/// `c (m x n) = a (m x k, row-major) * b (k x n, row stride ldb)`.
pub(crate) fn gemm(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], ldb: usize, c: &mut [f32]) {
    gemm_strided(m, k, n, a, b, (ldb, 1), c);
}

/// Work (multiply-adds) below which [`par_gemm_strided`] stays on one thread.
const PAR_GEMM_MIN_WORK: usize = 1 << 20;
/// Smallest number of rows of `a` per parallel task.
const PAR_GEMM_MIN_ROWS: usize = 16;

/// [`gemm_strided`] split over rows of `a` / `c` with rayon.
pub(crate) fn par_gemm_strided(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    b: &[f32],
    strides: (usize, usize),
    c: &mut [f32],
) {
    if m * k * n < PAR_GEMM_MIN_WORK || m < 2 * PAR_GEMM_MIN_ROWS || k == 0 || n == 0 {
        gemm_strided(m, k, n, a, b, strides, c);
        return;
    }
    let rows = (m / (4 * rayon::current_num_threads())).max(PAR_GEMM_MIN_ROWS);
    c[..m * n].par_chunks_mut(rows * n).zip(a[..m * k].par_chunks(rows * k)).for_each(|(cc, aa)| {
        gemm_strided(aa.len() / k, k, n, aa, b, strides, cc);
    });
}

/// `c (m x n, row-major) = a (m x k, row-major) * b`, where element `(i, j)`
/// of the `k x n` matrix `b` is `b[i * rsb + j * csb]`.
pub(crate) fn gemm_strided(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    b: &[f32],
    (rsb, csb): (usize, usize),
    c: &mut [f32],
) {
    if m == 0 || n == 0 {
        return;
    }
    // These hold for every caller (they pass matching sizes); checking keeps
    // the unsafe call below sound whatever happens.
    assert!(a.len() >= m * k, "gemm: A too short");
    assert!(c.len() >= m * n, "gemm: C too short");
    assert!(k == 0 || b.len() > (k - 1) * rsb + (n - 1) * csb, "gemm: B too short");
    let (rsb, csb) = (rsb as isize, csb as isize);
    // SAFETY: the asserts above prove every element sgemm touches is inside
    // the slices: A is m x k with strides (k, 1), B is k x n with strides
    // (rsb, csb), C is m x n with strides (n, 1), and C does not alias A or B
    // (it is a unique borrow).
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            rsb,
            csb,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

/// Non-overlapping `s x s` average pooling (floors the size like PyTorch).
pub fn avg_pool(x: &Map, s: usize) -> Map {
    let (ho, wo) = (x.h / s, x.w / s);
    let mut out = Map::zeros(x.c, ho, wo);
    let inv = 1.0 / (s * s) as f32;
    for k in 0..x.c {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = 0.0f32;
                for dy in 0..s {
                    for dx in 0..s {
                        acc += x.at(k, oy * s + dy, ox * s + dx);
                    }
                }
                out.data[(k * ho + oy) * wo + ox] = acc * inv;
            }
        }
    }
    out
}

/// Source index and weights of PyTorch's bilinear resize with
/// `align_corners=False` (`area_pixel_compute_source_index`): for output
/// index `d`, `src = (d + 0.5) * in/out - 0.5`, clamped below at 0.
fn linear_taps(out_len: usize, in_len: usize) -> Vec<(usize, usize, f32, f32)> {
    let scale = in_len as f32 / out_len as f32;
    (0..out_len)
        .map(|d| {
            let src = (scale * (d as f32 + 0.5) - 0.5).max(0.0);
            let i0 = (src as usize).min(in_len - 1);
            let i1 = if i0 < in_len - 1 { i0 + 1 } else { i0 };
            let l1 = src - i0 as f32;
            (i0, i1, 1.0 - l1, l1)
        })
        .collect()
}

/// Bilinear resize to `ho x wo`, `align_corners=False`, no antialiasing (as
/// `F.interpolate(mode='bilinear')`). `x` must be non-empty.
pub fn resize_bilinear(x: &Map, ho: usize, wo: usize) -> Map {
    let ty = linear_taps(ho, x.h);
    let tx = linear_taps(wo, x.w);
    let mut out = Map::zeros(x.c, ho, wo);
    for k in 0..x.c {
        let src = x.channel(k);
        let dst = &mut out.data[k * ho * wo..(k + 1) * ho * wo];
        for (oy, &(y0, y1, wy0, wy1)) in ty.iter().enumerate() {
            for (ox, &(x0, x1, wx0, wx1)) in tx.iter().enumerate() {
                let v = wy0 * (wx0 * src[y0 * x.w + x0] + wx1 * src[y0 * x.w + x1])
                    + wy1 * (wx0 * src[y1 * x.w + x0] + wx1 * src[y1 * x.w + x1]);
                dst[oy * wo + ox] = v;
            }
        }
    }
    out
}

/// PyTorch's default epsilon of InstanceNorm / BatchNorm.
pub const NORM_EPS: f64 = 1e-5;

/// Instance normalisation of every channel (no affine, biased variance, as
/// `nn.InstanceNorm2d` with default arguments). Sums in `f64`.
pub fn instance_norm(x: &mut Map) {
    let n = x.plane();
    if n == 0 {
        return;
    }
    for ch in x.data.chunks_exact_mut(n) {
        let mean = ch.iter().map(|&v| f64::from(v)).sum::<f64>() / n as f64;
        let var = ch.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / n as f64;
        let inv = 1.0 / (var + NORM_EPS).sqrt();
        for v in ch.iter_mut() {
            *v = ((f64::from(*v) - mean) * inv) as f32;
        }
    }
}

/// Splits every `s x s` block into `s*s` channels (XFeat's `_unfold2d`,
/// i.e. `pixel_unshuffle`): output channel `c*s*s + dy*s + dx` at `(y, x)` is
/// input `(c, y*s + dy, x*s + dx)`. Sizes are floored to multiples of `s`.
pub fn pixel_unshuffle(x: &Map, s: usize) -> Map {
    let (ho, wo) = (x.h / s, x.w / s);
    let mut out = Map::zeros(x.c * s * s, ho, wo);
    for k in 0..x.c {
        for dy in 0..s {
            for dx in 0..s {
                let oc = (k * s + dy) * s + dx;
                for y in 0..ho {
                    for xx in 0..wo {
                        out.data[(oc * ho + y) * wo + xx] = x.at(k, y * s + dy, xx * s + dx);
                    }
                }
            }
        }
    }
    out
}

/// Element-wise sum of same-shaped maps.
pub fn add_into(acc: &mut Map, x: &Map) {
    debug_assert_eq!((acc.c, acc.h, acc.w), (x.c, x.h, x.w));
    for (a, b) in acc.data.iter_mut().zip(&x.data) {
        *a += b;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct convolution, the definition.
    fn naive(conv: &Conv, x: &Map) -> Map {
        let (ho, wo) = (conv.out_len(x.h), conv.out_len(x.w));
        let mut out = Map::zeros(conv.cout, ho, wo);
        for o in 0..conv.cout {
            for oy in 0..ho {
                for ox in 0..wo {
                    let mut acc = conv.bias[o] as f64;
                    for ci in 0..conv.cin {
                        for ky in 0..conv.k {
                            for kx in 0..conv.k {
                                let iy = (oy * conv.stride + ky) as isize - conv.pad as isize;
                                let ix = (ox * conv.stride + kx) as isize - conv.pad as isize;
                                if iy >= 0 && ix >= 0 && (iy as usize) < x.h && (ix as usize) < x.w {
                                    let wv = conv.weight[((o * conv.cin + ci) * conv.k + ky) * conv.k + kx];
                                    acc += f64::from(wv) * f64::from(x.at(ci, iy as usize, ix as usize));
                                }
                            }
                        }
                    }
                    let v = if conv.relu { acc.max(0.0) } else { acc };
                    out.data[(o * ho + oy) * wo + ox] = v as f32;
                }
            }
        }
        out
    }

    fn pseudo(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5
            })
            .collect()
    }

    #[test]
    fn conv_matches_the_definition() {
        for &(cin, cout, k, stride, pad, h, w) in
            &[(3, 5, 3, 1, 1, 17, 23), (4, 8, 3, 2, 1, 16, 20), (6, 7, 1, 1, 0, 9, 700), (2, 3, 3, 2, 1, 1, 1)]
        {
            let conv = Conv {
                cout,
                cin,
                k,
                stride,
                pad,
                weight: pseudo(cout * cin * k * k, 1),
                bias: pseudo(cout, 2),
                relu: cin % 2 == 0,
            };
            let x = Map { c: cin, h, w, data: pseudo(cin * h * w, 3) };
            let a = conv.forward(&x);
            let b = naive(&conv, &x);
            assert_eq!((a.c, a.h, a.w), (b.c, b.h, b.w));
            let err = a.data.iter().zip(&b.data).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
            assert!(err < 1e-5, "conv {cin}->{cout} k{k} s{stride}: max error {err}");
        }
    }

    #[test]
    fn bilinear_resize_follows_pytorch() {
        // F.interpolate(torch.arange(4.).view(1,1,1,4), (1,8), mode='bilinear')
        // = [0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3].
        let x = Map { c: 1, h: 1, w: 4, data: vec![0.0, 1.0, 2.0, 3.0] };
        let y = resize_bilinear(&x, 1, 8);
        assert_eq!(y.data, vec![0.0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.0]);
        // Same size is the identity.
        let z = resize_bilinear(&x, 1, 4);
        assert_eq!(z.data, x.data);
    }

    #[test]
    fn unshuffle_and_pool() {
        let x = Map { c: 1, h: 4, w: 4, data: (0..16).map(|v| v as f32).collect() };
        let u = pixel_unshuffle(&x, 2);
        assert_eq!((u.c, u.h, u.w), (4, 2, 2));
        assert_eq!(u.channel(0), &[0.0, 2.0, 8.0, 10.0]);
        assert_eq!(u.channel(3), &[5.0, 7.0, 13.0, 15.0]);
        let p = avg_pool(&x, 2);
        assert_eq!(p.data, vec![2.5, 4.5, 10.5, 12.5]);
        let mut n = x.clone();
        instance_norm(&mut n);
        let mean: f32 = n.data.iter().sum::<f32>() / 16.0;
        assert!(mean.abs() < 1e-6);
    }
}
