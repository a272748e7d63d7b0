//! A small deterministic mutation fuzzer for the parsers' tests.
//!
//! Every parser gets one ordinary `#[test]` that calls [`fuzz`] with a
//! [`Corpus`] of valid inputs (written with the project's own writers where
//! there is one) and a closure running the parser. Each generated input is
//! the result of a few random mutations of a corpus sample; it must not make
//! the parser panic, run longer than [`TIME_LIMIT`], or allocate more than
//! [`MEMORY_LIMIT`] (one request, or live bytes at any time during the
//! input). Errors are fine: they are counted as rejected inputs (and their
//! `Display` is run, since a message that panics is a bug too).
//!
//! * Inputs are a function of the seed and their index only, so a failure
//!   reported as `COLSLAM_FUZZ_SEED=s COLSLAM_FUZZ_ONLY=i` replays alone.
//! * `COLSLAM_FUZZ_ITERS` sets the number of inputs (the test gives the
//!   default, small enough for the default `cargo test` run);
//!   `COLSLAM_FUZZ_SEED` the seed (default [`DEFAULT_SEED`], so CI is
//!   deterministic).
//! * An input may have several parts (the files of a COLMAP model); a
//!   mutation changes one part. [`Scratch`] writes parts to files for the
//!   parsers that read paths.
//! * A failing input is written under the target folder's `tmp/fuzz-failures`
//!   (see [`failure_dir`]) and the test panics with its path.
//! * Memory is counted by [`CountingAlloc`], which the test binary installs
//!   with [`fuzz_allocator!`](crate::fuzz_allocator) (a library cannot, as
//!   other test binaries have their own allocators). Requests above
//!   [`HARD_ALLOC_CAP`] during an input are refused (the process aborts
//!   after printing how to replay the input), so that a corrupt count cannot
//!   take the machine's memory; requests between [`MEMORY_LIMIT`] and the
//!   cap are served (untouched pages cost nothing) and reported after the
//!   input with the input saved.
//! * An input over the time limit is run a second time and fails only if it
//!   is slow again: on a shared machine a process may wait for a core.
//! * A watchdog thread aborts the process, after saving the input, when one
//!   input runs longer than [`HANG_ABORT`] (a hang would never return to the
//!   per-input time check).
//!
//! Wiring a new parser (for example one taking `&[u8]`) is one call:
//!
//! ```
//! use colslam_testutil::fuzz::{Corpus, fuzz};
//! let corpus = Corpus::single("request.txt").sample(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n".to_vec());
//! let parse = |bytes: &[u8]| -> Result<usize, String> {
//!     let text = std::str::from_utf8(bytes).map_err(|e| e.to_string())?;
//!     text.lines().next().map(str::len).ok_or_else(|| "empty".to_string())
//! };
//! // Without the counting allocator memory is not checked; fuzz tests install it.
//! let report = fuzz("first-line", &corpus, 100, |parts| parse(&parts[0]));
//! assert_eq!(report.inputs, 100);
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::HashMap;
use std::fmt;
use std::io::Write as _;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use colslam_geometry::SplitMix64;

/// Environment variable: number of inputs per fuzz test.
pub const ITERS_ENV: &str = "COLSLAM_FUZZ_ITERS";
/// Environment variable: the seed.
pub const SEED_ENV: &str = "COLSLAM_FUZZ_SEED";
/// Environment variable: run only the input of this index (to replay one).
pub const ONLY_ENV: &str = "COLSLAM_FUZZ_ONLY";
/// Seed when [`SEED_ENV`] is unset.
pub const DEFAULT_SEED: u64 = 17;
/// Longest accepted time for one input.
pub const TIME_LIMIT: Duration = Duration::from_secs(1);
/// Largest accepted allocation, and largest accepted growth of live bytes,
/// during one input.
pub const MEMORY_LIMIT: usize = 256 << 20;
/// Requests above this during an input are refused and abort the process.
pub const HARD_ALLOC_CAP: usize = 1 << 30;
/// An input running this long is taken to hang: the watchdog aborts.
pub const HANG_ABORT: Duration = Duration::from_secs(20);
/// Mutations never grow a part beyond this (large inputs only slow the run).
const MAX_PART_LEN: usize = 1 << 20;
/// At most this many mutations are stacked on one input.
const MAX_STACKED_MUTATIONS: usize = 5;
/// How often the watchdog looks at the running input.
const WATCHDOG_PERIOD: Duration = Duration::from_millis(200);

// ----- memory --------------------------------------------------------------

