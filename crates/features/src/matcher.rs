//! Nearest-neighbour descriptor matching: brute force (Hamming distance with
//! 64-bit popcount for binary descriptors, Euclidean for float ones) and a
//! guided variant that searches only near a predicted position.
//!
//! The binary brute force picks at run time the fastest kernel the CPU
//! supports (AVX-512 VPOPCNTQ on a structure-of-arrays copy of the train
//! set, AVX2 byte lookups on a copy split into nibbles, else scalar POPCNT
//! with 4 queries per train load); all give identical results (tested
//! against a bit-by-bit reference). Cross-check
//! comes from the same pass: every distance also updates the train row's
//! best query, so mutual matching costs no second pass.
//!
//! Filters, applied in this order: maximum distance, Lowe's ratio test (best
//! against second-best distance; Lowe, IJCV 2004), and cross-check (mutual
//! nearest neighbours).

use crate::FeatureError;
use crate::types::{Descriptors, Features, Keypoint, Match, Matcher};
use rayon::prelude::*;

/// Hamming distance between two 256-bit descriptors.
#[inline]
pub fn hamming_distance(a: &[u64; 4], b: &[u64; 4]) -> u32 {
    (a[0] ^ b[0]).count_ones() + (a[1] ^ b[1]).count_ones() + (a[2] ^ b[2]).count_ones() + (a[3] ^ b[3]).count_ones()
}

/// Options of [`NnMatcher`].
#[derive(Debug, Clone, PartialEq)]
pub struct NnMatcherOptions {
    /// Keep only mutual nearest neighbours (default true). In guided
    /// matching, where each query sees only part of the train set, this
    /// means: of the queries matched to one train feature, keep the closest.
    pub cross_check: bool,
    /// Lowe's ratio: keep a match only if `best < max_ratio * second_best`
    /// (default 0.9). Values >= 1 switch the test off. A query with a single
    /// candidate passes.
    pub max_ratio: f32,
    /// Largest Hamming distance accepted for binary descriptors, in bits out
    /// of 256 (default 64; ORB-SLAM uses 50 and 100 in its searches).
    pub max_hamming: u32,
    /// Largest Euclidean distance accepted for float descriptors (default
    /// infinity, i.e. off).
    pub max_l2: f32,
}

impl Default for NnMatcherOptions {
    fn default() -> Self {
        Self { cross_check: true, max_ratio: 0.9, max_hamming: 64, max_l2: f32::INFINITY }
    }
}

impl NnMatcherOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), FeatureError> {
        let bad = |reason: String| Err(FeatureError::InvalidOptions { what: "nearest-neighbour matcher", reason });
        if !(self.max_ratio.is_finite() && self.max_ratio > 0.0) {
            return bad(format!("max_ratio {} must be finite and positive", self.max_ratio));
        }
        if self.max_l2.is_nan() || self.max_l2 < 0.0 {
            return bad(format!("max_l2 {} must be non-negative", self.max_l2));
        }
        Ok(())
    }
}

/// Brute-force nearest-neighbour matcher ("nn").
#[derive(Debug, Clone)]
pub struct NnMatcher {
    opts: NnMatcherOptions,
}

/// Best and second-best candidate of one query in a scan over increasing
/// train indices (strict comparisons keep the lowest index among ties).
#[derive(Debug, Clone, Copy)]
struct Best {
    d1: u32,
    d2: u32,
    i1: u32,
}

impl Best {
    const EMPTY: Best = Best { d1: u32::MAX, d2: u32::MAX, i1: u32::MAX };

    /// From the best and second best packed as `(distance << 32) | index`
    /// ([`NONE`] for none; both none give [`Best::EMPTY`]).
    #[inline(always)]
    fn from_packed(first: u64, second: u64) -> Self {
        Best {
            d1: (first >> 32) as u32,
            i1: (first & 0xffff_ffff) as u32,
            d2: if second == NONE { u32::MAX } else { (second >> 32) as u32 },
        }
    }

    /// Offers train `j` at distance `d`; the common case (`d >= d2`) costs
    /// one compare.
    #[inline(always)]
    fn push(&mut self, d: u32, j: usize) {
        if d < self.d2 {
            if d < self.d1 {
                self.d2 = self.d1;
                self.d1 = d;
                self.i1 = j as u32;
            } else {
                self.d2 = d;
            }
        }
    }
}

/// Best and second best packed as `(distance << 32) | index`, for scans in
/// arbitrary index order: one integer comparison orders by distance, then
/// index, so ties resolve to the lowest index whatever the order.
#[derive(Debug, Clone, Copy)]
struct PackedBest {
    first: u64,
    second: u64,
}

const NONE: u64 = u64::MAX;

impl PackedBest {
    const EMPTY: PackedBest = PackedBest { first: NONE, second: NONE };

    #[inline(always)]
    fn push(&mut self, v: u64) {
        if v < self.second {
            if v < self.first {
                self.second = self.first;
                self.first = v;
            } else {
                self.second = v;
            }
        }
    }
}

#[inline(always)]
fn pack(dist: u32, idx: usize) -> u64 {
    ((dist as u64) << 32) | idx as u64
}

/// Queries per block of the brute-force kernel: each train descriptor is
/// loaded once per block.
const QUERY_BLOCK: usize = 4;
/// Queries per rayon task.
const QUERIES_PER_TASK: usize = 64;

/// Offers query `qi` at distance `d` as the reverse nearest neighbour of a
/// train row (packed; the comparison is exact whatever the query order).
#[inline(always)]
fn offer_rev(r: &mut u64, d: u32, qi: usize) {
    // Cheap pre-test on the distance alone; rarely true after a few rows.
    if (d as u64) <= (*r >> 32) {
        *r = (*r).min(pack(d, qi));
    }
}

/// Offers query `qi` at distance `d` as one of the two nearest queries of a
/// train row (`r1` the nearest, `r2` the second, packed).
#[inline(always)]
fn offer_rev2(r1: &mut u64, r2: &mut u64, d: u32, qi: usize) {
    if (d as u64) <= (*r2 >> 32) {
        push_two(r1, r2, pack(d, qi));
    }
}

