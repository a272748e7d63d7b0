//! A bag of binary words for place recognition: a vocabulary tree over
//! 256-bit descriptors, tf-idf word vectors, their L1 similarity and an
//! inverted index (after DBoW2, Gálvez-López and Tardós, "Bags of Binary
//! Words for Fast Place Recognition in Image Sequences", T-RO 2012, which
//! ORB-SLAM's loop detection uses; this is an own implementation).
//!
//! The vocabulary is trained on the run's own descriptors (seeded
//! k-majority clustering: k-means++ seeding with Hamming distances, bitwise
//! majority as the centre), so nothing is downloaded or shipped and the same
//! input always gives the same words. A word's weight is its inverse
//! document frequency over the training documents.

use crate::matcher::hamming_distance;
use colslam_geometry::SplitMix64;
use std::collections::HashMap;

/// A binary descriptor (ORB's 256 bits, see [`crate::Descriptors::Binary`]).
pub type BinaryDescriptor = [u64; 4];

/// How a vocabulary is trained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VocabularyOptions {
    /// Children per node (k).
    pub branching: usize,
    /// Levels below the root (L): at most `branching^depth` words.
    pub depth: usize,
    /// Assignment / majority rounds per clustering.
    pub iterations: usize,
    /// Descriptors taken from each training document at most (evenly
    /// strided), so training stays cheap on long runs.
    pub max_per_document: usize,
    /// Seed of the k-means++ seeding.
    pub seed: u64,
}

impl Default for VocabularyOptions {
    fn default() -> Self {
        // Seed: "bow" in ASCII. 10^3 words: enough to tell rooms apart in a run's few hundred
        // keyframes while each node still gets descriptors to cluster.
        Self { branching: 10, depth: 3, iterations: 6, max_per_document: 300, seed: 0x0062_6f77 }
    }
}

/// One node of the tree: its centre, its children (node indices) and, for a
/// leaf, its word.
#[derive(Debug, Clone)]
struct Node {
    center: BinaryDescriptor,
    children: Vec<u32>,
    word: Option<u32>,
}

/// A vocabulary tree with idf word weights.
#[derive(Debug, Clone)]
pub struct Vocabulary {
    nodes: Vec<Node>,
    idf: Vec<f32>,
}

/// A tf-idf word vector, sorted by word, L1-normalised.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BowVector(pub Vec<(u32, f32)>);

impl Vocabulary {
    /// Trains a vocabulary on `documents` (each one image's descriptors).
    /// An empty training set gives a vocabulary of one word.
    pub fn train(documents: &[&[BinaryDescriptor]], opts: &VocabularyOptions) -> Self {
        let mut sample: Vec<BinaryDescriptor> = Vec::new();
        for doc in documents {
            let stride = doc.len().div_ceil(opts.max_per_document.max(1)).max(1);
            sample.extend(doc.iter().step_by(stride).copied());
        }
        let mut rng = SplitMix64::new(opts.seed);
        let mut nodes = vec![Node { center: [0; 4], children: Vec::new(), word: None }];
        let mut words = 0u32;
        // Breadth-first over (node, its descriptors, level).
        let mut queue = std::collections::VecDeque::from([(0usize, (0..sample.len()).collect::<Vec<usize>>(), 0usize)]);
        while let Some((node, members, level)) = queue.pop_front() {
            if level >= opts.depth || members.len() <= 1 {
                nodes[node].word = Some(words);
                words += 1;
                continue;
            }
            let (centers, groups) = k_majority(&sample, &members, opts.branching.max(2), opts.iterations, &mut rng);
            for (center, group) in centers.into_iter().zip(groups) {
                let child = nodes.len();
                nodes.push(Node { center, children: Vec::new(), word: None });
                nodes[node].children.push(child as u32);
                queue.push_back((child, group, level + 1));
            }
        }
        let mut vocab = Self { nodes, idf: vec![0.0; words as usize] };
        vocab.set_idf(documents);
        vocab
    }

    /// Number of words.
    pub fn num_words(&self) -> usize {
        self.idf.len()
    }