thread_local! {
    // Per thread, so that fuzz tests running in parallel in one binary
    // measure their own inputs only. `const` cells without destructors never
    // allocate, which an allocator requires.
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    /// `(seed, index)` of the input running on this thread, if any.
    static RUNNING: Cell<Option<(u64, u64)>> = const { Cell::new(None) };
}

/// The system allocator with per-thread counts of live bytes, their peak and
/// the largest request, for [`fuzz`]. Install it with
/// [`fuzz_allocator!`](crate::fuzz_allocator).
pub struct CountingAlloc;

fn note_alloc(size: usize) {
    let _ = LIVE.try_with(|live| {
        let now = live.get().saturating_add_unsigned(size);
        live.set(now);
        let _ = PEAK.try_with(|p| p.set(p.get().max(now)));
    });
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
    let _ = ALLOCATIONS.try_with(|n| n.set(n.get().wrapping_add(1)));
}

fn note_free(size: usize) {
    let _ = LIVE.try_with(|live| live.set(live.get().saturating_sub_unsigned(size)));
}

/// True when a request must be refused: above the hard cap while an input
/// runs on this thread. Prints the replay line without allocating.
fn refuse(size: usize) -> bool {
    if size <= HARD_ALLOC_CAP {
        return false;
    }
    let Some((seed, index)) = RUNNING.try_with(Cell::get).ok().flatten() else { return false };
    let mut err = std::io::stderr();
    let mut buf = [0u8; 20];
    let _ = err.write_all(b"\nfuzz: an input requested ");
    let _ = err.write_all(decimal(size as u64, &mut buf));
    let _ = err.write_all(b" bytes (hard cap exceeded, aborting); replay with COLSLAM_FUZZ_SEED=");
    let _ = err.write_all(decimal(seed, &mut buf));
    let _ = err.write_all(b" COLSLAM_FUZZ_ONLY=");
    let _ = err.write_all(decimal(index, &mut buf));
    let _ = err.write_all(b"\n");
    true
}

/// `v` in decimal, formatted into `buf` (no allocation).
fn decimal(mut v: u64, buf: &mut [u8; 20]) -> &[u8] {
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (v % 10) as u8;
        v /= 10;
        if v == 0 {
            break;
        }
    }
    &buf[i..]
}

// SAFETY: every method forwards to `System` with the caller's arguments and
// only adds bookkeeping in thread-local cells; refusing returns null, which
// the `GlobalAlloc` contract allows.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if refuse(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller upholds `alloc`'s contract.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            note_alloc(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if refuse(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller upholds `alloc_zeroed`'s contract.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            note_alloc(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller upholds `dealloc`'s contract.
        unsafe { System.dealloc(ptr, layout) };
        note_free(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if refuse(new_size) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller upholds `realloc`'s contract.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            note_free(layout.size());
            note_alloc(new_size);
        }
        p
    }
}

/// Installs [`CountingAlloc`] as the test binary's global allocator; every
/// fuzz test file invokes it once at the top level.
#[macro_export]
macro_rules! fuzz_allocator {
    () => {
        #[global_allocator]
        static COLSLAM_FUZZ_ALLOCATOR: $crate::fuzz::CountingAlloc = $crate::fuzz::CountingAlloc;
    };
}

/// True when [`CountingAlloc`] is the global allocator.
pub fn counting_alloc_installed() -> bool {
    let before = ALLOCATIONS.with(Cell::get);
    let b = std::hint::black_box(Box::new(0u64));
    drop(b);
    ALLOCATIONS.with(Cell::get) != before
}

/// Memory used by one input on this thread: growth of live bytes at their
/// peak, and the largest single request.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MemoryUse {
    /// Peak live bytes above the level at the start.
    pub peak: usize,
    /// Largest single request.
    pub largest: usize,
}

/// Measures the memory `f` allocates on this thread.
pub fn measure_memory<R>(f: impl FnOnce() -> R) -> (R, MemoryUse) {
    let base = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(base));
    LARGEST.with(|l| l.set(0));
    let r = f();
    let peak = PEAK.with(Cell::get).saturating_sub(base).max(0) as usize;
    (r, MemoryUse { peak, largest: LARGEST.with(Cell::get) })
}

// ----- corpus --------------------------------------------------------------

/// Valid inputs of one parser, each made of the same named parts, plus words
/// worth inserting (keywords of the format).
#[derive(Debug, Clone)]
pub struct Corpus {
    names: Vec<String>,
    samples: Vec<Vec<Vec<u8>>>,
    words: Vec<Vec<u8>>,
}

