//! Mutual nearest-neighbour matching on cosine similarity, as XFeat's
//! reference `XFeat.match`: each query's most similar train descriptor and
//! vice versa; a pair is kept when both agree and (optionally) the
//! similarity exceeds a minimum. Similarities come from an SGEMM over query
//! blocks, so memory stays at one block of rows.

use crate::nn::gemm_strided;
use colslam_features::{Descriptors, FeatureError, Features, Match, Matcher};
use rayon::prelude::*;

/// A best similarity and the index that has it.
type Best = (f32, u32);

/// Queries per block of the similarity matrix.
const QUERY_BLOCK: usize = 256;

/// Options of [`MnnCosineMatcher`].
#[derive(Debug, Clone, PartialEq)]
pub struct MnnCosineOptions {
    /// Keep a mutual pair only if its cosine similarity is above this
    /// (default 0.82, the reference `XFeat.match` default). Values `<= 0`
    /// switch the test off, as in the reference.
    pub min_cossim: f32,
}

impl Default for MnnCosineOptions {
    fn default() -> Self {
        Self { min_cossim: 0.82 }
    }
}

impl MnnCosineOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), FeatureError> {
        if !(self.min_cossim.is_finite() && self.min_cossim <= 1.0) {
            return Err(FeatureError::InvalidOptions {
                what: "mutual-nearest-neighbour cosine matcher",
                reason: format!("min_cossim {} must be finite and at most 1", self.min_cossim),
            });
        }
        Ok(())
    }
}

/// Mutual nearest neighbours on cosine similarity ("xfeat-mnn"). Expects
/// L2-normalised float descriptors (XFeat's are); on others the "cosine" is
/// the plain dot product, as in the reference.
#[derive(Debug, Clone)]
pub struct MnnCosineMatcher {
    opts: MnnCosineOptions,
}

impl MnnCosineMatcher {
    /// Checks the options.
    pub fn new(opts: MnnCosineOptions) -> Result<Self, FeatureError> {
        opts.validate()?;
        Ok(Self { opts })
    }

    /// The options.
    pub fn options(&self) -> &MnnCosineOptions {
        &self.opts
    }

    /// Matches row-major `dim`-dimensional descriptor sets. `distance` in the
    /// result is the Euclidean distance of unit vectors, `sqrt(2 - 2 cos)`.
    pub fn match_descriptors(&self, dim: usize, query: &[f32], train: &[f32]) -> Result<Vec<Match>, FeatureError> {
        if dim == 0 || !query.len().is_multiple_of(dim) || !train.len().is_multiple_of(dim) {
            return Err(FeatureError::DescriptorMismatch(format!(
                "{} and {} values are not whole {dim}-dimensional descriptors",
                query.len(),
                train.len()
            )));
        }
        let (nq, nt) = (query.len() / dim, train.len() / dim);
        if nq == 0 || nt == 0 {
            return Ok(Vec::new());
        }
        // Per block: forward best (sim, train index) of each query, and each
        // train row's best (sim, query index) within the block.
        let blocks: Vec<(Vec<Best>, Vec<Best>)> = (0..nq)
            .step_by(QUERY_BLOCK)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|q0| {
                let nb = QUERY_BLOCK.min(nq - q0);
                let mut sim = vec![0.0f32; nb * nt];
                // train^T: element (i, j) = train[j * dim + i].
                gemm_strided(nb, dim, nt, &query[q0 * dim..(q0 + nb) * dim], train, (1, dim), &mut sim);
                let mut fwd = Vec::with_capacity(nb);
                let mut rev = vec![(f32::NEG_INFINITY, u32::MAX); nt];
                for (r, row) in sim.chunks_exact(nt).enumerate() {
                    let mut best = (f32::NEG_INFINITY, u32::MAX);
                    for (j, (&s, rv)) in row.iter().zip(rev.iter_mut()).enumerate() {
                        // Strict comparisons keep the lowest index among ties.
                        if s > best.0 {
                            best = (s, j as u32);
                        }
                        if s > rv.0 {
                            *rv = (s, (q0 + r) as u32);
                        }
                    }
                    fwd.push(best);
                }
                (fwd, rev)
            })
            .collect();
        let mut fwd = Vec::with_capacity(nq);
        let mut rev = vec![(f32::NEG_INFINITY, u32::MAX); nt];
        // Blocks arrive in query order, so strict ">" again keeps the lowest query.
        for (f, r) in blocks {
            fwd.extend(f);
            for (acc, b) in rev.iter_mut().zip(r) {
                if b.0 > acc.0 {
                    *acc = b;
                }
            }
        }
        let mut out = Vec::new();
        for (qi, &(s, j)) in fwd.iter().enumerate() {
            let Some(&(_, back)) = rev.get(j as usize) else {
                continue;
            };
            if back as usize != qi || (self.opts.min_cossim > 0.0 && s <= self.opts.min_cossim) {
                continue;
            }
            out.push(Match { query: qi as u32, train: j, distance: (2.0 - 2.0 * s).max(0.0).sqrt() });
        }
        Ok(out)
    }
}

