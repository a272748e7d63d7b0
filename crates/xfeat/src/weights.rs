//! Reading a PyTorch `state_dict` checkpoint (`torch.save` zip format:
//! `<name>/data.pkl` holds the pickled dict, `<name>/data/<key>` the raw
//! little-endian storages) into plain `f32` tensors, without Python.

use crate::XFeatError;
use crate::pickle::{self, Value};
use crate::zip::StoredZip;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A dense row-major `f32` tensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    /// Sizes, outermost first.
    pub shape: Vec<usize>,
    /// `shape.iter().product()` values, row-major.
    pub data: Vec<f32>,
}

/// The floating-point tensors of a checkpoint by state-dict key (integer
/// tensors such as BatchNorm's `num_batches_tracked` are skipped).
#[derive(Debug, Clone, Default)]
pub struct StateDict {
    /// The file it came from (for error messages).
    pub path: PathBuf,
    /// Tensors by key.
    pub tensors: BTreeMap<String, Tensor>,
}

impl StateDict {
    /// Reads a `torch.save(state_dict)` zip checkpoint.
    pub fn read(path: &Path) -> Result<Self, XFeatError> {
        let bytes = std::fs::read(path).map_err(|source| XFeatError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&bytes, path)
    }

    /// Parses checkpoint bytes; `path` only names the source in errors.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self, XFeatError> {
        let bad_zip = |reason: String| XFeatError::BadArchive { path: path.to_path_buf(), reason };
        let bad_pickle = |reason: String| XFeatError::BadPickle { path: path.to_path_buf(), reason };
        let zip = StoredZip::parse(bytes).map_err(bad_zip)?;
        let pkl = zip.find_suffix("data.pkl").ok_or_else(|| bad_zip("no data.pkl entry".into()))?;
        let pkl = bytes.get(pkl).ok_or_else(|| bad_zip("data.pkl out of range".into()))?;
        let root = pickle::load(pkl).map_err(bad_pickle)?;
        let Value::Dict(items) = root else {
            return Err(bad_pickle("the pickle is not a dict (expected a state_dict)".into()));
        };
        let mut tensors = BTreeMap::new();
        for (k, v) in items {
            let Value::Str(name) = k else {
                return Err(bad_pickle(format!("non-string key {k:?}")));
            };
            let tensor = rebuild_tensor(&v, &zip, bytes).map_err(|e| bad_pickle(format!("tensor '{name}': {e}")))?;
            if let Some(t) = tensor {
                tensors.insert(name, t);
            }
        }
        Ok(Self { path: path.to_path_buf(), tensors })
    }

    /// The tensor `name`, checked to have `shape`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<&Tensor, XFeatError> {
        let t = self.tensors.get(name).ok_or_else(|| XFeatError::BadWeight {
            path: self.path.clone(),
            name: name.to_string(),
            reason: "missing".into(),
        })?;
        if t.shape != shape {
            return Err(XFeatError::BadWeight {
                path: self.path.clone(),
                name: name.to_string(),
                reason: format!("shape {:?}, expected {shape:?}", t.shape),
            });
        }
        Ok(t)
    }
}

/// Element type of a storage, from its `torch.<Type>Storage` global.
fn storage_elem(global: &str) -> Result<Option<usize>, String> {
    Ok(match global {
        "torch.FloatStorage" => Some(4),
        // Integer / bool storages (e.g. `num_batches_tracked`): skipped.
        "torch.LongStorage" | "torch.IntStorage" | "torch.BoolStorage" | "torch.ByteStorage" => None,
        other => return Err(format!("unsupported storage type {other}")),
    })
}

fn as_usize_list(v: &Value) -> Result<Vec<usize>, String> {
    match v {
        Value::Tuple(items) => items
            .iter()
            .map(|x| match x {
                Value::Int(i) if *i >= 0 => Ok(*i as usize),
                other => Err(format!("expected a non-negative int, got {other:?}")),
            })
            .collect(),
        other => Err(format!("expected a tuple of ints, got {other:?}")),
    }
}