impl Corpus {
    /// A corpus whose inputs have one part per name (for example the files
    /// of a model folder).
    pub fn new<S: Into<String>>(names: impl IntoIterator<Item = S>) -> Self {
        Self { names: names.into_iter().map(Into::into).collect(), samples: Vec::new(), words: Vec::new() }
    }

    /// A corpus of one-part inputs.
    pub fn single(name: &str) -> Self {
        Self::new([name])
    }

    /// The part names.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The valid samples.
    pub fn samples(&self) -> &[Vec<Vec<u8>>] {
        &self.samples
    }

    /// Adds a one-part sample.
    pub fn sample(self, bytes: impl Into<Vec<u8>>) -> Self {
        self.sample_parts(vec![bytes.into()])
    }

    /// Adds a sample with one part per name. Panics on a wrong part count
    /// (a mistake in the test).
    pub fn sample_parts(mut self, parts: Vec<Vec<u8>>) -> Self {
        assert_eq!(parts.len(), self.names.len(), "a sample needs one part per name {:?}", self.names);
        self.samples.push(parts);
        self
    }

    /// Adds words (keywords, separators) that mutations insert or swap in.
    pub fn words<S: AsRef<[u8]>>(mut self, words: impl IntoIterator<Item = S>) -> Self {
        self.words.extend(words.into_iter().map(|w| w.as_ref().to_vec()));
        self
    }
}

// ----- mutations -----------------------------------------------------------

/// Integers that make counts, sizes and ids interesting (zero, one, sign and
/// width boundaries, counts that would need gigabytes).
const INTERESTING_INTS: [u64; 24] = [
    0,
    1,
    2,
    0x7f,
    0x80,
    0xff,
    0x100,
    0x7fff,
    0x8000,
    0xffff,
    0x1_0000,
    0x0fff_ffff,
    0x1000_0000,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_fffe,
    0xffff_ffff,
    1 << 32,
    1 << 40,
    1 << 62,
    i64::MAX as u64,
    1 << 63,
    u64::MAX - 1,
    u64::MAX,
];

/// Floats that break arithmetic.
const INTERESTING_FLOATS: [f64; 10] =
    [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0, 1e308, -1e308, f64::MIN_POSITIVE, 5e-324, 1e-300];

/// Single bytes that are boundaries or separators.
const INTERESTING_BYTES: [u8; 12] = [0, 0xff, 0x7f, 0x80, 0x01, b' ', b'\n', b'\r', b'\t', b'-', b'#', b','];

/// Tokens swapped into text formats: numbers at and beyond the types'
/// limits, non-finite spellings, separators.
const TEXT_TOKENS: [&str; 40] = [
    "-1",
    "0",
    "1",
    "-0",
    "2",
    "1e308",
    "-1e308",
    "1e309",
    "1e-400",
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "infinity",
    "18446744073709551616",
    "18446744073709551615",
    "-9223372036854775809",
    "9223372036854775807",
    "4294967296",
    "4294967295",
    "2147483648",
    "65536",
    "0.5",
    "1e-7",
    "0x10",
    "+1",
    "1_000",
    "99999999999999999999999999999999999999999999999999",
    "",
    "#",
    ",",
    ":",
    "=",
    "[",
    "]",
    "\"",
    " ",
    "\t",
    "\r\n",
];

/// Byte sequences that are not (or are unusual) UTF-8: lone continuation
/// and lead bytes, a surrogate, an over-long form, a BOM, NUL, non-ASCII
/// whitespace (NBSP, line separator) and a multi-byte letter.
const UTF8_GARBAGE: [&[u8]; 11] = [
    b"\x80",
    b"\xc3",
    b"\xed\xa0\x80",
    b"\xf4\x90\x80\x80",
    b"\xc0\xaf",
    b"\xef\xbb\xbf",
    b"\0",
    "\u{a0}".as_bytes(),
    "\u{2028}".as_bytes(),
    "\u{e9}".as_bytes(),
    b"\xff\xfe",
];

fn is_separator(b: u8) -> bool {
    b.is_ascii_whitespace() || matches!(b, b',' | b':' | b'=' | b'[' | b']' | b'"' | b'\'')
}

/// Half-open range of the token (run of non-separators) at `pos`, or an
/// empty range at `pos` when it is a separator.
fn token_at(data: &[u8], pos: usize) -> (usize, usize) {
    if data.get(pos).is_none_or(|&b| is_separator(b)) {
        return (pos, pos);
    }
    let mut start = pos;
    while start > 0 && !is_separator(data[start - 1]) {
        start -= 1;
    }
    let mut end = pos;
    while end < data.len() && !is_separator(data[end]) {
        end += 1;
    }
    (start, end)
}