impl Matcher for MnnCosineMatcher {
    fn name(&self) -> &str {
        "xfeat-mnn"
    }

    fn match_features(&self, a: &Features, b: &Features) -> Result<Vec<Match>, FeatureError> {
        a.validate()?;
        b.validate()?;
        match (&a.descriptors, &b.descriptors) {
            (Descriptors::Float { dim: da, data: q }, Descriptors::Float { dim: db, data: t }) => {
                if q.is_empty() || t.is_empty() {
                    return Ok(Vec::new());
                }
                if da != db {
                    return Err(FeatureError::DescriptorMismatch(format!(
                        "{da}- and {db}-dimensional descriptors cannot be compared"
                    )));
                }
                self.match_descriptors(*da, q, t)
            }
            _ if a.is_empty() || b.is_empty() => Ok(Vec::new()),
            _ => {
                Err(FeatureError::DescriptorMismatch("the cosine matcher needs float descriptors on both sides".into()))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: &[f32]) -> Vec<f32> {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.iter().map(|x| x / n).collect()
    }

    /// Brute force by definition.
    fn naive(dim: usize, q: &[f32], t: &[f32], min: f32) -> Vec<(u32, u32)> {
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
        let argmax = |v: Vec<f32>| {
            v.iter().enumerate().fold((0, f32::NEG_INFINITY), |b, (i, &s)| if s > b.1 { (i, s) } else { b })
        };
        let (nq, nt) = (q.len() / dim, t.len() / dim);
        let mut out = Vec::new();
        for i in 0..nq {
            let qi = &q[i * dim..(i + 1) * dim];
            let (j, s) = argmax((0..nt).map(|j| dot(qi, &t[j * dim..(j + 1) * dim])).collect());
            let (back, _) =
                argmax((0..nq).map(|k| dot(&q[k * dim..(k + 1) * dim], &t[j * dim..(j + 1) * dim])).collect());
            if back == i && (min <= 0.0 || s > min) {
                out.push((i as u32, j as u32));
            }
        }
        out
    }

    #[test]
    fn equals_brute_force_across_blocks() {
        let dim = 8;
        let mut s = 7u64;
        let mut rnd = |n: usize| -> Vec<f32> {
            (0..n)
                .flat_map(|_| {
                    let v: Vec<f32> = (0..dim)
                        .map(|_| {
                            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                            (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
                        })
                        .collect();
                    unit(&v)
                })
                .collect()
        };
        let q = rnd(600);
        let t = rnd(500);
        for min in [-1.0f32, 0.82] {
            let m = MnnCosineMatcher::new(MnnCosineOptions { min_cossim: min }).unwrap();
            let got: Vec<(u32, u32)> =
                m.match_descriptors(dim, &q, &t).unwrap().iter().map(|m| (m.query, m.train)).collect();
            let want = naive(dim, &q, &t, min);
            assert!(!want.is_empty());
            assert_eq!(got, want, "min_cossim {min}");
        }
    }

    #[test]
    fn bad_inputs_and_options() {
        assert!(MnnCosineMatcher::new(MnnCosineOptions { min_cossim: f32::NAN }).is_err());
        assert!(MnnCosineMatcher::new(MnnCosineOptions { min_cossim: 1.5 }).is_err());
        let m = MnnCosineMatcher::new(MnnCosineOptions::default()).unwrap();
        assert!(m.match_descriptors(3, &[1.0; 4], &[1.0; 3]).is_err());
        assert!(m.match_descriptors(0, &[], &[]).is_err());
        assert!(m.match_descriptors(2, &[], &[1.0, 0.0]).unwrap().is_empty());
        let binary = Features::empty_binary();
        let float = Features {
            keypoints: vec![colslam_features::Keypoint {
                x: 0.0,
                y: 0.0,
                octave: 0,
                angle: 0.0,
                response: 1.0,
                size: 8.0,
            }],
            descriptors: Descriptors::Float { dim: 2, data: vec![1.0, 0.0] },
        };
        assert!(m.match_features(&binary, &float).unwrap().is_empty());
        let got = m.match_features(&float, &float).unwrap();
        assert_eq!(got.len(), 1);
        assert!(got[0].distance.abs() < 1e-3);
    }
}
