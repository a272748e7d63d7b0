//! Where the records of non-keyframes live until the final localisation
//! (issue 15, item 3): [`RecordStore`], the one owner of a map's records.
//!
//! A record ([`FrameRecord`]) is small (20 bytes an observation) but every
//! non-keyframe has one, so an hour of video holds gigabytes of them. The
//! store keeps the newest records in memory up to a byte budget
//! (`--record-memory`) and appends older ones to a temporary file, keeping
//! only an index entry per record in memory. Records spilled to the file are
//! never rewritten: what the run still changes about them is kept beside the
//! index as a history and replayed, in the order it happened, when a record
//! is read back:
//!
//! - a culled keyframe's relink table (`cull.rs`): each of its keypoints'
//!   first link to another keyframe's observation;
//! - matches to a keyframe registered while the frame was pending, and the
//!   promotion of a frame to keyframe;
//! - rolling-shutter compensation (`rolling_shutter.rs`), computed from the
//!   camera, velocities and readout it was made with.
//!
//! Records in memory get the same changes at once, so a record read back
//! equals the record an in-memory run would hold (the tests compare them).
//! Final localisation reads the records back in their order of creation
//! (frame order, apart from backward tracking and relocalisation), a bounded
//! batch at a time ([`RecordStore::groups`]).
//!
//! The temporary file lives beside the run's output folder (the same file
//! system as the outputs the user chose room for; `$TMPDIR` is often a
//! memory file system), named `.OUT.scratch-PID-N`: it is removed when the
//! store is dropped, whatever ended the run (success, an error, Ctrl-C), and
//! the next writer to `OUT` removes one a killed run left
//! ([`colslam_image::OutputDir`]'s leftover cleanup).

use crate::error::SlamError;
use crate::frame::{FrameData, FrameRecord, RecordObs};
use crate::mapper::rolling_shutter::Compensation;
use colslam_features::Match;
use colslam_scene::{ImageId, TrackElement};
use std::borrow::Cow;
use std::collections::HashMap;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// First bytes of a record file, with the format's version.
pub const RECORD_FILE_MAGIC: &[u8; 8] = b"CSLREC01";

/// Records always kept in memory, the newest: the pipeline promotes the
/// record of the frame before the current one, and cull pushes one record,
/// so the records it changes in place are among these (older ones take the
/// replayed history, which is exact but slower to read).
const KEEP_NEWEST: usize = 8;

/// Where and when a store spills its records.
#[derive(Debug, Clone)]
pub struct SpillConfig {
    /// The folder of the temporary file.
    pub dir: PathBuf,
    /// The start of its name; the store appends `PID-N`.
    pub prefix: String,
    /// Bytes of records kept in memory before older ones are spilled.
    pub budget: usize,
}

impl SpillConfig {
    /// The system's temporary folder (a library run without an output
    /// folder), with `budget` bytes in memory.
    pub fn temp(budget: usize) -> Self {
        Self { dir: std::env::temp_dir(), prefix: "colslam-records-".into(), budget }
    }
}

/// A culled keyframe, for records that matched it: each of its keypoints'
/// first link to another keyframe (none: the observation is dropped), and
/// its frame, whose records are no longer promoted.
#[derive(Debug, Clone)]
struct Cull {
    id: ImageId,
    frame: usize,
    links: Vec<Option<TrackElement>>,
}

/// A change to a spilled record, replayed after the culls before it.
#[derive(Debug, Clone)]
enum Change {
    /// Observations appended (matches to a new keyframe).
    Add(Vec<RecordObs>),
    /// Became a keyframe.
    Promote,
}

/// A record in the file.
#[derive(Debug, Clone)]
struct Spilled {
    frame: usize,
    offset: u64,
    len: u32,
    /// Culls already applied when it was written.
    epoch: usize,
    /// Changes since, each with the number of culls before it.
    changes: Vec<(usize, Change)>,
}

#[derive(Debug, Clone)]
enum Slot {
    Memory(FrameRecord),
    Disk(Spilled),
}

/// The temporary file; removed when the last store sharing it is dropped.
#[derive(Debug)]
struct SpillFile {
    path: PathBuf,
    /// The file and its length (appends and reads take turns).
    file: Mutex<(std::fs::File, u64)>,
}

impl Drop for SpillFile {
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_file(&self.path) {
            tracing::warn!("record store: cannot remove {}: {e}", self.path.display());
        }
    }
}

/// Distinguishes the files of one process.
static FILE_COUNTER: AtomicU64 = AtomicU64::new(0);