/// Half-open range of the line holding `pos` (with its newline).
fn line_at(data: &[u8], pos: usize) -> (usize, usize) {
    let start = data[..pos].iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    let end = data[pos..].iter().position(|&b| b == b'\n').map_or(data.len(), |p| pos + p + 1);
    (start, end)
}

/// A random chunk `[start, end)` of `data` (non-empty data).
fn chunk(rng: &mut SplitMix64, len: usize) -> (usize, usize) {
    let start = rng.below(len);
    let max = (len - start).min(64);
    (start, start + 1 + rng.below(max))
}

/// Applies one random mutation to part `p` of `input`.
fn mutate_once(rng: &mut SplitMix64, corpus: &Corpus, input: &mut [Vec<u8>], p: usize) {
    let data = &mut input[p];
    let len = data.len();
    // Position for insertions (may be the end).
    let at = rng.below(len + 1);
    match rng.below(17) {
        // Bit flip.
        0 if len > 0 => {
            let i = rng.below(len);
            data[i] ^= 1 << rng.below(8);
        }
        // Byte set to a boundary value or a random one.
        1 if len > 0 => {
            let i = rng.below(len);
            data[i] = INTERESTING_BYTES[rng.below(INTERESTING_BYTES.len())];
        }
        2 if len > 0 => {
            let i = rng.below(len);
            data[i] = rng.next_u64() as u8;
        }
        // An interesting integer (1, 2, 4 or 8 bytes, either endianness)
        // over the bytes at a random offset: huge counts and sizes.
        3 if len > 0 => {
            let v = INTERESTING_INTS[rng.below(INTERESTING_INTS.len())];
            let width = 1 << rng.below(4);
            let (le, be) = (v.to_le_bytes(), v.to_be_bytes());
            let bytes = if rng.below(2) == 0 { &le[..width] } else { &be[8 - width..] };
            let i = rng.below(len);
            let n = bytes.len().min(len - i);
            data[i..i + n].copy_from_slice(&bytes[..n]);
        }
        // An interesting f64 over 8 bytes.
        4 if len >= 8 => {
            let v = INTERESTING_FLOATS[rng.below(INTERESTING_FLOATS.len())];
            let i = rng.below(len - 7);
            data[i..i + 8].copy_from_slice(&v.to_le_bytes());
        }
        // Truncation.
        5 => data.truncate(rng.below(len + 1)),
        // Random bytes inserted.
        6 => {
            let n = 1 + rng.below(16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            data.splice(at..at, bytes);
        }
        // A chunk deleted.
        7 if len > 0 => {
            let (s, e) = chunk(rng, len);
            data.drain(s..e);
        }
        // A chunk duplicated elsewhere.
        8 if len > 0 => {
            let (s, e) = chunk(rng, len);
            let c = data[s..e].to_vec();
            data.splice(at..at, c);
        }
        // Splice: the head of this part, the tail of the same part of
        // another sample.
        9 => {
            let other = &corpus.samples[rng.below(corpus.samples.len())][p];
            let from = rng.below(other.len() + 1);
            data.truncate(at);
            data.extend_from_slice(&other[from..]);
        }
        // Token replaced by an interesting number or separator.
        10 | 11 if len > 0 => {
            let (s, e) = token_at(data, rng.below(len));
            let tok = pick_token(rng, corpus);
            data.splice(s..e, tok);
        }
        // Token or word inserted.
        12 => {
            let tok = pick_token(rng, corpus);
            data.splice(at..at, tok);
        }
        // A very long run of one character (very long lines, numbers,
        // tokens).
        13 => {
            let c = [b'9', b'a', b' ', b'0', b',', b'.', b'\n', b'#'][rng.below(8)];
            let bits = 4 + rng.below(13);
            let n = 1 + rng.below(1 << bits);
            data.splice(at..at, std::iter::repeat_n(c, n));
        }
        // Line endings: one `\n` made `\r\n`, every one, or a stray `\r`.
        14 => match rng.below(3) {
            0 => {
                let mut out = Vec::with_capacity(len * 2);
                for &b in data.iter() {
                    if b == b'\n' {
                        out.push(b'\r');
                    }
                    out.push(b);
                }
                *data = out;
            }
            1 => data.insert(at, b'\r'),
            _ => {
                if let Some(i) = data.iter().skip(at).position(|&b| b == b'\n') {
                    data.insert(at + i, b'\r');
                }
            }
        },
        // UTF-8 garbage.
        15 => {
            let g = UTF8_GARBAGE[rng.below(UTF8_GARBAGE.len())];
            data.splice(at..at, g.iter().copied());
        }
        // A line repeated (many records, duplicate ids) or removed.
        16 if len > 0 => {
            let (s, e) = line_at(data, rng.below(len));
            if rng.below(4) == 0 {
                data.drain(s..e);
            } else {
                let line = data[s..e].to_vec();
                let most = if rng.below(8) == 0 { 2000 } else { 3 };
                let times = 1 + rng.below(most);
                let at = line_at(data, rng.below(len)).0;
                // Only what survives the final truncation is built (a long
                // line repeated 2,000 times would take gigabytes).
                let room = MAX_PART_LEN.saturating_sub(at);
                let mut rep = Vec::with_capacity((line.len() * times).min(room));
                for _ in 0..times {
                    if rep.len() >= room {
                        break;
                    }
                    rep.extend_from_slice(&line);
                }
                rep.truncate(room);
                data.splice(at..at, rep);
            }
        }
        // The mutation needed bytes the part lacks: insert a random byte.
        _ => data.insert(at, rng.next_u64() as u8),
    }
    data.truncate(MAX_PART_LEN);
}

fn pick_token(rng: &mut SplitMix64, corpus: &Corpus) -> Vec<u8> {
    if !corpus.words.is_empty() && rng.below(3) == 0 {
        corpus.words[rng.below(corpus.words.len())].clone()
    } else {
        TEXT_TOKENS[rng.below(TEXT_TOKENS.len())].as_bytes().to_vec()
    }
}

/// The RNG of input `index`: independent of every other input's.
fn input_rng(seed: u64, index: u64) -> SplitMix64 {
    let mut mix = SplitMix64::new(seed ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03));
    SplitMix64::new(mix.next_u64())
}