/// Interprets `torch._utils._rebuild_tensor_v2(storage, offset, size, stride, ...)`.
/// Returns `None` for non-float tensors.
fn rebuild_tensor(v: &Value, zip: &StoredZip, bytes: &[u8]) -> Result<Option<Tensor>, String> {
    let Value::Call(f, args) = v else {
        return Err(format!("not a tensor: {v:?}"));
    };
    if **f != Value::Global("torch._utils._rebuild_tensor_v2".into()) {
        return Err(format!("unsupported tensor constructor {f:?}"));
    }
    let [Value::PersId(pid), Value::Int(offset), size, stride, ..] = args.as_slice() else {
        return Err("unexpected _rebuild_tensor_v2 arguments".into());
    };
    let Value::Tuple(pid) = &**pid else {
        return Err("storage id is not a tuple".into());
    };
    let [Value::Str(tag), Value::Global(kind), Value::Str(key), _location, Value::Int(numel)] = pid.as_slice() else {
        return Err(format!("unexpected storage id {pid:?}"));
    };
    if tag != "storage" {
        return Err(format!("unexpected persistent id tag '{tag}'"));
    }
    let Some(elem) = storage_elem(kind)? else {
        return Ok(None);
    };
    let shape = as_usize_list(size)?;
    let strides = as_usize_list(stride)?;
    if shape.len() != strides.len() {
        return Err("size and stride differ in length".into());
    }
    let range = zip.find_suffix(&format!("data/{key}")).ok_or_else(|| format!("storage data/{key} missing"))?;
    let raw = bytes.get(range).ok_or("storage out of range")?;
    let numel = usize::try_from(*numel).map_err(|_| "negative storage size")?;
    let nbytes = numel.checked_mul(elem).ok_or("storage size overflows")?;
    let raw =
        raw.get(..nbytes).ok_or_else(|| format!("storage data/{key} has {} bytes, expected {nbytes}", raw.len()))?;
    let storage: Vec<f32> = raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    let offset = usize::try_from(*offset).map_err(|_| "negative storage offset")?;
    let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or("tensor size overflows")?;
    // A checkpoint tensor never has more elements than its storage (no
    // broadcast strides); this also bounds the allocation below.
    if count > numel {
        return Err(format!("{count} elements from a storage of {numel}"));
    }
    // Gather with the given strides (checkpoints are usually contiguous, but
    // nothing requires it).
    let mut data = Vec::with_capacity(count);
    let mut idx = vec![0usize; shape.len()];
    for _ in 0..count {
        let at = idx
            .iter()
            .zip(&strides)
            .try_fold(offset, |acc, (i, s)| i.checked_mul(*s).and_then(|v| v.checked_add(acc)))
            .ok_or("element offset overflows")?;
        data.push(*storage.get(at).ok_or_else(|| format!("element {at} outside storage of {numel}"))?);
        for d in (0..shape.len()).rev() {
            idx[d] += 1;
            if idx[d] < shape[d] {
                break;
            }
            idx[d] = 0;
        }
    }
    Ok(Some(Tensor { shape, data }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `torch.save` of {'a.weight': arange(6).view(2,3) - 2.5,
    /// 'b.t': arange(12).view(3,4).t(), 'c.slice': arange(12).view(3,4)[1:, 1:3],
    /// 'n': tensor(7)} (int64), made by torch 2.15.
    const TINY: &[u8] = include_bytes!("../tests/fixtures/tiny-state-dict.pt");

    #[test]
    fn reads_strided_and_offset_tensors() {
        let sd = StateDict::parse(TINY, Path::new("tiny.pt")).unwrap();
        assert_eq!(sd.tensors.len(), 3, "the int64 tensor is skipped");
        assert_eq!(sd.get("a.weight", &[2, 3]).unwrap().data, vec![-2.5, -1.5, -0.5, 0.5, 1.5, 2.5]);
        let bt = sd.get("b.t", &[4, 3]).unwrap();
        assert_eq!(bt.data, vec![0.0, 4.0, 8.0, 1.0, 5.0, 9.0, 2.0, 6.0, 10.0, 3.0, 7.0, 11.0]);
        assert_eq!(sd.get("c.slice", &[2, 2]).unwrap().data, vec![5.0, 6.0, 9.0, 10.0]);
        let e = sd.get("a.weight", &[3, 2]).unwrap_err().to_string();
        assert!(e.contains("tiny.pt") && e.contains("a.weight") && e.contains("[2, 3]"), "{e}");
        assert!(sd.get("missing", &[1]).is_err());
    }

    #[test]
    fn corrupt_files_are_errors_not_panics() {
        // Every truncation, and a byte flipped at every position, either
        // parses or fails cleanly.
        for len in 0..TINY.len() {
            let _ = StateDict::parse(&TINY[..len], Path::new("t.pt"));
        }
        for i in 0..TINY.len() {
            let mut b = TINY.to_vec();
            b[i] ^= 0x5a;
            let _ = StateDict::parse(&b, Path::new("t.pt"));
        }
        let e = StateDict::parse(b"not a zip at all, just text", Path::new("x.pt")).unwrap_err().to_string();
        assert!(e.contains("x.pt"), "{e}");
    }
}