    /// The word of one descriptor: the leaf reached by descending to the
    /// nearest centre at each level.
    pub fn word(&self, d: &BinaryDescriptor) -> u32 {
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            if let Some(w) = n.word {
                return w;
            }
            // A node without a word has children (training gives every
            // childless node a word).
            let mut best = (u32::MAX, node);
            for &c in &n.children {
                let dist = hamming_distance(&self.nodes[c as usize].center, d);
                if dist < best.0 {
                    best = (dist, c as usize);
                }
            }
            if best.1 == node {
                return 0;
            }
            node = best.1;
        }
    }

    /// The tf-idf vector of an image's descriptors, L1-normalised (empty for
    /// no descriptors).
    pub fn transform(&self, descriptors: &[BinaryDescriptor]) -> BowVector {
        let mut counts: HashMap<u32, u32> = HashMap::new();
        for d in descriptors {
            *counts.entry(self.word(d)).or_default() += 1;
        }
        let mut v: Vec<(u32, f32)> = counts
            .into_iter()
            .map(|(w, c)| (w, c as f32 * self.idf.get(w as usize).copied().unwrap_or(0.0)))
            .filter(|(_, x)| *x > 0.0)
            .collect();
        v.sort_by_key(|(w, _)| *w);
        let total: f32 = v.iter().map(|(_, x)| x).sum();
        if total > 0.0 {
            v.iter_mut().for_each(|(_, x)| *x /= total);
        }
        BowVector(v)
    }

    /// idf = ln(N / n_w) over the training documents; a word no document
    /// holds gets the largest weight, ln(N).
    fn set_idf(&mut self, documents: &[&[BinaryDescriptor]]) {
        let n = documents.len().max(1) as f32;
        let mut df = vec![0u32; self.idf.len()];
        for doc in documents {
            let mut seen: Vec<u32> = doc.iter().map(|d| self.word(d)).collect();
            seen.sort_unstable();
            seen.dedup();
            for w in seen {
                df[w as usize] += 1;
            }
        }
        for (idf, df) in self.idf.iter_mut().zip(df) {
            *idf = (n / df.max(1) as f32).ln();
        }
    }
}

/// DBoW2's L1 score of two L1-normalised vectors, in [0, 1] (1: same
/// words in the same proportions): `1 - |a - b|_1 / 2`, computed over the
/// common words only.
pub fn bow_score(a: &BowVector, b: &BowVector) -> f32 {
    let (mut i, mut j, mut s) = (0, 0, 0.0f32);
    while i < a.0.len() && j < b.0.len() {
        let ((wa, va), (wb, vb)) = (a.0[i], b.0[j]);
        match wa.cmp(&wb) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                s += va + vb - (va - vb).abs();
                i += 1;
                j += 1;
            }
        }
    }
    s / 2.0
}

/// An inverted index (word -> documents holding it) over documents with
/// caller-chosen ids: a query scores only the documents sharing a word.
#[derive(Debug, Clone, Default)]
pub struct PlaceIndex {
    inverted: HashMap<u32, Vec<(u32, f32)>>,
}

impl PlaceIndex {
    /// Adds document `doc` with word vector `bow`.
    pub fn add(&mut self, doc: u32, bow: &BowVector) {
        for &(w, x) in &bow.0 {
            self.inverted.entry(w).or_default().push((doc, x));
        }
    }

    /// The documents sharing a word with `bow`, with their [`bow_score`],
    /// best first (ties: lower id first).
    pub fn query(&self, bow: &BowVector) -> Vec<(u32, f32)> {
        let mut acc: HashMap<u32, f32> = HashMap::new();
        for &(w, q) in &bow.0 {
            for &(doc, x) in self.inverted.get(&w).map_or(&[][..], Vec::as_slice) {
                *acc.entry(doc).or_default() += q + x - (q - x).abs();
            }
        }
        let mut out: Vec<(u32, f32)> = acc.into_iter().map(|(d, s)| (d, s / 2.0)).collect();
        out.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        out
    }
}