/// Input `index` of a run: the corpus samples unchanged first, then
/// mutations of random samples.
pub fn generate(corpus: &Corpus, seed: u64, index: u64) -> Vec<Vec<u8>> {
    let n = corpus.samples.len() as u64;
    if index < n {
        return corpus.samples[index as usize].clone();
    }
    let mut rng = input_rng(seed, index);
    let mut input = corpus.samples[rng.below(corpus.samples.len())].clone();
    let parts = input.len();
    let first = rng.below(parts);
    for k in 0..1 + rng.below(MAX_STACKED_MUTATIONS) {
        // Mostly one part per input, so that the others stay consistent and
        // the parser gets past them.
        let p = if k > 0 && rng.below(4) == 0 { rng.below(parts) } else { first };
        mutate_once(&mut rng, corpus, &mut input, p);
    }
    input
}

// ----- running -------------------------------------------------------------

/// What a fuzz run did.
#[derive(Debug, Clone)]
pub struct FuzzReport {
    /// The parser's name.
    pub name: String,
    /// The seed.
    pub seed: u64,
    /// Inputs run.
    pub inputs: u64,
    /// Inputs the parser accepted.
    pub accepted: u64,
    /// Inputs the parser rejected with an error.
    pub rejected: u64,
    /// Longest time of one input.
    pub max_time: Duration,
    /// Largest growth of live bytes during one input.
    pub max_peak_bytes: usize,
    /// Largest single allocation during an input.
    pub max_alloc_bytes: usize,
    /// Whether memory was measured (the counting allocator is installed).
    pub memory_checked: bool,
    /// Growth of this thread's live bytes over the whole run: what the
    /// parser (or the closure's state) kept, a leak when it grows with the
    /// number of inputs.
    pub retained_bytes: isize,
    /// Wall time of the whole run.
    pub wall: Duration,
}

impl fmt::Display for FuzzReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let rate = self.inputs as f64 / self.wall.as_secs_f64().max(1e-9);
        write!(
            f,
            "fuzz {}: {} inputs (seed {}), {} accepted, {} rejected, 0 failures; max {:.3} ms per input; ",
            self.name,
            self.inputs,
            self.seed,
            self.accepted,
            self.rejected,
            self.max_time.as_secs_f64() * 1e3,
        )?;
        if self.memory_checked {
            write!(
                f,
                "peak {:.1} KiB, largest allocation {:.1} KiB per input, {:.1} KiB retained after the run; ",
                self.max_peak_bytes as f64 / 1024.0,
                self.max_alloc_bytes as f64 / 1024.0,
                self.retained_bytes as f64 / 1024.0
            )?;
        } else {
            write!(f, "memory not measured (no counting allocator); ")?;
        }
        write!(f, "{:.1} s, {rate:.0} inputs/s", self.wall.as_secs_f64())
    }
}

