//! FAST-9 corner detection (Rosten & Drummond, "Machine learning for
//! high-speed corner detection", ECCV 2006): a pixel is a corner when at least
//! 9 contiguous pixels of the 16-pixel Bresenham circle of radius 3 around it
//! are all brighter than `centre + t` or all darker than `centre - t`.
//!
//! Implementation: a vectorised pre-test per row on the 8 even circle pixels
//! (any arc of 9 contiguous circle pixels contains 4 consecutive even ones),
//! then the exact test with 16-bit masks on the few survivors.

use crate::pyramid::Plane;

/// Radius of the Bresenham circle.
pub(crate) const FAST_RADIUS: usize = 3;
/// Contiguous circle pixels required (FAST-9).
const ARC: usize = 9;
/// Pixels on the circle.
const CIRCLE_LEN: usize = 16;

/// The circle as (dx, dy), in circular order starting straight above the
/// centre and going clockwise on screen. Indices 0, 4, 8, 12 are the compass
/// pixels (up, right, down, left).
const CIRCLE: [(isize, isize); CIRCLE_LEN] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// True if the 16-bit circular mask has `ARC` contiguous set bits.
#[inline]
fn has_arc(mask: u16) -> bool {
    // Doubling the mask turns circular runs into linear ones; AND-ing shifted
    // copies leaves bit i set iff bits i..i+ARC are all set.
    let m = mask as u32 | ((mask as u32) << CIRCLE_LEN);
    let mut run = m;
    for s in 1..ARC {
        run &= m >> s;
    }
    run != 0
}

/// `a` rotated left by `s` lanes: `out[i] = a[(i + s) % 16]`.
#[inline(always)]
fn rot(a: &[i16; CIRCLE_LEN], s: usize) -> [i16; CIRCLE_LEN] {
    std::array::from_fn(|i| a[(i + s) % CIRCLE_LEN])
}

/// FAST score of a corner: the largest `t'` such that the pixel is still a
/// corner at threshold `t' - 1`, i.e. over all arcs of 9, the best arc's
/// smallest contrast. Arc minima come from doubling windows (1, 2, 4, 8, then
/// 8 + 1), 4 lane-wise steps instead of 9 * 16 comparisons.
#[inline]
fn corner_score(diff: &[i16; CIRCLE_LEN]) -> i16 {
    let zip = |a: [i16; CIRCLE_LEN], b: [i16; CIRCLE_LEN], f: fn(i16, i16) -> i16| -> [i16; CIRCLE_LEN] {
        std::array::from_fn(|i| f(a[i], b[i]))
    };
    // Minimum (bright arcs) and maximum (dark arcs) over windows of 8, then 9.
    let mn2 = zip(*diff, rot(diff, 1), i16::min);
    let mx2 = zip(*diff, rot(diff, 1), i16::max);
    let mn4 = zip(mn2, rot(&mn2, 2), i16::min);
    let mx4 = zip(mx2, rot(&mx2, 2), i16::max);
    let mn8 = zip(mn4, rot(&mn4, 4), i16::min);
    let mx8 = zip(mx4, rot(&mx4, 4), i16::max);
    let last = rot(diff, 8);
    let mn9 = zip(mn8, last, i16::min);
    let mx9 = zip(mx8, last, i16::max);
    let bright = mn9.iter().copied().max().unwrap_or(0);
    // A dark arc's contrast is -max(diff) over the arc.
    let dark = -mx9.iter().copied().min().unwrap_or(0);
    bright.max(dark).max(0)
}

/// The pre-test for one row: `rows` are the centres then the 8 even circle
/// pixels in circular order, all of the length of `flags`. Sets `flags[i]`
/// to 1 when 4 circularly consecutive even pixels are all brighter than
/// `centre + t` or all darker than `centre - t`.
#[inline(always)]
fn prefilter_kernel(rows: &[&[u8]; 9], t: u8, flags: &mut [u8]) {
    let n = flags.len();
    let [c, p0, p2, p4, p6, p8, p10, p12, p14] = rows.map(|r| &r[..n]);
    // Branch-free on slices of length n, so this loop is vectorised.
    for i in 0..n {
        let hi = c[i].saturating_add(t);
        let lo = c[i].saturating_sub(t);
        let b = (p0[i] > hi) as u8
            | ((p2[i] > hi) as u8) << 1
            | ((p4[i] > hi) as u8) << 2
            | ((p6[i] > hi) as u8) << 3
            | ((p8[i] > hi) as u8) << 4
            | ((p10[i] > hi) as u8) << 5
            | ((p12[i] > hi) as u8) << 6
            | ((p14[i] > hi) as u8) << 7;
        let k = (p0[i] < lo) as u8
            | ((p2[i] < lo) as u8) << 1
            | ((p4[i] < lo) as u8) << 2
            | ((p6[i] < lo) as u8) << 3
            | ((p8[i] < lo) as u8) << 4
            | ((p10[i] < lo) as u8) << 5
            | ((p12[i] < lo) as u8) << 6
            | ((p14[i] < lo) as u8) << 7;
        // 4 circularly consecutive set bits.
        let b2 = b & b.rotate_right(1);
        let k2 = k & k.rotate_right(1);
        let any = (b2 & b2.rotate_right(2)) | (k2 & k2.rotate_right(2));
        flags[i] = (any != 0) as u8;
    }
}