/// Forward nearest neighbours of the queries `q` (global indices from
/// `first`) and, in `rev`, every train row's nearest query so far; with
/// `TWO`, also its second nearest in `rev2` (else `rev2` is unused).
#[inline(always)]
fn brute_force_block<const TWO: bool>(
    q: &[[u64; 4]],
    first: usize,
    train: &[[u64; 4]],
    best: &mut [Best],
    rev: &mut [u64],
    rev2: &mut [u64],
) {
    if TWO {
        for (k, (qd, b)) in q.iter().zip(best.iter_mut()).enumerate() {
            for (j, ((t, r1), r2)) in train.iter().zip(rev.iter_mut()).zip(rev2.iter_mut()).enumerate() {
                let d = hamming_distance(qd, t);
                b.push(d, j);
                offer_rev2(r1, r2, d, first + k);
            }
        }
        return;
    }
    let mut base = first;
    for (qb, bb) in q.chunks(QUERY_BLOCK).zip(best.chunks_mut(QUERY_BLOCK)) {
        if let ([q0, q1, q2, q3], [b0, b1, b2, b3]) = (qb, &mut *bb) {
            for (j, (t, r)) in train.iter().zip(rev.iter_mut()).enumerate() {
                let d0 = hamming_distance(q0, t);
                let d1 = hamming_distance(q1, t);
                let d2 = hamming_distance(q2, t);
                let d3 = hamming_distance(q3, t);
                b0.push(d0, j);
                b1.push(d1, j);
                b2.push(d2, j);
                b3.push(d3, j);
                let dm = d0.min(d1).min(d2).min(d3);
                if (dm as u64) <= (*r >> 32) {
                    // Lowest query index of the block reaching the minimum.
                    let k = if d0 == dm {
                        0
                    } else if d1 == dm {
                        1
                    } else if d2 == dm {
                        2
                    } else {
                        3
                    };
                    *r = (*r).min(pack(dm, base + k));
                }
            }
        } else {
            for (k, (qd, b)) in qb.iter().zip(bb.iter_mut()).enumerate() {
                for (j, (t, r)) in train.iter().zip(rev.iter_mut()).enumerate() {
                    let d = hamming_distance(qd, t);
                    b.push(d, j);
                    offer_rev(r, d, base + k);
                }
            }
        }
        base += qb.len();
    }
}

/// Train descriptors stored column-major (structure of arrays), so that one
/// query against consecutive train rows is a vectorisable loop: the four
/// 64-bit words ([`TrainSoa::words`]), or for AVX2 their low and high
/// nibbles in eight columns ([`TrainSoa::nibbles`]).
struct TrainSoa {
    w: Vec<Vec<u64>>,
}

/// Every byte's low nibble.
const LOW_NIBBLES: u64 = 0x0f0f_0f0f_0f0f_0f0f;

impl TrainSoa {
    fn words(train: &[[u64; 4]]) -> Self {
        Self { w: (0..4).map(|k| train.iter().map(|t| t[k]).collect()).collect() }
    }

    /// Columns 0-3 the words' low nibbles, 4-7 their high nibbles (each in
    /// the low half of its byte): the AVX2 kernel looks bytes' popcounts up
    /// by nibble, and splitting the train rows once saves two instructions
    /// per word and row.
    fn nibbles(train: &[[u64; 4]]) -> Self {
        let col = |k: usize| -> Vec<u64> {
            train.iter().map(|t| if k < 4 { t[k] & LOW_NIBBLES } else { (t[k - 4] >> 4) & LOW_NIBBLES }).collect()
        };
        Self { w: (0..8).map(col).collect() }
    }

    fn none() -> Self {
        Self { w: Vec::new() }
    }

    fn len(&self) -> usize {
        self.w.first().map_or(0, Vec::len)
    }
}

/// Lanes of the per-lane two-smallest reduction.
const LANES: usize = 8;

/// A distance packed with an index, the distance in the high bits, so that
/// one integer comparison orders by distance, then index. The kernel runs on
/// 64-bit keys where the CPU compares them in one instruction (AVX-512) and
/// on 32-bit keys where it does not (AVX2 has no unsigned 64-bit minimum:
/// each took four instructions).
trait Key: Copy + Ord {
    /// Larger than every key.
    const NONE: Self;
    /// Distance `d` with index `idx`.
    fn key(d: u32, idx: usize) -> Self;
    /// The same distance with another index.
    fn with_index(self, idx: usize) -> Self;
    /// As `(d << 32) | index` ([`NONE`] stays none).
    fn widen(self) -> u64;
}

impl Key for u64 {
    const NONE: u64 = NONE;
    #[inline(always)]
    fn key(d: u32, idx: usize) -> u64 {
        pack(d, idx)
    }
    #[inline(always)]
    fn with_index(self, idx: usize) -> u64 {
        (self & !0xffff_ffff) | idx as u64
    }
    #[inline(always)]
    fn widen(self) -> u64 {
        self
    }
}

/// 23 bits of index: the distance (9 bits, at most 256) fills the rest, and
/// `u32::MAX` is above every key (256 << 23 | index < 2^32 - 1).
const KEY32_INDEX_BITS: u32 = 23;
/// The index bits of a 32-bit key.
const KEY32_INDEX_MASK: u32 = (1 << KEY32_INDEX_BITS) - 1;

impl Key for u32 {
    const NONE: u32 = u32::MAX;
    #[inline(always)]
    fn key(d: u32, idx: usize) -> u32 {
        (d << KEY32_INDEX_BITS) | idx as u32
    }
    #[inline(always)]
    fn with_index(self, idx: usize) -> u32 {
        (self & !KEY32_INDEX_MASK) | idx as u32
    }
    #[inline(always)]
    fn widen(self) -> u64 {
        if self == u32::MAX {
            return NONE;
        }
        pack(self >> KEY32_INDEX_BITS, (self & KEY32_INDEX_MASK) as usize)
    }
}

/// Inserts `v` into the two smallest `r1 <= r2` (keys are distinct, the
/// index being part of them); branch-free, so loops over rows vectorise.
#[inline(always)]
fn push_two<K: Key>(r1: &mut K, r2: &mut K, v: K) {
    let hi = (*r1).max(v);
    *r1 = (*r1).min(v);
    *r2 = (*r2).min(hi);
}

/// Train rows per tile of [`soa_kernel`]: a tile's columns (4 KB of words,
/// 8 KB of nibbles), its reverse minima and the packed distances of one
/// query against it stay in the L1 cache while every query of the task
/// passes over them. Whole train
/// sets per query streamed those from L2 at Strecha's 8,000 keypoints;
/// tiles of 256 rows and more measured slower (docs/benchmarks.md).
const TRAIN_TILE: usize = 128;