fn env_u64(name: &str) -> Option<u64> {
    let v = std::env::var(name).ok()?;
    let v = v.trim().replace('_', "");
    Some(v.parse().unwrap_or_else(|_| panic!("{name}={v:?} is not a whole number")))
}

/// Where failing inputs are saved: `tmp/fuzz-failures` in the target folder
/// (the test executable lies in `<target>/<profile>/deps/`), else in the
/// system's temporary folder.
pub fn failure_dir() -> PathBuf {
    let target = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.ancestors().nth(3).map(Path::to_path_buf))
        .filter(|t| t.is_dir());
    target.map_or_else(std::env::temp_dir, |t| t.join("tmp")).join("fuzz-failures")
}

/// Saves an input's parts into their own folder; returns the folder.
fn save_input(name: &str, names: &[String], seed: u64, index: u64, input: &[Vec<u8>]) -> PathBuf {
    let dir = failure_dir().join(format!("{name}-seed{seed}-input{index}"));
    let _ = std::fs::create_dir_all(&dir);
    for (n, part) in names.iter().zip(input) {
        let file = n.replace(['/', '\\'], "_");
        let _ = std::fs::write(dir.join(file), part);
    }
    dir
}

/// The input running now, for the watchdog.
struct Running {
    index: u64,
    started: Instant,
    input: Arc<Vec<Vec<u8>>>,
}