impl SpillFile {
    fn create(config: &SpillConfig) -> Result<Self, SlamError> {
        let n = FILE_COUNTER.fetch_add(1, Ordering::Relaxed);
        let path = config.dir.join(format!("{}{}-{n}", config.prefix, std::process::id()));
        let io = |action: &str| {
            let path = path.clone();
            let action = action.to_string();
            move |source| SlamError::RecordStore { path, action, source }
        };
        let mut file =
            std::fs::OpenOptions::new().read(true).write(true).create_new(true).open(&path).map_err(io("creating"))?;
        // From here on a failure removes the file (Drop).
        let out = Self { path: path.clone(), file: Mutex::new((file.try_clone().map_err(io("opening"))?, 0)) };
        file.write_all(RECORD_FILE_MAGIC).map_err(io("writing"))?;
        out.lock().1 = RECORD_FILE_MAGIC.len() as u64;
        tracing::debug!("record store: spilling records to {}", path.display());
        Ok(out)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, (std::fs::File, u64)> {
        // A panic while holding the lock leaves the file as it was: the
        // offsets of complete records stay valid.
        self.file.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn io(&self, action: &str) -> impl FnOnce(std::io::Error) -> SlamError + use<> {
        let (path, action) = (self.path.clone(), action.to_string());
        move |source| SlamError::RecordStore { path, action, source }
    }

    /// Appends `bytes`; returns their offset.
    fn append(&self, bytes: &[u8]) -> Result<u64, SlamError> {
        let mut guard = self.lock();
        let (file, len) = &mut *guard;
        let offset = *len;
        file.seek(SeekFrom::Start(offset)).map_err(self.io("writing"))?;
        file.write_all(bytes).map_err(self.io("writing"))?;
        *len += bytes.len() as u64;
        Ok(offset)
    }

    fn read(&self, offset: u64, len: u32) -> Result<Vec<u8>, SlamError> {
        let mut buf = vec![0; len as usize];
        let mut guard = self.lock();
        guard.0.seek(SeekFrom::Start(offset)).map_err(self.io("reading"))?;
        guard.0.read_exact(&mut buf).map_err(self.io("reading"))?;
        Ok(buf)
    }
}

/// The records of one map: the newest in memory, older ones in a temporary
/// file once they exceed the budget (see the module's documentation).
#[derive(Debug, Clone)]
pub struct RecordStore {
    slots: Vec<Slot>,
    /// Slots below are on disk (records are spilled oldest first).
    spilled: usize,
    /// Bytes of the records in memory (estimated, [`record_bytes`]).
    memory: usize,
    culls: Vec<Cull>,
    compensation: Option<Arc<Compensation>>,
    config: Option<SpillConfig>,
    file: Option<Arc<SpillFile>>,
    /// Bytes written to the file.
    disk: u64,
}

impl Default for RecordStore {
    fn default() -> Self {
        Self::new(None)
    }
}

/// The memory a record holds, roughly (its vectors and name).
fn record_bytes(r: &FrameRecord) -> usize {
    std::mem::size_of::<FrameRecord>()
        + r.frame.name.len()
        + r.obs.len() * std::mem::size_of::<RecordObs>()
        + r.compensated.len() * std::mem::size_of::<colslam_geometry::Vec2>()
}

impl RecordStore {
    /// An empty store; without `config` every record stays in memory.
    pub fn new(config: Option<SpillConfig>) -> Self {
        Self {
            slots: Vec::new(),
            spilled: 0,
            memory: 0,
            culls: Vec::new(),
            compensation: None,
            config,
            file: None,
            disk: 0,
        }
    }

    /// Where and when the store spills from now on (`None`: never).
    pub fn set_config(&mut self, config: Option<SpillConfig>) {
        self.config = config;
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Records in the file.
    pub fn spilled(&self) -> usize {
        self.spilled
    }

    /// Bytes written to the file so far.
    pub fn disk_bytes(&self) -> u64 {
        self.disk
    }

    /// The file's path while it exists.
    pub fn file_path(&self) -> Option<&std::path::Path> {
        self.file.as_deref().map(|f| f.path.as_path())
    }

    /// Adds a record; returns its index. Spills the oldest records in memory
    /// when they exceed the budget.
    pub fn push(&mut self, record: FrameRecord) -> Result<usize, SlamError> {
        self.memory += record_bytes(&record);
        self.slots.push(Slot::Memory(record));
        self.spill_over_budget()?;
        Ok(self.slots.len() - 1)
    }

    /// Appends the matches of `data` (query) to keyframe `kf` (train) to
    /// record `index`.
    pub fn add_matches(&mut self, index: usize, data: &FrameData, kf: ImageId, matches: &[Match]) {
        let epoch = self.culls.len();
        match self.slots.get_mut(index) {
            Some(Slot::Memory(r)) => {
                let before = r.obs.len();
                r.add_matches(data, kf, matches);
                self.memory += (r.obs.len() - before) * std::mem::size_of::<RecordObs>();
            }
            Some(Slot::Disk(s)) => {
                let mut r = FrameRecord::new(data);
                r.add_matches(data, kf, matches);
                s.changes.push((epoch, Change::Add(r.obs)));
            }
            None => {}
        }
    }

    /// Marks record `index` as promoted (its frame became a keyframe).
    pub fn promote(&mut self, index: usize) {
        let epoch = self.culls.len();
        match self.slots.get_mut(index) {
            Some(Slot::Memory(r)) => r.promoted = true,
            Some(Slot::Disk(s)) => s.changes.push((epoch, Change::Promote)),
            None => {}
        }
    }

    /// Keyframe `id` of frame `frame` was culled: every observation of it
    /// moves to its keypoint's first link in `links` (or is dropped), and
    /// the frame's records are no longer promoted.
    pub fn cull(&mut self, id: ImageId, frame: usize, links: Vec<Option<TrackElement>>) {
        let cull = Cull { id, frame, links };
        for slot in &mut self.slots[self.spilled..] {
            if let Slot::Memory(r) = slot {
                apply_cull(r, &cull);
            }
        }
        // Spilled records take it when read back.
        if self.spilled > 0 {
            self.culls.push(cull);
        } else {
            self.culls.clear();
        }
    }

    /// Compensates every record for rolling shutter with `spec` from its
    /// measured positions (replacing an earlier compensation).
    pub fn compensate(&mut self, spec: Compensation) {
        for slot in &mut self.slots {
            if let Slot::Memory(r) = slot {
                let before = r.compensated.len();
                spec.apply(r);
                self.memory = (self.memory + r.compensated.len() * 16).saturating_sub(before * 16);
            }
        }
        self.compensation = (self.spilled > 0).then(|| Arc::new(spec));
    }

    /// Record `index` as it is now.
    pub fn get(&self, index: usize) -> Result<Option<Cow<'_, FrameRecord>>, SlamError> {
        match self.slots.get(index) {
            Some(Slot::Memory(r)) => Ok(Some(Cow::Borrowed(r))),
            Some(Slot::Disk(s)) => self.read_back(s).map(|r| Some(Cow::Owned(r))),
            None => Ok(None),
        }
    }

    /// The records' indices grouped by frame, in the order each frame first
    /// appears: a frame can hold several records (tracked by two maps that
    /// were merged, tracked backwards and relocalised, culled after it was
    /// promoted), which localisation pools ([`Self::pooled`]).
    pub fn groups(&self) -> Vec<Vec<usize>> {
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut slot: HashMap<usize, usize> = HashMap::new();
        for (i, s) in self.slots.iter().enumerate() {
            let frame = match s {
                Slot::Memory(r) => r.frame.index,
                Slot::Disk(d) => d.frame,
            };
            match slot.get(&frame) {
                Some(&g) => groups[g].push(i),
                None => {
                    slot.insert(frame, groups.len());
                    groups.push(vec![i]);
                }
            }
        }
        groups
    }

    /// The records `group` (one frame's, from [`Self::groups`]) pooled into
    /// one: their observations in order, promoted when any is. A frame
    /// with one record in memory borrows it.
    pub fn pooled(&self, group: &[usize]) -> Result<Option<Cow<'_, FrameRecord>>, SlamError> {
        let mut out: Option<Cow<'_, FrameRecord>> = None;
        for &i in group {
            let Some(r) = self.get(i)? else { continue };
            match &mut out {
                Some(o) => o.to_mut().extend(&r),
                None => out = Some(r),
            }
        }
        Ok(out)
    }

    /// Every record pooled by frame ([`Self::groups`]), read into memory:
    /// for tests and small maps.
    pub fn pooled_all(&self) -> Result<Vec<FrameRecord>, SlamError> {
        let mut out = Vec::new();
        for g in self.groups() {
            if let Some(r) = self.pooled(&g)? {
                out.push(r.into_owned());
            }
        }
        Ok(out)
    }

    /// Every record as it is now, one by one, in order.
    pub fn all(&self) -> Result<Vec<FrameRecord>, SlamError> {
        (0..self.len()).filter_map(|i| self.get(i).transpose()).map(|r| r.map(Cow::into_owned)).collect()
    }

    /// Drops every record and the file (the final localisation is done).
    pub fn clear(&mut self) {
        *self = Self::new(self.config.take());
    }

    /// Spills the oldest records in memory while they exceed the budget,
    /// keeping the [`KEEP_NEWEST`].
    fn spill_over_budget(&mut self) -> Result<(), SlamError> {
        let Some(config) = &self.config else { return Ok(()) };
        if self.memory <= config.budget {
            return Ok(());
        }
        let file = match &self.file {
            Some(f) => f.clone(),
            None => {
                let f = Arc::new(SpillFile::create(config)?);
                self.file = Some(f.clone());
                f
            }
        };
        let keep = self.slots.len().saturating_sub(KEEP_NEWEST);
        let mut bytes = Vec::new();
        while self.memory > config.budget && self.spilled < keep {
            let Slot::Memory(r) = &self.slots[self.spilled] else {
                self.spilled += 1;
                continue;
            };
            bytes.clear();
            encode(r, &mut bytes);
            let len = u32::try_from(bytes.len()).map_err(|_| {
                let e = std::io::Error::new(std::io::ErrorKind::InvalidInput, "a record over 4 GiB");
                SlamError::RecordStore { path: file.path.clone(), action: "writing".into(), source: e }
            })?;
            let offset = file.append(&bytes)?;
            self.disk += u64::from(len);
            self.memory -= record_bytes(r).min(self.memory);
            let spilled = Spilled { frame: r.frame.index, offset, len, epoch: self.culls.len(), changes: Vec::new() };
            self.slots[self.spilled] = Slot::Disk(spilled);
            self.spilled += 1;
        }
        Ok(())
    }

    /// A spilled record read back with its history replayed.
    fn read_back(&self, s: &Spilled) -> Result<FrameRecord, SlamError> {
        // Slots on disk exist only once the file does.
        let Some(file) = &self.file else {
            return Err(SlamError::RecordStore {
                path: PathBuf::new(),
                action: "reading".into(),
                source: std::io::Error::other("the record file is gone"),
            });
        };
        let bytes = file.read(s.offset, s.len)?;
        let mut r = decode(&bytes).map_err(file.io("decoding"))?;
        if r.frame.index != s.frame {
            let e = std::io::Error::new(std::io::ErrorKind::InvalidData, "record of another frame");
            return Err(file.io("decoding")(e));
        }
        let mut keyframes = keyframes_of(&r);
        let mut changes = s.changes.iter().peekable();
        for (c, cull) in self.culls.iter().enumerate().skip(s.epoch) {
            while let Some((_, change)) = changes.next_if(|(at, _)| *at <= c) {
                apply_change(&mut r, change);
                keyframes = keyframes_of(&r);
            }
            if r.frame.index == cull.frame {
                r.promoted = false;
            }
            // Most culls concern none of a record's keyframes.
            if keyframes.binary_search(&cull.id).is_ok() {
                apply_cull(&mut r, cull);
                keyframes = keyframes_of(&r);
            }
        }
        for (_, change) in changes {
            apply_change(&mut r, change);
        }
        if let Some(spec) = &self.compensation {
            spec.apply(&mut r);
        }
        Ok(r)
    }
}

/// The distinct keyframes a record's observations refer to, sorted.
fn keyframes_of(r: &FrameRecord) -> Vec<ImageId> {
    let mut ids: Vec<ImageId> = r.obs.iter().map(|o| o.keyframe).collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

fn apply_change(r: &mut FrameRecord, change: &Change) {
    match change {
        Change::Add(obs) => {
            // Compensation comes after every change (it runs at the end).
            r.obs.extend_from_slice(obs);
        }
        Change::Promote => r.promoted = true,
    }
}

/// Replaces a record's observations of the culled keyframe by its
/// keypoints' first link (dropped without one), keeping the rolling-shutter
/// compensated coordinates beside their observations, and unpromotes the
/// culled keyframe's frame (it is localised again).
fn apply_cull(r: &mut FrameRecord, cull: &Cull) {
    if r.frame.index == cull.frame {
        r.promoted = false;
    }
    if !r.obs.iter().any(|o| o.keyframe == cull.id) {
        return;
    }
    let compensated = r.compensated.len() == r.obs.len();
    let mut obs = Vec::with_capacity(r.obs.len());
    let mut comp = Vec::new();
    for (k, o) in r.obs.iter().enumerate() {
        let o = if o.keyframe == cull.id {
            let Some(el) = cull.links.get(o.keyframe_kp as usize).and_then(|l| l.as_ref()) else { continue };
            o.relinked(el.image_id, el.point2d_idx)
        } else {
            *o
        };
        obs.push(o);
        if compensated {
            comp.push(r.compensated[k]);
        }
    }
    r.obs = obs;
    r.compensated = comp;
}

// ----- file format ------------------------------------------------------------
//
// After the magic, records one after another, little-endian: frame index
// u64, timestamp f64, name (u32 length, UTF-8), promoted u8, observations
// (u32 count; each frame keypoint u32, keypoint x, y f32, keyframe u32,
// keyframe keypoint u32), compensated coordinates (u32 count; each x, y f64).
// The index in memory holds each record's offset and length.

fn encode(r: &FrameRecord, out: &mut Vec<u8>) {
    out.extend_from_slice(&(r.frame.index as u64).to_le_bytes());
    out.extend_from_slice(&r.frame.timestamp.to_le_bytes());
    out.extend_from_slice(&(r.frame.name.len() as u32).to_le_bytes());
    out.extend_from_slice(r.frame.name.as_bytes());
    out.push(u8::from(r.promoted));
    out.extend_from_slice(&(r.obs.len() as u32).to_le_bytes());
    for o in &r.obs {
        let [x, y] = o.keypoint();
        for v in [o.frame_kp.to_le_bytes(), x.to_le_bytes(), y.to_le_bytes(), o.keyframe.0.to_le_bytes()] {
            out.extend_from_slice(&v);
        }
        out.extend_from_slice(&o.keyframe_kp.to_le_bytes());
    }
    out.extend_from_slice(&(r.compensated.len() as u32).to_le_bytes());
    for c in &r.compensated {
        out.extend_from_slice(&c.x.to_le_bytes());
        out.extend_from_slice(&c.y.to_le_bytes());
    }
}

/// Reads what [`encode`] wrote.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> std::io::Result<[u8; N]> {
        let Some((head, rest)) = self.0.split_first_chunk::<N>() else {
            return Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "record cut short"));
        };
        self.0 = rest;
        Ok(*head)
    }
    fn u32(&mut self) -> std::io::Result<u32> {
        self.take().map(u32::from_le_bytes)
    }
    fn f32(&mut self) -> std::io::Result<f32> {
        self.take().map(f32::from_le_bytes)
    }
    fn f64(&mut self) -> std::io::Result<f64> {
        self.take().map(f64::from_le_bytes)
    }
    /// A count of items of `size` bytes, checked against what is left.
    fn count(&mut self, size: usize) -> std::io::Result<usize> {
        let n = self.u32()? as usize;
        if n.saturating_mul(size) > self.0.len() {
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidData, "count beyond the record"));
        }
        Ok(n)
    }
}