/// Vectorisable kernel: the train rows in tiles of [`TRAIN_TILE`]; for each
/// query and tile, all distances packed with the train index as keys `K` in
/// one pass, the tile's reverse minima in a second pass, and the query's two
/// smallest keys by a per-lane reduction carried across tiles. `fill` makes
/// the keys from the `C` columns of [`TrainSoa`]: [`fill_keys`] compiled for
/// AVX-512 (VPOPCNTQ), [`fill_keys_avx2`] for AVX2, by the wrappers below;
/// `rev`/`rev2` hold keys of query indices.
#[inline(always)]
fn soa_kernel<K: Key, const C: usize, const TWO: bool>(
    q: &[[u64; 4]],
    first: usize,
    t: &TrainSoa,
    best: &mut [Best],
    rev: &mut [K],
    rev2: &mut [K],
    fill: impl Fn(&[u64; 4], [&[u64]; C], usize, &mut [K]),
) {
    let n = t.len();
    let mut keys = [K::NONE; TRAIN_TILE];
    // Each query's per-lane two smallest keys, and the keys of a last tile
    // that is not a whole number of lanes.
    let mut m1 = vec![[K::NONE; LANES]; q.len()];
    let mut m2 = vec![[K::NONE; LANES]; q.len()];
    let mut rest = vec![PackedBest::EMPTY; q.len()];
    for start in (0..n).step_by(TRAIN_TILE) {
        // One length for every slice of the tile, so that the loops below
        // index without bounds checks and vectorise.
        let len = (n - start).min(TRAIN_TILE);
        let end = start + len;
        let w: [&[u64]; C] = std::array::from_fn(|c| &t.w[c][start..end]);
        let rev = &mut rev[start..end];
        let rev2 = if TWO { &mut rev2[start..end] } else { &mut rev2[..0] };
        let keys = &mut keys[..len];
        for (k, qd) in q.iter().enumerate() {
            let qi = first + k;
            fill(qd, w, start, keys);
            if TWO {
                for ((r1, r2), &key) in rev.iter_mut().zip(rev2.iter_mut()).zip(keys.iter()) {
                    push_two(r1, r2, key.with_index(qi));
                }
            } else {
                for (r, &key) in rev.iter_mut().zip(keys.iter()) {
                    *r = (*r).min(key.with_index(qi));
                }
            }
            // Local copies, so that the lanes stay in registers.
            let (mut a, mut b) = (m1[k], m2[k]);
            let mut chunks = keys.chunks_exact(LANES);
            for c in &mut chunks {
                for l in 0..LANES {
                    let v = c[l];
                    let hi = a[l].max(v);
                    a[l] = a[l].min(v);
                    b[l] = b[l].min(hi);
                }
            }
            (m1[k], m2[k]) = (a, b);
            for &v in chunks.remainder() {
                rest[k].push(v.widen());
            }
        }
    }
    for (k, b) in best.iter_mut().enumerate().take(q.len()) {
        let mut top = rest[k];
        for v in m1[k].into_iter().chain(m2[k]) {
            top.push(v.widen());
        }
        if top.first != NONE {
            *b = Best::from_packed(top.first, top.second);
        }
    }
}

/// The keys of query `qd` against train rows `start..` (the tile's words
/// `w`, as long as `keys`): portable code, which LLVM vectorises with
/// VPOPCNTQ where the CPU has it.
#[inline(always)]
fn fill_keys<K: Key>(qd: &[u64; 4], w: [&[u64]; 4], start: usize, keys: &mut [K]) {
    let len = keys.len();
    let [w0, w1, w2, w3] = [&w[0][..len], &w[1][..len], &w[2][..len], &w[3][..len]];
    for j in 0..len {
        let d = (qd[0] ^ w0[j]).count_ones()
            + (qd[1] ^ w1[j]).count_ones()
            + (qd[2] ^ w2[j]).count_ones()
            + (qd[3] ^ w3[j]).count_ones();
        keys[j] = K::key(d, start + j);
    }
}

/// [`fill_keys`] with AVX2 for 32-bit keys, eight rows at a time, from the
/// train words' nibbles ([`TrainSoa::nibbles`]). AVX2 has no vector
/// popcount: each byte's is looked up by nibble (Mula, Kurz and Lemire,
/// "Faster population counts using AVX2 instructions", 2018), and the four
/// words' byte counts are summed before one VPSADBW per four rows. LLVM's
/// own lowering of `count_ones` summed every word separately, and on 64-bit
/// keys this kernel measured slower than scalar POPCNT (docs/benchmarks.md).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn fill_keys_avx2(qd: &[u64; 4], w: [&[u64]; 8], start: usize, keys: &mut [u32]) {
    use std::arch::x86_64::*;
    let len = keys.len();
    let [w0, w1, w2, w3, w4, w5, w6, w7] = w;
    // Written out: `array::from_fn` and `map` were not inlined here, and
    // their calls for every query and tile cost a tenth of the kernel.
    let w = [&w0[..len], &w1[..len], &w2[..len], &w3[..len], &w4[..len], &w5[..len], &w6[..len], &w7[..len]];
    let lut = _mm256_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
    );
    let zero = _mm256_setzero_si256();
    // The query's nibbles, as the train columns hold them.
    let lo = |x: u64| _mm256_set1_epi64x((x & LOW_NIBBLES) as i64);
    let hi = |x: u64| _mm256_set1_epi64x(((x >> 4) & LOW_NIBBLES) as i64);
    let q = [lo(qd[0]), lo(qd[1]), lo(qd[2]), lo(qd[3]), hi(qd[0]), hi(qd[1]), hi(qd[2]), hi(qd[3])];
    // The rows' distances come out as [a0 b0 a1 b1 a2 b2 a3 b3] (rows j..j+4
    // in a, j+4..j+8 in b); this puts them in row order.
    let order = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
    let mut idx = _mm256_add_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), _mm256_set1_epi32(start as i32));
    let eight = _mm256_set1_epi32(8);
    let full = len - len % 8;
    for j in (0..full).step_by(8) {
        let (mut a, mut b) = (zero, zero);
        for (wc, qc) in w.iter().zip(q) {
            // SAFETY: j + 8 <= full <= len, the length of every column, so
            // both unaligned 32-byte loads stay inside `wc`.
            let (xa, xb) = unsafe {
                let p = wc.as_ptr().add(j);
                (_mm256_loadu_si256(p.cast()), _mm256_loadu_si256(p.add(4).cast()))
            };
            // A nibble's popcount is at most 4 and eight nibbles a byte add
            // up to at most 32: no overflow.
            a = _mm256_add_epi8(a, _mm256_shuffle_epi8(lut, _mm256_xor_si256(xa, qc)));
            b = _mm256_add_epi8(b, _mm256_shuffle_epi8(lut, _mm256_xor_si256(xb, qc)));
        }
        let (da, db) = (_mm256_sad_epu8(a, zero), _mm256_sad_epu8(b, zero));
        let d = _mm256_permutevar8x32_epi32(_mm256_blend_epi32(da, _mm256_slli_epi64(db, 32), 0b1010_1010), order);
        let key = _mm256_or_si256(_mm256_slli_epi32(d, KEY32_INDEX_BITS as i32), idx);
        // SAFETY: j + 8 <= len, so the 32-byte store stays inside `keys`.
        unsafe { _mm256_storeu_si256(keys.as_mut_ptr().add(j).cast(), key) };
        idx = _mm256_add_epi32(idx, eight);
    }
    // The last rows: the words put together again from their nibbles.
    for j in full..len {
        let d: u32 = (0..4).map(|c| (qd[c] ^ (w[c][j] | (w[c + 4][j] << 4))).count_ones()).sum();
        keys[j] = u32::key(d, start + j);
    }
}