/// Aborts the process when an input runs past [`HANG_ABORT`].
struct Watchdog {
    current: Arc<Mutex<Option<Running>>>,
    done: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Watchdog {
    fn start(name: &str, names: &[String], seed: u64) -> Self {
        let current: Arc<Mutex<Option<Running>>> = Arc::new(Mutex::new(None));
        let done = Arc::new(AtomicBool::new(false));
        let (c, d, name, names) = (current.clone(), done.clone(), name.to_string(), names.to_vec());
        let thread = std::thread::spawn(move || {
            while !d.load(Ordering::Relaxed) {
                std::thread::park_timeout(WATCHDOG_PERIOD);
                let guard = c.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(r) = guard.as_ref()
                    && r.started.elapsed() > HANG_ABORT
                {
                    let dir = save_input(&name, &names, seed, r.index, &r.input);
                    eprintln!(
                        "\nfuzz {name}: input {} has run for over {HANG_ABORT:?} (a hang); saved in {}; \
                         replay with {SEED_ENV}={seed} {ONLY_ENV}={}; aborting",
                        r.index,
                        dir.display(),
                        r.index
                    );
                    std::process::abort();
                }
            }
        });
        Self { current, done, thread: Some(thread) }
    }

    fn set(&self, running: Option<Running>) {
        *self.current.lock().unwrap_or_else(|e| e.into_inner()) = running;
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        self.done.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(non-string panic payload)".into())
}

/// Runs `target` on `default_iters` generated inputs (or [`ITERS_ENV`]) and
/// panics, with the input saved, at the first one that panics, takes longer
/// than [`TIME_LIMIT`] or allocates more than [`MEMORY_LIMIT`]. Also panics
/// when a corpus sample is rejected (the corpus must be valid, so that
/// mutations start deep in the parser). Prints and returns the counts.
pub fn fuzz<T, E: fmt::Display>(
    name: &str,
    corpus: &Corpus,
    default_iters: u64,
    mut target: impl FnMut(&[Vec<u8>]) -> Result<T, E>,
) -> FuzzReport {
    assert!(!corpus.samples.is_empty(), "fuzz {name}: the corpus is empty");
    let seed = env_u64(SEED_ENV).unwrap_or(DEFAULT_SEED);
    let range = match env_u64(ONLY_ENV) {
        Some(i) => i..i + 1,
        None => 0..env_u64(ITERS_ENV).unwrap_or(default_iters),
    };
    let memory_checked = counting_alloc_installed();
    let watchdog = Watchdog::start(name, &corpus.names, seed);
    let mut report = FuzzReport {
        name: name.to_string(),
        seed,
        inputs: 0,
        accepted: 0,
        rejected: 0,
        max_time: Duration::ZERO,
        max_peak_bytes: 0,
        max_alloc_bytes: 0,
        memory_checked,
        retained_bytes: 0,
        wall: Duration::ZERO,
    };
    let live_at_start = LIVE.with(Cell::get);
    let run_start = Instant::now();
    for index in range {
        let input = Arc::new(generate(corpus, seed, index));
        let mut run = || {
            watchdog.set(Some(Running { index, started: Instant::now(), input: input.clone() }));
            RUNNING.with(|r| r.set(Some((seed, index))));
            let started = Instant::now();
            let (outcome, mem) = measure_memory(|| {
                std::panic::catch_unwind(AssertUnwindSafe(|| match target(&input) {
                    Ok(_) => Ok(()),
                    Err(e) => Err(e.to_string()),
                }))
            });
            let elapsed = started.elapsed();
            RUNNING.with(|r| r.set(None));
            watchdog.set(None);
            (outcome, mem, elapsed)
        };
        let (outcome, mem, mut elapsed) = run();
        if elapsed > TIME_LIMIT && outcome.is_ok() {
            // On a shared machine a process can wait for a core for a long
            // time; a slow parser is slow again on the same input.
            elapsed = elapsed.min(run().2);
        }

        let fail = |why: String| -> ! {
            let dir = save_input(name, &corpus.names, seed, index, &input);
            panic!(
                "fuzz {name}: input {index} {why}; saved in {}; replay with {SEED_ENV}={seed} {ONLY_ENV}={index}",
                dir.display()
            )
        };
        let accepted = match outcome {
            Err(payload) => fail(format!("panicked: {}", panic_message(payload.as_ref()))),
            Ok(Ok(())) => true,
            Ok(Err(msg)) => {
                if index < corpus.samples.len() as u64 {
                    fail(format!("(an unchanged corpus sample) was rejected: {msg}"));
                }
                false
            }
        };
        if elapsed > TIME_LIMIT {
            fail(format!("took {elapsed:?} twice (limit {TIME_LIMIT:?})"));
        }
        if mem.peak > MEMORY_LIMIT || mem.largest > MEMORY_LIMIT {
            fail(format!(
                "allocated {} bytes at its peak, {} in one request (limit {MEMORY_LIMIT})",
                mem.peak, mem.largest
            ));
        }
        report.inputs += 1;
        if accepted {
            report.accepted += 1;
        } else {
            report.rejected += 1;
        }
        report.max_time = report.max_time.max(elapsed);
        report.max_peak_bytes = report.max_peak_bytes.max(mem.peak);
        report.max_alloc_bytes = report.max_alloc_bytes.max(mem.largest);
    }
    drop(watchdog);
    report.wall = run_start.elapsed();
    report.retained_bytes = LIVE.with(Cell::get).saturating_sub(live_at_start);
    assert!(
        report.retained_bytes <= MEMORY_LIMIT as isize,
        "fuzz {name}: {} bytes stayed allocated after the run (a leak?): {report}",
        report.retained_bytes
    );
    eprintln!("{report}");
    report
}

// ----- files ---------------------------------------------------------------

/// A memory-backed temporary file system on Linux.
const MEMORY_TMP: &str = "/dev/shm";

/// A temporary folder for parsers that read files: parts are written to
/// files inside it, skipping writes of unchanged content (most inputs change
/// one file of several).
pub struct Scratch {
    dir: tempfile::TempDir,
    written: HashMap<PathBuf, Option<Vec<u8>>>,
}

impl Scratch {
    /// A new empty folder (removed on drop): in `/dev/shm` when it is
    /// usable, since rewriting a file there is an order of magnitude faster
    /// than on a disk file system (see docs/benchmarks.md, "Fuzzing"), else
    /// in the system's temporary folder. Panics when neither is usable (test
    /// helper).
    pub fn new() -> Self {
        let builder = tempfile::Builder::new().prefix("colslam-fuzz-").clone();
        let dir = builder.tempdir_in(MEMORY_TMP).or_else(|_| builder.tempdir()).expect("create a temporary folder");
        Self { dir, written: HashMap::new() }
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Makes `rel` (relative to the folder) hold `bytes`, or not exist for
    /// `None`; returns its path. Panics on file-system errors.
    pub fn put(&mut self, rel: &str, bytes: Option<&[u8]>) -> PathBuf {
        let path = self.dir.path().join(rel);
        if self.written.get(&path).map(Option::as_deref) == Some(bytes) {
            return path;
        }
        match bytes {
            Some(b) => {
                if let Some(parent) = path.parent() {
                    std::fs::create_dir_all(parent).expect("create a scratch folder");
                }
                std::fs::write(&path, b).unwrap_or_else(|e| panic!("write {}: {e}", path.display()));
            }
            None => {
                if let Err(e) = std::fs::remove_file(&path)
                    && e.kind() != std::io::ErrorKind::NotFound
                {
                    panic!("remove {}: {e}", path.display());
                }
            }
        }
        self.written.insert(path.clone(), bytes.map(<[u8]>::to_vec));
        path
    }
}

impl Default for Scratch {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corpus() -> Corpus {
        Corpus::new(["a.txt", "b.bin"])
            .sample_parts(vec![b"1 2 3\n4 5 6\n".to_vec(), vec![1, 0, 0, 0, 9, 9]])
            .sample_parts(vec![b"# c\nx: 1\n".to_vec(), vec![]])
            .words(["model", "width"])
    }

    #[test]
    fn inputs_depend_on_seed_and_index_only() {
        let c = corpus();
        assert_eq!(generate(&c, 5, 0), c.samples()[0]);
        assert_eq!(generate(&c, 5, 1), c.samples()[1]);
        let a: Vec<_> = (2..200).map(|i| generate(&c, 5, i)).collect();
        let b: Vec<_> = (2..200).rev().map(|i| generate(&c, 5, i)).collect();
        assert!(a.iter().eq(b.iter().rev()));
        let other: Vec<_> = (2..200).map(|i| generate(&c, 6, i)).collect();
        assert_ne!(a, other);
        // Mutations change something most of the time.
        let changed = a.iter().filter(|x| !c.samples().contains(x)).count();
        assert!(changed > 150, "{changed}");
    }

    #[test]
    fn parts_stay_bounded() {
        let c = corpus();
        for i in 0..2000 {
            let x = generate(&c, 1, i);
            assert_eq!(x.len(), 2);
            assert!(x.iter().all(|p| p.len() <= MAX_PART_LEN));
        }
    }

    #[test]
    fn generating_an_input_takes_memory_bounded_by_the_part_limit() {
        // One long line (no newline): repeating it must not build gigabytes.
        let c = Corpus::single("a").sample(vec![b'x'; MAX_PART_LEN / 2]).sample(b"1 2\n".to_vec());
        assert!(counting_alloc_installed());
        for i in 0..3000 {
            let (x, mem) = measure_memory(|| generate(&c, 3, i));
            assert!(x[0].len() <= MAX_PART_LEN);
            assert!(mem.largest <= 4 * MAX_PART_LEN, "input {i}: {mem:?}");
        }
    }

    #[test]
    fn counts_accepted_and_rejected() {
        let c = corpus();
        let r =
            fuzz("selftest", &c, 300, |parts| std::str::from_utf8(&parts[0]).map(str::len).map_err(|e| e.to_string()));
        assert_eq!(r.inputs, 300);
        assert_eq!(r.accepted + r.rejected, 300);
        assert!(r.accepted > 0 && r.rejected > 0, "{r}");
    }

    #[test]
    fn a_panic_fails_with_the_input_saved() {
        let c = corpus();
        let err = std::panic::catch_unwind(|| {
            fuzz("selftest-panic", &c, 50, |parts| -> Result<(), String> {
                assert!(parts[1].len() < 7, "long part");
                Ok(())
            })
        })
        .expect_err("a panicking target fails the run");
        let msg = panic_message(err.as_ref());
        assert!(msg.contains("panicked: long part") && msg.contains(ONLY_ENV), "{msg}");
        let dir = msg.split("saved in ").nth(1).and_then(|s| s.split(';').next()).expect("a saved path");
        assert!(Path::new(dir).join("b.bin").is_file(), "{dir}");
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn tokens_and_lines() {
        let d = b"ab cd,ef\ngh";
        assert_eq!(token_at(d, 4), (3, 5));
        assert_eq!(token_at(d, 2), (2, 2));
        assert_eq!(line_at(d, 4), (0, 9));
        assert_eq!(line_at(d, 10), (9, 11));
        let mut buf = [0u8; 20];
        assert_eq!(decimal(0, &mut buf), b"0");
        assert_eq!(decimal(u64::MAX, &mut buf), b"18446744073709551615");
    }

    #[test]
    fn scratch_writes_and_removes() {
        let mut s = Scratch::new();
        let p = s.put("x/y.txt", Some(b"hi"));
        assert_eq!(std::fs::read(&p).unwrap(), b"hi");
        s.put("x/y.txt", None);
        assert!(!p.exists());
        s.put("x/y.txt", None);
    }
}