fn decode(bytes: &[u8]) -> std::io::Result<FrameRecord> {
    let bad = |m: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, m.to_string());
    let mut rd = Reader(bytes);
    let index = usize::try_from(u64::from_le_bytes(rd.take()?)).map_err(|_| bad("frame index"))?;
    let timestamp = rd.f64()?;
    let n = rd.count(1)?;
    let (name, rest) = rd.0.split_at(n);
    let name = String::from_utf8(name.to_vec()).map_err(|_| bad("frame name"))?;
    rd.0 = rest;
    let promoted = rd.take::<1>()?[0] != 0;
    let n = rd.count(20)?;
    let mut obs = Vec::with_capacity(n);
    for _ in 0..n {
        let (kp, x, y, kf, kf_kp) = (rd.u32()?, rd.f32()?, rd.f32()?, rd.u32()?, rd.u32()?);
        obs.push(RecordObs::from_keypoint(kp, [x, y], ImageId(kf), kf_kp));
    }
    let n = rd.count(16)?;
    let mut compensated = Vec::with_capacity(n);
    for _ in 0..n {
        compensated.push(colslam_geometry::Vec2::new(rd.f64()?, rd.f64()?));
    }
    if !rd.0.is_empty() {
        return Err(bad("bytes after the record"));
    }
    let frame = crate::frame::FrameId { index, timestamp, name };
    Ok(FrameRecord { frame, obs, compensated, promoted })
}

#[cfg(test)]
#[path = "records_tests.rs"]
mod tests;
