//! A minimal reader for the uncompressed ("stored") zip archives that
//! `torch.save` writes (PyTorch's `PytorchStreamWriter` never compresses).
//! Only the central directory and local headers are parsed; ZIP64 and
//! compressed entries are rejected with an error.

use std::collections::HashMap;

/// End-of-central-directory signature.
const EOCD_SIG: u32 = 0x0605_4b50;
/// Central-directory file header signature.
const CDIR_SIG: u32 = 0x0201_4b50;
/// Local file header signature.
const LOCAL_SIG: u32 = 0x0403_4b50;
/// Fixed size of the end-of-central-directory record.
const EOCD_LEN: usize = 22;
/// Fixed part of a central-directory header.
const CDIR_LEN: usize = 46;
/// Fixed part of a local header.
const LOCAL_LEN: usize = 30;
/// Largest zip comment (the EOCD search window).
const MAX_COMMENT: usize = 0xffff;
/// Compression method "stored".
const METHOD_STORED: u16 = 0;

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}
fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// The entries of a stored zip archive: name -> byte range in the archive.
#[derive(Debug)]
pub(crate) struct StoredZip {
    entries: HashMap<String, std::ops::Range<usize>>,
}

impl StoredZip {
    /// Parses the archive's directory. Errors name what is wrong.
    pub(crate) fn parse(bytes: &[u8]) -> Result<Self, String> {
        if bytes.len() < EOCD_LEN {
            return Err(format!("{} bytes is too short for a zip archive", bytes.len()));
        }
        let search_from = bytes.len().saturating_sub(EOCD_LEN + MAX_COMMENT);
        let eocd = (search_from..=bytes.len() - EOCD_LEN)
            .rev()
            .find(|&i| u32_at(bytes, i) == Some(EOCD_SIG))
            .ok_or("no end-of-central-directory record")?;
        let count = u16_at(bytes, eocd + 10).ok_or("truncated EOCD")? as usize;
        let cdir_off = u32_at(bytes, eocd + 16).ok_or("truncated EOCD")? as usize;
        if count == 0xffff || cdir_off == 0xffff_ffff {
            return Err("ZIP64 archives are not supported".into());
        }
        let mut entries = HashMap::with_capacity(count);
        let mut at = cdir_off;
        for _ in 0..count {
            if u32_at(bytes, at) != Some(CDIR_SIG) {
                return Err(format!("bad central-directory header at byte {at}"));
            }
            let short = || format!("truncated central-directory header at byte {at}");
            let method = u16_at(bytes, at + 10).ok_or_else(short)?;
            let csize = u32_at(bytes, at + 20).ok_or_else(short)? as usize;
            let usize_ = u32_at(bytes, at + 24).ok_or_else(short)? as usize;
            let name_len = u16_at(bytes, at + 28).ok_or_else(short)? as usize;
            let extra_len = u16_at(bytes, at + 30).ok_or_else(short)? as usize;
            let comment_len = u16_at(bytes, at + 32).ok_or_else(short)? as usize;
            let local = u32_at(bytes, at + 42).ok_or_else(short)? as usize;
            let name = bytes.get(at + CDIR_LEN..at + CDIR_LEN + name_len).ok_or_else(short)?;
            let name = String::from_utf8_lossy(name).into_owned();
            if method != METHOD_STORED || csize != usize_ {
                return Err(format!(
                    "entry '{name}' is compressed (method {method}); only stored entries are supported"
                ));
            }
            if u32_at(bytes, local) != Some(LOCAL_SIG) {
                return Err(format!("entry '{name}': bad local header at byte {local}"));
            }
            let l_name = u16_at(bytes, local + 26).ok_or("truncated local header")? as usize;
            let l_extra = u16_at(bytes, local + 28).ok_or("truncated local header")? as usize;
            let start = local + LOCAL_LEN + l_name + l_extra;
            let end = start.checked_add(csize).ok_or("entry size overflows")?;
            if end > bytes.len() {
                return Err(format!("entry '{name}' runs past the end of the archive"));
            }
            entries.insert(name, start..end);
            at += CDIR_LEN + name_len + extra_len + comment_len;
        }
        Ok(Self { entries })
    }

    /// Byte range of the entry whose name is `<top folder>/suffix` (PyTorch
    /// puts every entry under a top folder named after the saved file).
    pub(crate) fn find_suffix(&self, suffix: &str) -> Option<std::ops::Range<usize>> {
        self.entries
            .iter()
            .find(|(n, _)| n.strip_suffix(suffix).is_some_and(|p| p.ends_with('/') && p.len() > 1))
            .map(|(_, r)| r.clone())
    }
}