crate::simd::multiversion!(prefilter_row, prefilter_kernel, (rows: &[&[u8]; 9], t: u8, flags: &mut [u8]));

/// Detector state for one pyramid level: a score map (0 = not a corner) and
/// the candidate pixel indices found so far.
pub(crate) struct FastMap {
    /// Per-pixel FAST score, 0 where no corner was found.
    pub score: Vec<u8>,
    /// Linear indices `y * width + x` of the corners, in detection order.
    pub corners: Vec<u32>,
    /// Circle offsets as linear index deltas for this plane's width.
    offsets: [isize; CIRCLE_LEN],
    /// Row buffer for the pre-test.
    flags: Vec<u8>,
    /// Columns of one row that passed the pre-test.
    survivors: Vec<usize>,
}

impl FastMap {
    pub fn new(plane: &Plane) -> Self {
        let w = plane.width as isize;
        let offsets = CIRCLE.map(|(dx, dy)| dy * w + dx);
        Self {
            score: vec![0; plane.width * plane.height],
            corners: Vec::new(),
            offsets,
            flags: vec![0; plane.width],
            survivors: Vec::with_capacity(plane.width),
        }
    }

    /// Forgets every corner found so far (the score map is cleared where
    /// corners were, so this costs in proportion to their number).
    pub fn reset(&mut self) {
        for &ci in &self.corners {
            if let Some(s) = self.score.get_mut(ci as usize) {
                *s = 0;
            }
        }
        self.corners.clear();
    }

    /// Detects corners with threshold `t` in the rectangle `[x0, x1) x [y0, y1)`,
    /// writing their scores into the map and appending them to `corners`.
    ///
    /// Precondition (checked, the call does nothing otherwise): the rectangle
    /// lies at least [`FAST_RADIUS`] pixels inside the plane, so every circle
    /// read is in bounds.
    pub fn detect(&mut self, plane: &Plane, rect: (usize, usize, usize, usize), t: u8) {
        self.detect_where(plane, rect, t, |_| true);
    }

    /// As [`FastMap::detect`], testing only the columns `x` for which
    /// `keep(x)` holds (the cheap, vectorised pre-test still runs on whole
    /// rows, which is faster than many short rows).
    pub fn detect_where(
        &mut self,
        plane: &Plane,
        rect: (usize, usize, usize, usize),
        t: u8,
        keep: impl Fn(usize) -> bool,
    ) {
        let (x0, x1, y0, y1) = rect;
        let (w, h) = (plane.width, plane.height);
        let r = FAST_RADIUS;
        if x0 < r || y0 < r || x1 + r > w || y1 + r > h || x0 >= x1 || y0 >= y1 {
            return;
        }
        let n = x1 - x0;
        let d = &plane.data;
        // Row slice of length exactly n starting at (x0 + dx, yy).
        let span = |yy: usize, dx: isize| {
            let s = (yy * w + x0) as isize + dx;
            &d[s as usize..s as usize + n]
        };
        for y in y0..y1 {
            // The 8 even circle pixels (a 9-arc always covers 4 consecutive
            // ones), in circular order.
            let c = span(y, 0);
            let p0 = span(y - r, 0);
            let p2 = span(y - 2, 2);
            let p4 = span(y, 3);
            let p6 = span(y + 2, 2);
            let p8 = span(y + r, 0);
            let p10 = span(y + 2, -2);
            let p12 = span(y, -3);
            let p14 = span(y - 2, -2);
            prefilter_row(&[c, p0, p2, p4, p6, p8, p10, p12, p14], t, &mut self.flags[..n]);
            // Survivors are sparse: skip 32 flags at a time.
            let mut survivors = Vec::new();
            std::mem::swap(&mut survivors, &mut self.survivors);
            survivors.clear();
            let flags = &self.flags[..n];
            // Flags as little-endian words: byte j of word k is column 8k + j.
            let mut word_of = |k: usize, mut bits: u64| {
                while bits != 0 {
                    survivors.push(k * 8 + bits.trailing_zeros() as usize / 8);
                    // Flags are 0 or 1: clear the lowest set byte.
                    bits &= bits - 1;
                }
            };
            // Blocks of 32 columns with no survivor are skipped at once.
            let mut k = 0;
            for block in flags.chunks_exact(32) {
                let w: [u64; 4] = std::array::from_fn(|j| {
                    let b: [u8; 8] = block[8 * j..8 * j + 8].try_into().unwrap_or([0; 8]);
                    u64::from_le_bytes(b)
                });
                if (w[0] | w[1] | w[2] | w[3]) != 0 {
                    for (j, &bits) in w.iter().enumerate() {
                        word_of(k + j, bits);
                    }
                }
                k += 4;
            }
            for chunk in flags[k * 8..].chunks(8) {
                let mut word = [0u8; 8];
                word[..chunk.len()].copy_from_slice(chunk);
                let bits = u64::from_le_bytes(word);
                word_of(k, bits);
                k += 1;
            }
            for &i in &survivors {
                if !keep(x0 + i) {
                    continue;
                }
                let ci = y * w + x0 + i;
                let cv = d[ci] as i16;
                let mut diff = [0i16; CIRCLE_LEN];
                let mut bright = 0u16;
                let mut dark = 0u16;
                for (k, (&o, dk)) in self.offsets.iter().zip(diff.iter_mut()).enumerate() {
                    // In bounds: the centre is >= r pixels from every border.
                    let p = d[(ci as isize + o) as usize] as i16;
                    *dk = p - cv;
                    bright |= ((*dk > t as i16) as u16) << k;
                    dark |= ((*dk < -(t as i16)) as u16) << k;
                }
                if has_arc(bright) || has_arc(dark) {
                    let s = corner_score(&diff).clamp(1, u8::MAX as i16) as u8;
                    self.score[ci] = s;
                    self.corners.push(ci as u32);
                }
            }
            self.survivors = survivors;
        }
    }