/// The arguments every kernel takes: queries, the first query's global
/// index, the train set (as rows and as structure of arrays), the queries'
/// best train rows, and the train rows' nearest (and, with `TWO`, second
/// nearest) queries.
type KernelArgs<'a> =
    (&'a [[u64; 4]], usize, &'a [[u64; 4]], &'a TrainSoa, &'a mut [Best], &'a mut [u64], &'a mut [u64]);

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512vpopcntdq,popcnt")]
fn soa_kernel_avx512<const TWO: bool>((q, first, _, t, best, rev, rev2): KernelArgs<'_>) {
    soa_kernel::<u64, 4, TWO>(q, first, t, best, rev, rev2, fill_keys)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
fn soa_kernel_avx2<const TWO: bool>((q, first, _, t, best, rev, rev2): KernelArgs<'_>) {
    // The task's reverse minima as 32-bit keys, merged into the packed ones.
    let n = t.len();
    let mut r1 = vec![u32::NONE; n];
    let mut r2 = if TWO { vec![u32::NONE; n] } else { Vec::new() };
    soa_kernel::<u32, 8, TWO>(q, first, t, best, &mut r1, &mut r2, |qd, w, start, keys| {
        fill_keys_avx2(qd, w, start, keys)
    });
    if TWO {
        for ((x1, x2), (y1, y2)) in rev.iter_mut().zip(rev2.iter_mut()).zip(r1.into_iter().zip(r2)) {
            push_two(x1, x2, y1.widen());
            push_two(x1, x2, y2.widen());
        }
    } else {
        for (x, y) in rev.iter_mut().zip(r1) {
            *x = (*x).min(y.widen());
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
fn brute_force_block_popcnt<const TWO: bool>((q, first, train, _, best, rev, rev2): KernelArgs<'_>) {
    brute_force_block::<TWO>(q, first, train, best, rev, rev2)
}

/// Which build of the brute-force kernel runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kernel {
    /// AVX-512 with VPOPCNTQ, structure-of-arrays kernel.
    Avx512,
    /// AVX2 (popcount by byte shuffles on the train rows' nibbles, 32-bit
    /// keys), structure-of-arrays kernel.
    Avx2,
    /// Scalar POPCNT, 4 queries per train load.
    Popcnt,
    /// Portable scalar code.
    Generic,
}

impl Kernel {
    /// The fastest kernel this CPU supports.
    fn detect() -> Kernel {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx512f") && has!("avx512bw") && has!("avx512vl") && has!("avx512vpopcntdq") && has!("popcnt") {
                return Kernel::Avx512;
            }
            if has!("avx2") && has!("popcnt") {
                return Kernel::Avx2;
            }
            if has!("popcnt") {
                return Kernel::Popcnt;
            }
        }
        Kernel::Generic
    }

    /// This kernel, or scalar POPCNT where the AVX2 kernel's 32-bit keys
    /// cannot hold the row indices (`rows` at least 2^23).
    fn for_rows(self, rows: usize) -> Kernel {
        if self == Kernel::Avx2 && rows >> KEY32_INDEX_BITS != 0 { Kernel::Popcnt } else { self }
    }

    /// Kernels usable on this CPU, fastest first (for tests).
    #[cfg(test)]
    fn available() -> Vec<Kernel> {
        let all = [Kernel::Avx512, Kernel::Avx2, Kernel::Popcnt, Kernel::Generic];
        let first = all.iter().position(|&k| k == Kernel::detect()).unwrap_or(3);
        let mut v: Vec<Kernel> = all[first..].to_vec();
        // AVX-512 implies AVX2 and POPCNT on every CPU that has it, but check.
        #[cfg(target_arch = "x86_64")]
        v.retain(|k| match k {
            Kernel::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            Kernel::Popcnt | Kernel::Avx512 => std::arch::is_x86_feature_detected!("popcnt"),
            Kernel::Generic => true,
        });
        v
    }

    fn run<const TWO: bool>(self, args: KernelArgs<'_>) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernel::detect` (or `available`) chose this variant
            // only after checking at run time that the CPU has every feature
            // the function is compiled for, the only requirement of a
            // `target_feature` function.
            Kernel::Avx512 => unsafe { soa_kernel_avx512::<TWO>(args) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above, AVX2 and POPCNT were detected.
            Kernel::Avx2 => unsafe { soa_kernel_avx2::<TWO>(args) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above, POPCNT was detected.
            Kernel::Popcnt => unsafe { brute_force_block_popcnt::<TWO>(args) },
            _ => {
                let (q, first, train, _, best, rev, rev2) = args;
                brute_force_block::<TWO>(q, first, train, best, rev, rev2)
            }
        }
    }
}

/// The nearest (and, with `TWO`, second nearest) query of every train row,
/// packed; `second` is empty without `TWO`.
struct Reverse {
    first: Vec<u64>,
    second: Vec<u64>,
}

impl Reverse {
    fn empty<const TWO: bool>(n: usize) -> Self {
        Self { first: vec![NONE; n], second: if TWO { vec![NONE; n] } else { Vec::new() } }
    }

    /// The two nearest of both: the other's nearest, then its second,
    /// inserted into this one's two.
    fn merge(mut self, other: Reverse) -> Self {
        if self.second.is_empty() {
            for (x, y) in self.first.iter_mut().zip(other.first) {
                *x = (*x).min(y);
            }
        } else {
            for ((x1, x2), (y1, y2)) in
                self.first.iter_mut().zip(self.second.iter_mut()).zip(other.first.into_iter().zip(other.second))
            {
                push_two(x1, x2, y1);
                push_two(x1, x2, y2);
            }
        }
        self
    }
}

/// For each query its best/second-best train and, for each train, the best
/// query (packed; with `TWO` also the second best). Parallel over blocks of
/// queries; the reverse minima are merged with `min` on packed values,
/// which is associative and commutative, so the result does not depend on
/// the thread count.
fn nn_binary<const TWO: bool>(query: &[[u64; 4]], train: &[[u64; 4]], kernel: Kernel) -> (Vec<Best>, Reverse) {
    let mut best = vec![Best::EMPTY; query.len()];
    let kernel = kernel.for_rows(query.len().max(train.len()));
    let soa = match kernel {
        Kernel::Avx512 => TrainSoa::words(train),
        Kernel::Avx2 => TrainSoa::nibbles(train),
        _ => TrainSoa::none(),
    };
    let rev = query
        .par_chunks(QUERIES_PER_TASK)
        .zip(best.par_chunks_mut(QUERIES_PER_TASK))
        .enumerate()
        .fold(
            || Reverse::empty::<TWO>(train.len()),
            |mut rev, (chunk, (q, b))| {
                kernel.run::<TWO>((q, chunk * QUERIES_PER_TASK, train, &soa, b, &mut rev.first, &mut rev.second));
                rev
            },
        )
        .reduce(|| Reverse::empty::<TWO>(train.len()), Reverse::merge);
    (best, rev)
}

/// Squared Euclidean distance.
#[inline]
fn l2_sq(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

impl NnMatcher {
    /// Makes a matcher after validating the options.
    pub fn new(opts: NnMatcherOptions) -> Result<Self, FeatureError> {
        opts.validate()?;
        Ok(Self { opts })
    }

    /// The options in use.
    pub fn options(&self) -> &NnMatcherOptions {
        &self.opts
    }

    fn ratio_ok(&self, d1: f32, d2: Option<f32>) -> bool {
        if self.opts.max_ratio >= 1.0 {
            return true;
        }
        match d2 {
            Some(d2) => d1 < self.opts.max_ratio * d2,
            None => true,
        }
    }

    /// Brute-force matching of binary descriptors (all query rows against all
    /// train rows). Sorted by query index.
    pub fn match_binary(&self, query: &[[u64; 4]], train: &[[u64; 4]]) -> Vec<Match> {
        self.match_binary_with(query, train, Kernel::detect())
    }

    fn match_binary_with(&self, query: &[[u64; 4]], train: &[[u64; 4]], kernel: Kernel) -> Vec<Match> {
        if query.is_empty() || train.is_empty() {
            return Vec::new();
        }
        let (best, rev) = nn_binary::<false>(query, train, kernel);
        self.filter(&best, |j| rev.first.get(j).map(|r| (r & 0xffff_ffff) as usize))
    }

    /// Brute-force matching both ways in one pass: the matches of `a`
    /// against `b` and those of `b` against `a`, exactly as two calls of
    /// [`NnMatcher::match_binary`] give them. The pass also keeps each `b`
    /// row's second nearest `a` row (for its ratio test); the cross-check of
    /// either direction is the other's nearest neighbour, which the pass has.
    pub fn match_binary_both(&self, a: &[[u64; 4]], b: &[[u64; 4]]) -> (Vec<Match>, Vec<Match>) {
        self.match_binary_both_with(a, b, Kernel::detect())
    }

    fn match_binary_both_with(&self, a: &[[u64; 4]], b: &[[u64; 4]], kernel: Kernel) -> (Vec<Match>, Vec<Match>) {
        if a.is_empty() || b.is_empty() {
            return (Vec::new(), Vec::new());
        }
        let (forward, rev) = nn_binary::<true>(a, b, kernel);
        let backward: Vec<Best> =
            rev.first.iter().zip(&rev.second).map(|(&r1, &r2)| Best::from_packed(r1, r2)).collect();
        let ab = self.filter(&forward, |j| backward.get(j).map(|r| r.i1 as usize));
        let ba = self.filter(&backward, |i| forward.get(i).map(|r| r.i1 as usize));
        (ab, ba)
    }

    /// The matches kept of each query's best and second-best train rows;
    /// `nearest(j)` is train row `j`'s nearest query (for the cross-check).
    fn filter(&self, best: &[Best], nearest: impl Fn(usize) -> Option<usize>) -> Vec<Match> {
        best.iter()
            .enumerate()
            .filter_map(|(i, b)| {
                if b.d1 == u32::MAX {
                    return None;
                }
                let j = b.i1 as usize;
                let d1 = b.d1;
                let d2 = (b.d2 != u32::MAX).then_some(b.d2 as f32);
                if d1 > self.opts.max_hamming || !self.ratio_ok(d1 as f32, d2) {
                    return None;
                }
                if self.opts.cross_check && nearest(j) != Some(i) {
                    return None;
                }
                Some(Match { query: i as u32, train: j as u32, distance: d1 as f32 })
            })
            .collect()
    }

    /// Brute-force matching of float descriptors (Euclidean distance).
    pub fn match_float(&self, dim: usize, query: &[f32], train: &[f32]) -> Result<Vec<Match>, FeatureError> {
        if dim == 0 {
            return Err(FeatureError::DescriptorMismatch("float descriptors with dim 0".into()));
        }
        if !query.len().is_multiple_of(dim) || !train.len().is_multiple_of(dim) {
            return Err(FeatureError::DescriptorMismatch(format!(
                "float buffers of {} and {} values are not whole {dim}-dimensional rows",
                query.len(),
                train.len()
            )));
        }
        let nn = |a: &[f32], b: &[f32]| -> Vec<(usize, f32, Option<f32>)> {
            a.par_chunks(dim)
                .map(|q| {
                    let (mut bi, mut b1, mut b2) = (usize::MAX, f32::INFINITY, f32::INFINITY);
                    for (j, t) in b.chunks(dim).enumerate() {
                        let d = l2_sq(q, t);
                        if d < b1 {
                            b2 = b1;
                            b1 = d;
                            bi = j;
                        } else if d < b2 {
                            b2 = d;
                        }
                    }
                    (bi, b1.sqrt(), b2.is_finite().then(|| b2.sqrt()))
                })
                .collect()
        };
        let fwd = nn(query, train);
        let rev = if self.opts.cross_check { nn(train, query) } else { Vec::new() };
        Ok(fwd
            .iter()
            .enumerate()
            .filter_map(|(i, &(j, d1, d2))| {
                if j == usize::MAX || d1 > self.opts.max_l2 || !self.ratio_ok(d1, d2) {
                    return None;
                }
                if self.opts.cross_check && rev.get(j).map(|r| r.0) != Some(i) {
                    return None;
                }
                Some(Match { query: i as u32, train: j as u32, distance: d1 })
            })
            .collect())
    }

    /// Guided matching of binary features: query `i` is compared only with
    /// train keypoints within `radius` pixels of `predicted[i]` (no search
    /// when `None`). Uses a grid index over the train keypoints with cells of
    /// `radius` pixels. Distance and ratio filters as in brute force (the
    /// ratio is taken among the candidates in the radius); with cross-check
    /// each train feature keeps only its closest query (ties: lowest index).
    pub fn match_guided(
        &self,
        query: &Features,
        train: &Features,
        predicted: &[Option<[f32; 2]>],
        radius: f32,
    ) -> Result<Vec<Match>, FeatureError> {
        query.validate()?;
        train.validate()?;
        if predicted.len() != query.len() {
            return Err(FeatureError::PredictionCount { predictions: predicted.len(), queries: query.len() });
        }
        if !(radius.is_finite() && radius > 0.0) {
            return Err(FeatureError::InvalidOptions {
                what: "guided matching",
                reason: format!("radius {radius} must be finite and positive"),
            });
        }
        let (Descriptors::Binary(qd), Descriptors::Binary(td)) = (&query.descriptors, &train.descriptors) else {
            return Err(FeatureError::DescriptorMismatch(
                "guided matching needs binary descriptors on both sides".into(),
            ));
        };
        let grid = Grid::new(&train.keypoints, radius);
        let r2 = radius * radius;
        let mut matches: Vec<Match> = predicted
            .par_iter()
            .zip(qd.par_iter())
            .enumerate()
            .filter_map(|(i, (p, q))| {
                let [px, py] = (*p)?;
                if !(px.is_finite() && py.is_finite()) {
                    return None;
                }
                let mut b = PackedBest::EMPTY;
                grid.for_each_near(px, py, |j| {
                    let (Some(k), Some(t)) = (train.keypoints.get(j), td.get(j)) else { return };
                    let (dx, dy) = (k.x - px, k.y - py);
                    if dx * dx + dy * dy <= r2 {
                        b.push(pack(hamming_distance(q, t), j));
                    }
                });
                if b.first == NONE {
                    return None;
                }
                let d1 = (b.first >> 32) as u32;
                let d2 = (b.second != NONE).then_some((b.second >> 32) as f32);
                if d1 > self.opts.max_hamming || !self.ratio_ok(d1 as f32, d2) {
                    return None;
                }
                Some(Match { query: i as u32, train: (b.first & 0xffff_ffff) as u32, distance: d1 as f32 })
            })
            .collect();
        if self.opts.cross_check {
            let mut owner = vec![NONE; train.len()];
            for m in &matches {
                if let Some(o) = owner.get_mut(m.train as usize) {
                    *o = (*o).min(pack(m.distance as u32, m.query as usize));
                }
            }
            matches.retain(|m| owner.get(m.train as usize).map(|o| (o & 0xffff_ffff) as u32) == Some(m.query));
        }
        Ok(matches)
    }
}

impl Matcher for NnMatcher {
    fn name(&self) -> &str {
        "nn"
    }

    fn match_features(&self, a: &Features, b: &Features) -> Result<Vec<Match>, FeatureError> {
        a.validate()?;
        b.validate()?;
        match (&a.descriptors, &b.descriptors) {
            (Descriptors::Binary(q), Descriptors::Binary(t)) => Ok(self.match_binary(q, t)),
            (Descriptors::Float { dim: da, data: q }, Descriptors::Float { dim: db, data: t }) => {
                if da != db {
                    return Err(FeatureError::DescriptorMismatch(format!(
                        "float descriptors of dimension {da} and {db}"
                    )));
                }
                if q.is_empty() || t.is_empty() {
                    return Ok(Vec::new());
                }
                self.match_float(*da, q, t)
            }
            _ => Err(FeatureError::DescriptorMismatch("cannot match binary against float descriptors".into())),
        }
    }

    fn match_features_both(&self, a: &Features, b: &Features) -> Result<(Vec<Match>, Vec<Match>), FeatureError> {
        match (&a.descriptors, &b.descriptors) {
            (Descriptors::Binary(q), Descriptors::Binary(t)) => {
                a.validate()?;
                b.validate()?;
                Ok(self.match_binary_both(q, t))
            }
            _ => Ok((self.match_features(a, b)?, self.match_features(b, a)?)),
        }
    }
}

/// Uniform grid over keypoint positions (compressed rows: `start[c]..start[c+1]`
/// indexes `items` for cell c).
struct Grid {
    x0: f32,
    y0: f32,
    cell: f32,
    cols: usize,
    rows: usize,
    start: Vec<usize>,
    items: Vec<usize>,
}

/// Most cells per grid side; a sparse, huge grid would waste memory.
const MAX_GRID_SIDE: usize = 1024;

impl Grid {
    fn new(kps: &[Keypoint], cell: f32) -> Self {
        let finite = || kps.iter().filter(|k| k.x.is_finite() && k.y.is_finite());
        let (mut x0, mut y0, mut x1, mut y1) = (f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
        for k in finite() {
            x0 = x0.min(k.x);
            y0 = y0.min(k.y);
            x1 = x1.max(k.x);
            y1 = y1.max(k.y);
        }
        if x0 > x1 {
            return Grid { x0: 0.0, y0: 0.0, cell, cols: 0, rows: 0, start: vec![0], items: Vec::new() };
        }
        let side = |lo: f32, hi: f32, c: f32| (((hi - lo) / c) as usize + 1).min(MAX_GRID_SIDE);
        // Enlarge cells when the extent would need too many of them.
        let cell = cell.max((x1 - x0) / MAX_GRID_SIDE as f32).max((y1 - y0) / MAX_GRID_SIDE as f32);
        let (cols, rows) = (side(x0, x1, cell), side(y0, y1, cell));
        let cell_of = |k: &Keypoint| {
            let c = (((k.x - x0) / cell) as usize).min(cols - 1);
            let r = (((k.y - y0) / cell) as usize).min(rows - 1);
            r * cols + c
        };
        let mut start = vec![0usize; cols * rows + 1];
        for k in finite() {
            if let Some(s) = start.get_mut(cell_of(k) + 1) {
                *s += 1;
            }
        }
        for c in 0..cols * rows {
            let prev = start.get(c).copied().unwrap_or(0);
            if let Some(s) = start.get_mut(c + 1) {
                *s += prev;
            }
        }
        let mut fill = start.clone();
        let mut items = vec![0usize; start.last().copied().unwrap_or(0)];
        for (i, k) in kps.iter().enumerate() {
            if !(k.x.is_finite() && k.y.is_finite()) {
                continue;
            }
            if let Some(f) = fill.get_mut(cell_of(k))
                && let Some(slot) = items.get_mut(*f)
            {
                *slot = i;
                *f += 1;
            }
        }
        Grid { x0, y0, cell, cols, rows, start, items }
    }

    /// Calls `f` with every item in the cells overlapping the square of half
    /// side `cell` around (x, y) (a superset of the disc of that radius).
    fn for_each_near(&self, x: f32, y: f32, mut f: impl FnMut(usize)) {
        if self.cols == 0 {
            return;
        }
        let lo = |v: f32, o: f32| ((v - self.cell - o) / self.cell).floor();
        let hi = |v: f32, o: f32| ((v + self.cell - o) / self.cell).floor();
        let (c0, c1) = (lo(x, self.x0), hi(x, self.x0));
        let (r0, r1) = (lo(y, self.y0), hi(y, self.y0));
        if c1 < 0.0 || r1 < 0.0 || c0 >= self.cols as f32 || r0 >= self.rows as f32 {
            return;
        }
        let c0 = c0.max(0.0) as usize;
        let r0 = r0.max(0.0) as usize;
        let c1 = (c1 as usize).min(self.cols - 1);
        let r1 = (r1 as usize).min(self.rows - 1);
        for r in r0..=r1 {
            let (Some(&s), Some(&e)) = (self.start.get(r * self.cols + c0), self.start.get(r * self.cols + c1 + 1))
            else {
                continue;
            };
            for &i in self.items.get(s..e).unwrap_or(&[]) {
                f(i);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive_hamming(a: &[u64; 4], b: &[u64; 4]) -> u32 {
        let mut n = 0;
        for bit in 0..256 {
            let x = (a[bit / 64] >> (bit % 64)) & 1;
            let y = (b[bit / 64] >> (bit % 64)) & 1;
            n += (x != y) as u32;
        }
        n
    }

    fn rng_desc(state: &mut u64) -> [u64; 4] {
        let mut next = || {
            *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = *state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        [next(), next(), next(), next()]
    }

    #[test]
    fn hamming_matches_bitwise_definition() {
        let mut s = 7;
        for _ in 0..200 {
            let (a, b) = (rng_desc(&mut s), rng_desc(&mut s));
            assert_eq!(hamming_distance(&a, &b), naive_hamming(&a, &b));
        }
        assert_eq!(hamming_distance(&[0; 4], &[u64::MAX; 4]), 256);
        assert_eq!(hamming_distance(&[5; 4], &[5; 4]), 0);
    }

    /// Naive O(n m) reference for the brute-force matcher.
    fn naive_match(q: &[[u64; 4]], t: &[[u64; 4]], o: &NnMatcherOptions) -> Vec<Match> {
        let nn = |a: &[u64; 4], set: &[[u64; 4]]| {
            let mut d: Vec<(u32, usize)> = set.iter().enumerate().map(|(j, x)| (naive_hamming(a, x), j)).collect();
            d.sort();
            d
        };
        let mut out = Vec::new();
        for (i, a) in q.iter().enumerate() {
            let d = nn(a, t);
            let (d1, j) = d[0];
            if d1 > o.max_hamming {
                continue;
            }
            if o.max_ratio < 1.0 && d.len() > 1 && (d1 as f32) >= o.max_ratio * d[1].0 as f32 {
                continue;
            }
            if o.cross_check && nn(&t[j], q)[0].1 != i {
                continue;
            }
            out.push(Match { query: i as u32, train: j as u32, distance: d1 as f32 });
        }
        out
    }

    #[test]
    fn brute_force_equals_naive_for_all_option_combinations() {
        let mut s = 99;
        let train: Vec<[u64; 4]> = (0..150).map(|_| rng_desc(&mut s)).collect();
        // Queries: noisy copies of some train rows, plus unrelated rows; 203
        // is not a multiple of the 4-query block.
        let mut query = Vec::new();
        for i in 0..203 {
            if i % 3 == 0 {
                query.push(rng_desc(&mut s));
            } else {
                let mut d = train[(i * 7) % 150];
                let noise = rng_desc(&mut s);
                d[0] ^= noise[0] & noise[1] & noise[2]; // ~8 flipped bits
                query.push(d);
            }
        }
        for cross_check in [false, true] {
            for max_ratio in [1.0, 0.8] {
                for max_hamming in [256, 40] {
                    let o = NnMatcherOptions { cross_check, max_ratio, max_hamming, ..Default::default() };
                    let m = NnMatcher::new(o.clone()).unwrap();
                    let want = naive_match(&query, &train, &o);
                    assert!(!want.is_empty());
                    for kernel in Kernel::available() {
                        // 150 train rows span two tiles of the vectorised
                        // kernel; 147 also leave a part of the lanes.
                        let got = m.match_binary_with(&query, &train, kernel);
                        assert_eq!(got, want, "{o:?} {kernel:?}");
                        let got = m.match_binary_with(&query, &train[..147], kernel);
                        assert_eq!(got, naive_match(&query, &train[..147], &o), "{o:?} {kernel:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_avx2_kernel_is_kept_only_where_its_keys_hold_the_indices() {
        let max = KEY32_INDEX_MASK as usize;
        assert_eq!(Kernel::Avx2.for_rows(max), Kernel::Avx2);
        assert_eq!(Kernel::Avx2.for_rows(max + 1), Kernel::Popcnt);
        assert_eq!(Kernel::Avx512.for_rows(max + 1), Kernel::Avx512);
        // The largest key is below the empty one, and keys order by
        // distance, then index, as the packed 64-bit ones do.
        assert!(u32::key(256, max) < u32::NONE);
        assert_eq!(u32::key(256, max).widen(), pack(256, max));
        assert_eq!(u32::NONE.widen(), NONE);
        assert!(u32::key(3, max) < u32::key(4, 0) && u32::key(4, 0) < u32::key(4, 1));
        assert_eq!(u32::key(7, 5).with_index(9), u32::key(7, 9));
    }

    #[test]
    fn every_kernel_is_exact_at_the_edges_of_its_groups_and_distances() {
        // Train sets around the AVX2 kernel's groups of 8 rows, the lanes and
        // the 128-row tiles; the queries include a train row's complement
        // (distance 256, the largest key) and an exact copy (distance 0).
        let mut s = 5;
        let rows: Vec<[u64; 4]> = (0..260).map(|_| rng_desc(&mut s)).collect();
        let mut query: Vec<[u64; 4]> = (0..37).map(|_| rng_desc(&mut s)).collect();
        query.push(rows[0].map(|w| !w));
        query.push(rows[3]);
        let o = NnMatcherOptions { cross_check: false, max_ratio: 1.0, max_hamming: 256, ..Default::default() };
        let m = NnMatcher::new(o.clone()).unwrap();
        for n in [1, 2, 7, 8, 9, 15, 16, 17, 127, 128, 129, 136, 260] {
            let train = &rows[..n];
            let want = naive_match(&query, train, &o);
            assert_eq!(want.len(), query.len());
            for kernel in Kernel::available() {
                assert_eq!(m.match_binary_with(&query, train, kernel), want, "{n} rows, {kernel:?}");
                let (ab, ba) = m.match_binary_both_with(&query, train, kernel);
                assert_eq!(ab, want, "{n} rows both ways, {kernel:?}");
                assert_eq!(ba, naive_match(train, &query, &o), "{n} rows backwards, {kernel:?}");
            }
        }
        let far = naive_match(&query, &rows[..1], &o);
        assert_eq!(far[37].distance, 256.0);
    }

    #[test]
    fn both_ways_in_one_pass_equal_two_calls() {
        let mut s = 7;
        // Few bits set, so distances tie often and the ratio test and the
        // lowest-index rule both matter.
        let sparse = |s: &mut u64| {
            let (a, b) = (rng_desc(s), rng_desc(s));
            std::array::from_fn::<u64, 4, _>(|k| a[k] & b[k] & 0x0f0f_0f0f_0f0f_0f0f)
        };
        let a: Vec<[u64; 4]> = (0..203).map(|_| sparse(&mut s)).collect();
        let b: Vec<[u64; 4]> = (0..150).map(|i| if i % 2 == 0 { a[(i * 3) % 203] } else { sparse(&mut s) }).collect();
        for cross_check in [false, true] {
            for max_ratio in [1.0, 0.8] {
                for max_hamming in [256, 20] {
                    let o = NnMatcherOptions { cross_check, max_ratio, max_hamming, ..Default::default() };
                    let m = NnMatcher::new(o.clone()).unwrap();
                    for kernel in Kernel::available() {
                        for (x, y) in [(&a[..], &b[..]), (&b[..], &a[..]), (&a[..], &b[..147])] {
                            let want = (m.match_binary_with(x, y, kernel), m.match_binary_with(y, x, kernel));
                            assert!(!want.0.is_empty() && !want.1.is_empty());
                            assert_eq!(m.match_binary_both_with(x, y, kernel), want, "{o:?} {kernel:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn options_behave_as_documented() {
        // Two train rows equally close to the query: the ratio test rejects.
        let q = [[0u64; 4]];
        let t = [[0b11, 0, 0, 0], [0b1100, 0, 0, 0], [u64::MAX; 4]];
        let plain =
            NnMatcher::new(NnMatcherOptions { cross_check: false, max_ratio: 1.0, ..Default::default() }).unwrap();
        let m = plain.match_binary(&q, &t);
        assert_eq!(m, vec![Match { query: 0, train: 0, distance: 2.0 }]); // tie -> lowest index
        let ratio =
            NnMatcher::new(NnMatcherOptions { cross_check: false, max_ratio: 0.8, ..Default::default() }).unwrap();
        assert!(ratio.match_binary(&q, &t).is_empty());
        // Max distance.
        let strict = NnMatcher::new(NnMatcherOptions { max_hamming: 1, max_ratio: 1.0, ..Default::default() }).unwrap();
        assert!(strict.match_binary(&q, &t).is_empty());
        // Cross-check: two queries share the same nearest train; only the
        // closer one survives.
        let q2 = [[0b1, 0, 0, 0], [0b111, 0, 0, 0]];
        let t2 = [[0u64; 4], [u64::MAX; 4]];
        let cc = NnMatcher::new(NnMatcherOptions { max_ratio: 1.0, ..Default::default() }).unwrap();
        assert_eq!(cc.match_binary(&q2, &t2), vec![Match { query: 0, train: 0, distance: 1.0 }]);
        assert_eq!(plain.match_binary(&q2, &t2).len(), 2);
        // Empty inputs.
        assert!(cc.match_binary(&[], &t2).is_empty());
        assert!(cc.match_binary(&q2, &[]).is_empty());
        // Invalid options.
        assert!(NnMatcher::new(NnMatcherOptions { max_ratio: 0.0, ..Default::default() }).is_err());
        assert!(NnMatcher::new(NnMatcherOptions { max_l2: f32::NAN, ..Default::default() }).is_err());
    }

    fn kp(x: f32, y: f32) -> Keypoint {
        Keypoint { x, y, octave: 0, angle: 0.0, response: 0.0, size: 31.0 }
    }

    #[test]
    fn guided_matching_searches_only_near_the_prediction() {
        let mut s = 5;
        let d: Vec<[u64; 4]> = (0..3).map(|_| rng_desc(&mut s)).collect();
        let train = Features {
            keypoints: vec![kp(10.0, 10.0), kp(100.0, 100.0), kp(300.0, 50.0)],
            descriptors: Descriptors::Binary(d.clone()),
        };
        let query = Features {
            keypoints: vec![kp(0.0, 0.0), kp(0.0, 0.0), kp(0.0, 0.0)],
            descriptors: Descriptors::Binary(d.clone()),
        };
        let m = NnMatcher::new(NnMatcherOptions::default()).unwrap();
        // Query 0 predicted near train 0, query 1 predicted far from train 1,
        // query 2 without a prediction.
        let pred = [Some([12.0, 9.0]), Some([200.0, 200.0]), None];
        let got = m.match_guided(&query, &train, &pred, 8.0).unwrap();
        assert_eq!(got, vec![Match { query: 0, train: 0, distance: 0.0 }]);
        // A wide radius finds query 1's true match.
        let got = m.match_guided(&query, &train, &[None, Some([200.0, 200.0]), None], 150.0).unwrap();
        assert_eq!(got, vec![Match { query: 1, train: 1, distance: 0.0 }]);
        // Errors: wrong prediction count, bad radius, float descriptors.
        assert!(matches!(
            m.match_guided(&query, &train, &pred[..2], 8.0),
            Err(FeatureError::PredictionCount { predictions: 2, queries: 3 })
        ));
        assert!(m.match_guided(&query, &train, &pred, 0.0).is_err());
        assert!(m.match_guided(&query, &train, &pred, f32::NAN).is_err());
        let float =
            Features { keypoints: vec![kp(0.0, 0.0)], descriptors: Descriptors::Float { dim: 2, data: vec![0.0; 2] } };
        assert!(m.match_guided(&float, &float, &[None], 4.0).is_err());
    }

    #[test]
    fn guided_equals_brute_force_with_a_huge_radius() {
        let mut s = 11;
        let n = 120;
        let t: Vec<[u64; 4]> = (0..n).map(|_| rng_desc(&mut s)).collect();
        let q: Vec<[u64; 4]> = (0..n).map(|i| if i % 2 == 0 { t[(i * 13) % n] } else { rng_desc(&mut s) }).collect();
        let kps: Vec<Keypoint> = (0..n).map(|i| kp((i * 37 % 640) as f32, (i * 91 % 480) as f32)).collect();
        let a = Features { keypoints: kps.clone(), descriptors: Descriptors::Binary(q.clone()) };
        let b = Features { keypoints: kps, descriptors: Descriptors::Binary(t.clone()) };
        let m = NnMatcher::new(NnMatcherOptions { cross_check: false, ..Default::default() }).unwrap();
        let pred = vec![Some([320.0, 240.0]); n];
        assert_eq!(m.match_guided(&a, &b, &pred, 2000.0).unwrap(), m.match_binary(&q, &t));
    }

    #[test]
    fn float_matching_and_mismatches() {
        let m = NnMatcher::new(NnMatcherOptions::default()).unwrap();
        let a = Features {
            keypoints: vec![kp(0.0, 0.0), kp(1.0, 1.0)],
            descriptors: Descriptors::Float { dim: 2, data: vec![0.0, 0.0, 10.0, 10.0] },
        };
        let b = Features {
            keypoints: vec![kp(0.0, 0.0), kp(1.0, 1.0)],
            descriptors: Descriptors::Float { dim: 2, data: vec![10.0, 11.0, 0.0, 1.0] },
        };
        let got = m.match_features(&a, &b).unwrap();
        assert_eq!(got, vec![Match { query: 0, train: 1, distance: 1.0 }, Match { query: 1, train: 0, distance: 1.0 }]);
        let bin = Features { keypoints: vec![kp(0.0, 0.0)], descriptors: Descriptors::Binary(vec![[0; 4]]) };
        assert!(matches!(m.match_features(&a, &bin), Err(FeatureError::DescriptorMismatch(_))));
        let c =
            Features { keypoints: vec![kp(0.0, 0.0)], descriptors: Descriptors::Float { dim: 3, data: vec![0.0; 3] } };
        assert!(m.match_features(&a, &c).is_err());
        // Inconsistent: 2 keypoints, 1 descriptor.
        let bad = Features { keypoints: vec![kp(0.0, 0.0); 2], descriptors: Descriptors::Binary(vec![[0; 4]]) };
        assert!(matches!(m.match_features(&bad, &bin), Err(FeatureError::InconsistentFeatures { .. })));
    }
}