/// Seeded k-majority clustering of `sample[members]`: k-means++ seeding on
/// Hamming distance, then rounds of nearest-centre assignment and bitwise
/// majority centres. Returns the centres and each one's members (empty
/// clusters dropped).
fn k_majority(
    sample: &[BinaryDescriptor],
    members: &[usize],
    k: usize,
    iterations: usize,
    rng: &mut SplitMix64,
) -> (Vec<BinaryDescriptor>, Vec<Vec<usize>>) {
    if members.len() <= k {
        return (members.iter().map(|&m| sample[m]).collect(), members.iter().map(|&m| vec![m]).collect());
    }
    let mut centers = vec![sample[members[rng.below(members.len())]]];
    let mut nearest: Vec<u32> = members.iter().map(|&m| hamming_distance(&centers[0], &sample[m])).collect();
    while centers.len() < k {
        let total: f64 = nearest.iter().map(|&d| f64::from(d * d)).sum();
        if total == 0.0 {
            break;
        }
        let mut target = rng.next_f64() * total;
        let mut pick = members.len() - 1;
        for (i, &d) in nearest.iter().enumerate() {
            target -= f64::from(d * d);
            if target <= 0.0 {
                pick = i;
                break;
            }
        }
        let c = sample[members[pick]];
        for (n, &m) in nearest.iter_mut().zip(members) {
            *n = (*n).min(hamming_distance(&c, &sample[m]));
        }
        centers.push(c);
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for round in 0..iterations.max(1) {
        let mut next: Vec<Vec<usize>> = vec![Vec::new(); centers.len()];
        for &m in members {
            // The nearest centre, the first among equals.
            let d = &sample[m];
            let mut best = (u32::MAX, 0);
            for (c, center) in centers.iter().enumerate() {
                let dist = hamming_distance(center, d);
                if dist < best.0 {
                    best = (dist, c);
                }
            }
            next[best.1].push(m);
        }
        let stable = round > 0 && next == groups;
        groups = next;
        if stable {
            break;
        }
        for (c, g) in centers.iter_mut().zip(&groups) {
            if !g.is_empty() {
                *c = majority(sample, g);
            }
        }
    }
    let keep: Vec<bool> = groups.iter().map(|g| !g.is_empty()).collect();
    let centers = centers.into_iter().zip(&keep).filter(|(_, k)| **k).map(|(c, _)| c).collect();
    groups.retain(|g| !g.is_empty());
    (centers, groups)
}

/// Byte `b` spread over eight byte lanes: lane `k` (bits `8k..8k+8` of the
/// `u64`) holds bit `k` of `b`.
const SPREAD: [u64; 256] = {
    let mut t = [0u64; 256];
    let mut b = 0;
    while b < 256 {
        let mut k = 0;
        while k < 8 {
            t[b] |= ((b as u64 >> k) & 1) << (8 * k);
            k += 1;
        }
        b += 1;
    }
    t
};

/// Descriptors counted in byte lanes before the lanes are flushed (a lane
/// holds at most 255).
const LANE_MAX: usize = 255;

/// The bitwise majority of the descriptors `group` (ties give 0).
fn majority(sample: &[BinaryDescriptor], group: &[usize]) -> BinaryDescriptor {
    let ones = bit_counts(sample, group);
    let mut out = [0u64; 4];
    for (bit, &count) in ones.iter().enumerate() {
        if 2 * count as usize > group.len() {
            out[bit / 64] |= 1 << (bit % 64);
        }
    }
    out
}

/// How many descriptors of `group` set each of the 256 bits. Counts in
/// byte lanes (SWAR): one table lookup and one add per descriptor byte, for
/// eight bits at once, instead of a branch per set bit; the lanes are
/// flushed into the `u32` counts every [`LANE_MAX`] descriptors.
fn bit_counts(sample: &[BinaryDescriptor], group: &[usize]) -> [u32; 256] {
    let mut ones = [0u32; 256];
    // Lane `k` of `lanes[8 w + j]` counts bit `8 j + k` of word `w`.
    let mut lanes = [0u64; 32];
    for chunk in group.chunks(LANE_MAX) {
        for &m in chunk {
            for (w, &word) in sample[m].iter().enumerate() {
                for (j, lane) in lanes[8 * w..8 * w + 8].iter_mut().enumerate() {
                    *lane += SPREAD[((word >> (8 * j)) & 0xff) as usize];
                }
            }
        }
        for (i, lane) in lanes.iter_mut().enumerate() {
            for (k, count) in ones[8 * i..8 * i + 8].iter_mut().enumerate() {
                *count += ((*lane >> (8 * k)) & 0xff) as u32;
            }
            *lane = 0;
        }
    }
    ones
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` noisy copies (`flips` random bits each) of each of `bases`.
    fn noisy(bases: &[BinaryDescriptor], n: usize, flips: usize, rng: &mut SplitMix64) -> Vec<BinaryDescriptor> {
        let mut out = Vec::new();
        for b in bases {
            for _ in 0..n {
                let mut d = *b;
                for _ in 0..flips {
                    let bit = rng.below(256);
                    d[bit / 64] ^= 1 << (bit % 64);
                }
                out.push(d);
            }
        }
        out
    }

    fn random_descriptors(n: usize, rng: &mut SplitMix64) -> Vec<BinaryDescriptor> {
        (0..n).map(|_| [rng.next_u64(), rng.next_u64(), rng.next_u64(), rng.next_u64()]).collect()
    }

    #[test]
    fn a_revisited_place_scores_above_other_places() {
        let mut rng = SplitMix64::new(7);
        // Three places, each its own 60 landmarks seen with descriptor noise.
        let places: Vec<Vec<BinaryDescriptor>> = (0..3).map(|_| random_descriptors(60, &mut rng)).collect();
        let images: Vec<Vec<BinaryDescriptor>> = places.iter().map(|p| noisy(p, 2, 12, &mut rng)).collect();
        let docs: Vec<&[BinaryDescriptor]> = images.iter().map(Vec::as_slice).collect();
        let vocab = Vocabulary::train(&docs, &VocabularyOptions::default());
        assert!(vocab.num_words() > 100, "{} words", vocab.num_words());
        let mut index = PlaceIndex::default();
        for (i, img) in images.iter().enumerate() {
            index.add(i as u32, &vocab.transform(img));
        }
        // Place 1 seen again, with fresh noise.
        let again = vocab.transform(&noisy(&places[1], 1, 12, &mut rng));
        let hits = index.query(&again);
        assert_eq!(hits.first().map(|h| h.0), Some(1), "{hits:?}");
        let other = hits.iter().filter(|h| h.0 != 1).map(|h| h.1).fold(0.0, f32::max);
        assert!(hits[0].1 > 3.0 * other.max(0.01), "{hits:?}");
        assert!((bow_score(&again, &vocab.transform(&images[1])) - hits[0].1).abs() < 1e-5);
    }

    #[test]
    fn bit_counts_equal_a_bit_by_bit_count() {
        let mut rng = SplitMix64::new(11);
        let mut sample = random_descriptors(700, &mut rng);
        // Rows of all ones: 600 of them overflow a byte lane unless the
        // lanes are flushed in time.
        sample.extend(std::iter::repeat_n([u64::MAX; 4], 600));
        let naive = |group: &[usize]| {
            let mut ones = [0u32; 256];
            for &m in group {
                for (bit, count) in ones.iter_mut().enumerate() {
                    *count += ((sample[m][bit / 64] >> (bit % 64)) & 1) as u32;
                }
            }
            ones
        };
        let all: Vec<usize> = (0..sample.len()).collect();
        for group in [&all[..0], &all[..1], &all[..2], &all[..255], &all[..256], &all[3..700], &all[..], &all[700..]] {
            assert_eq!(bit_counts(&sample, group), naive(group), "{} descriptors", group.len());
        }
        assert_eq!(majority(&sample, &all[700..]), [u64::MAX; 4]);
        // Ties give 0: a row and its complement.
        let pair = [sample[0], sample[0].map(|w| !w)];
        assert_eq!(majority(&pair, &[0, 1]), [0; 4]);
    }

    #[test]
    fn training_is_deterministic_and_scores_are_bounded() {
        let mut rng = SplitMix64::new(3);
        let a = random_descriptors(500, &mut rng);
        let b = random_descriptors(500, &mut rng);
        let docs: Vec<&[BinaryDescriptor]> = vec![&a, &b];
        let v1 = Vocabulary::train(&docs, &VocabularyOptions::default());
        let v2 = Vocabulary::train(&docs, &VocabularyOptions::default());
        let (x1, x2) = (v1.transform(&a), v2.transform(&a));
        assert_eq!(x1, x2);
        assert!((bow_score(&x1, &x1) - 1.0).abs() < 1e-5);
        let s = bow_score(&x1, &v1.transform(&b));
        assert!((0.0..0.5).contains(&s), "{s}");
        assert_eq!(Vocabulary::train(&[], &VocabularyOptions::default()).num_words(), 1);
    }
}