    /// Non-maximum suppression over 3x3 neighbourhoods: keeps a corner when
    /// every neighbour has a lower score, or an equal score and comes later in
    /// raster order (so exactly one of two tied neighbours survives). Returns
    /// the surviving pixel indices in ascending order.
    pub fn suppress(&self, width: usize) -> Vec<u32> {
        let w = width as isize;
        let neighbours = [-w - 1, -w, -w + 1, -1, 1, w - 1, w, w + 1];
        let mut keep: Vec<u32> = self
            .corners
            .iter()
            .copied()
            .filter(|&ci| {
                let s = self.score[ci as usize];
                neighbours.iter().all(|&o| {
                    let ni = ci as isize + o;
                    // Corners lie >= FAST_RADIUS pixels inside the plane, so
                    // all 8 neighbours exist; `get` keeps this panic-free.
                    let ns = self.score.get(ni as usize).copied().unwrap_or(0);
                    ns < s || (ns == s && ni > ci as isize)
                })
            })
            .collect();
        keep.sort_unstable();
        keep
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arc_detection() {
        assert!(has_arc(0b0000_0001_1111_1111));
        assert!(!has_arc(0b0000_0000_1111_1111));
        // Wrapping run: bits 12..16 and 0..5 = 4 + 5 = 9.
        assert!(has_arc(0b1111_0000_0001_1111));
        assert!(!has_arc(0b1111_0000_0000_1111));
        assert!(has_arc(u16::MAX));
        assert!(!has_arc(0b0101_0101_0101_0101));
    }

    /// Naive FAST test, straight from the definition.
    fn naive_corner(p: &Plane, x: usize, y: usize, t: i16) -> bool {
        let c = p.data[y * p.width + x] as i16;
        let v: Vec<i16> = CIRCLE
            .iter()
            .map(|&(dx, dy)| p.data[(y as isize + dy) as usize * p.width + (x as isize + dx) as usize] as i16)
            .collect();
        (0..16).any(|s| (0..9).all(|j| v[(s + j) % 16] > c + t) || (0..9).all(|j| v[(s + j) % 16] < c - t))
    }

    #[test]
    fn matches_naive_definition_and_score_is_threshold() {
        let (w, h) = (64usize, 48usize);
        let mut state = 12345u64;
        let data: Vec<u8> = (0..w * h)
            .map(|i| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                // Blocky random texture: corners at block junctions and noise.
                let (x, y) = (i % w, i / w);
                (((x / 5 * 37 + y / 4 * 91) % 200) as u64 + (state >> 60)) as u8
            })
            .collect();
        let p = Plane { width: w, height: h, data };
        for t in [7u8, 20] {
            let mut m = FastMap::new(&p);
            m.detect(&p, (3, w - 3, 3, h - 3), t);
            let mut naive = Vec::new();
            for y in 3..h - 3 {
                for x in 3..w - 3 {
                    if naive_corner(&p, x, y, t as i16) {
                        naive.push((y * w + x) as u32);
                    }
                }
            }
            assert!(!naive.is_empty());
            assert_eq!(m.corners, naive, "t={t}");
            for &ci in &m.corners {
                let (x, y) = (ci as usize % w, ci as usize / w);
                let s = m.score[ci as usize] as i16;
                assert!(naive_corner(&p, x, y, s - 1), "still a corner at score-1");
                assert!(!naive_corner(&p, x, y, s), "not a corner at the score");
            }
            let kept = m.suppress(w);
            assert!(!kept.is_empty() && kept.len() <= m.corners.len());
        }
    }

    #[test]
    fn out_of_bounds_rectangles_are_ignored() {
        let p = Plane { width: 10, height: 10, data: vec![0; 100] };
        let mut m = FastMap::new(&p);
        m.detect(&p, (0, 10, 0, 10), 20);
        m.detect(&p, (3, 8, 3, 7), 20);
        assert!(m.corners.is_empty());
    }
}
