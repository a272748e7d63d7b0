//! `colslam bench features`: our ORB extractor and Hamming matcher against
//! OpenCV's ORB and BFMatcher (issue 3), side by side in one run on the real
//! frames of the TUM fr1/rpy subset.
//!
//! * Extraction: median over frames of the best of `--repeats` runs, per
//!   640x480 frame, at 1000 and 2000 keypoints; ours in a local rayon pool of
//!   1 thread (OpenCV runs with `cv2.setNumThreads(1)`) and of 2 threads;
//!   `--rounds` rounds alternate ours and OpenCV; each frame keeps its best
//!   time over all rounds and repeats, and the median over frames is
//!   reported (the shared machine's load comes in bursts). OpenCV runs at
//!   FAST threshold 7 so that it returns the requested keypoint count (at
//!   its default of 20 it falls short on these frames; reported too).
//! * Matching: our 2000 x 2000 descriptors of consecutive frames, handed to
//!   OpenCV too so that both match identical sets, mutual nearest
//!   neighbours, no ratio or distance filter on either side (what
//!   `BFMatcher(NORM_HAMMING, crossCheck=True)` does); ours on 2 threads.
//! * Quality: matches of consecutive frames at 1000 keypoints scored for
//!   both libraries by the same Sampson check against the ground-truth
//!   relative pose (undistorted with the dataset's FULL_OPENCV camera).
//!
//! The OpenCV side is `scripts/peers/bench_features.py`, run by the peer
//! venv's interpreter ([`colslam_testutil::find_peer_python`]: `COLSLAM_PYTHON`,
//! else `.venv/bin/python` here or above, else the workspace's).

use crate::stdout::outln;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use colslam_camera::Camera;
use colslam_estimators::sampson_error_sq;
use colslam_eval::Trajectory;
use colslam_features::{Features, NnMatcher, NnMatcherOptions, OrbExtractor, OrbOptions};
use colslam_geometry::{Mat3, Rigid3, Vec2, Vec3};
use colslam_image::Image;
use serde_json::{Value, json};

// Shared with the other layer benchmarks, which import them from here.
pub(crate) use crate::median;
use colslam_testutil::{find_data_dir, find_peer_python, workspace_root};

/// Dataset the benchmark runs on.
const DATASET: &str = "tum_fr1_rpy_sub";
/// Keypoint counts timed.
const TIMING_FEATURES: [usize; 2] = [1000, 2000];
/// Keypoint count of the match-quality pairs (ORB-SLAM's default for VGA).
const QUALITY_FEATURES: usize = 1000;
/// Threads of the "multi-threaded" runs (the project machine has 2 cores).
const MULTI_THREADS: usize = 2;
/// Sampson error (pixels) under which a match agrees with the ground truth.
const SAMPSON_MAX_PX: f64 = 1.0;
/// OpenCV's FAST threshold for the headline runs: ORB-SLAM's fallback
/// threshold (our `min_fast_threshold`), so that OpenCV returns the requested
/// keypoint count on these blurry frames (at its default of 20 it returns
/// about 1600 of 2000).
const OPENCV_FAST_THRESHOLD_MATCHED: u8 = 7;
/// OpenCV's default FAST threshold, reported too.
const OPENCV_FAST_THRESHOLD_DEFAULT: u8 = 20;
/// Largest gap (s) between an image stamp and its ground-truth pose.
const MAX_STAMP_GAP: f64 = 0.02;
/// XFeat keypoints per frame in the benchmark (as ORB's larger setting).
const XFEAT_FEATURES: usize = 2000;

/// Arguments of `bench features`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Number of consecutive frames used (from the start of the sequence).
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// Timed runs per frame; the best is kept (filters scheduler noise).
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// Rounds alternating ours and OpenCV; each frame keeps its best time.
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
}

/// Best of `repeats` timings of `f`, in ms, and the last result.
fn best_ms<T>(repeats: usize, mut f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let r = f()?;
        best = best.min(t0.elapsed().as_secs_f64() * 1e3);
        last = Some(r);
    }
    // At least one iteration ran (repeats.max(1)).
    last.map(|r| (best, r)).ok_or_else(|| anyhow!("no timed run"))
}

/// The machine: core count, CPU model and load average.
pub(crate) fn machine() -> Value {
    let nproc = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into());
    let load = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|t| t.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default();
    json!({ "nproc": nproc, "cpu_model": cpu, "loadavg": load })
}

/// A peer script under `scripts/peers/` (current directory or workspace).
pub(crate) fn peer_script(name: &str) -> Result<PathBuf> {
    let rel = Path::new("scripts/peers").join(name);
    [rel.clone(), workspace_root().join(&rel)]
        .into_iter()
        .find(|p| p.is_file())
        .ok_or_else(|| anyhow!("peer script {} not found (run from the workspace root)", rel.display()))
}

/// Runs a peer script on a JSON input file and parses the JSON it prints.
pub(crate) fn run_peer(script: &str, input: &Value) -> Result<Value> {
    let py = find_peer_python()?;
    let script = peer_script(script)?;
    let dir = std::env::temp_dir().join(format!("colslam-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("input.json");
    std::fs::write(&path, serde_json::to_vec(input)?).with_context(|| format!("cannot write {}", path.display()))?;
    let out = Command::new(&py)
        .arg(&script)
        .arg(&path)
        .output()
        .with_context(|| format!("cannot start {} (run scripts/setup-peers.sh)", py.display()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = out?;
    if !out.status.success() {
        bail!(
            "{} {} failed (run scripts/setup-peers.sh if a module is missing):\n{}",
            py.display(),
            script.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    serde_json::from_slice(&out.stdout).with_context(|| format!("{} printed no valid JSON", script.display()))
}

/// One frame of the dataset.
struct Frame {
    path: PathBuf,
    gray: Image,
    /// `world_from_cam` from the ground truth.
    world_from_cam: Rigid3,
}

/// Reads `rgb.txt`, the first `n` images and their ground-truth poses.
fn load_frames(dir: &Path, n: usize) -> Result<Vec<Frame>> {
    let list = dir.join("rgb.txt");
    let text = std::fs::read_to_string(&list).with_context(|| format!("cannot read {}", list.display()))?;
    let gt_path = dir.join("groundtruth.txt");
    let gt = Trajectory::read_tum(&gt_path).with_context(|| format!("cannot read {}", gt_path.display()))?;
    let mut frames = Vec::new();
    for (lineno, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if frames.len() == n {
            break;
        }
        let mut it = line.split_whitespace();
        let (Some(stamp), Some(rel)) = (it.next(), it.next()) else {
            bail!("{}:{}: expected `timestamp path`", list.display(), lineno + 1);
        };
        let stamp: f64 =
            stamp.parse().map_err(|_| anyhow!("{}:{}: bad timestamp `{stamp}`", list.display(), lineno + 1))?;
        let (gap, pose) = gt
            .stamps
            .iter()
            .zip(&gt.poses)
            .map(|(s, p)| ((s - stamp).abs(), *p))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .ok_or_else(|| anyhow!("{} is empty", gt_path.display()))?;
        if gap > MAX_STAMP_GAP {
            bail!("{}: no ground-truth pose within {MAX_STAMP_GAP} s of image stamp {stamp}", gt_path.display());
        }
        let path = dir.join(rel);
        let gray = Image::read(&path).with_context(|| format!("cannot read {}", path.display()))?.to_gray();
        frames.push(Frame { path, gray, world_from_cam: pose });
    }
    if frames.len() < 2 {
        bail!("{} lists fewer than 2 frames", list.display());
    }
    Ok(frames)
}

/// Cross product matrix `[t]x`.
fn skew(t: &Vec3) -> Mat3 {
    Mat3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0)
}

/// Fundamental matrix between the undistorted (pinhole) images of the two
/// frames from the ground truth: `F = K^-T [t]x R K^-1` with
/// `cam2_from_cam1 = (world_from_cam2)^-1 * world_from_cam1`.
pub(crate) fn gt_fundamental(k: &Mat3, world_from_cam1: &Rigid3, world_from_cam2: &Rigid3) -> Option<Mat3> {
    let rel = world_from_cam2.inverse() * *world_from_cam1;
    let e = skew(&rel.translation) * rel.rotation_matrix();
    let k_inv = k.try_inverse()?;
    Some(k_inv.transpose() * e * k_inv)
}

/// Undistorted pinhole pixel of a distorted pixel (OpenCV convention), or
/// `None` when undistortion fails.
fn undistort(cam: &Camera, k: &Mat3, p: [f64; 2]) -> Option<Vec2> {
    let n = cam.cam_from_img(&Vec2::new(p[0], p[1]))?;
    Some(Vec2::new(k[(0, 0)] * n.x + k[(0, 2)], k[(1, 1)] * n.y + k[(1, 2)]))
}

/// Pyramid levels tallied separately in the per-octave breakdown.
const OCTAVES: usize = 8;

/// Per-octave (of the first keypoint) tallies: `[consistent, total]`.
type OctaveTally = [[usize; 2]; OCTAVES];

/// Counts matches within [`SAMPSON_MAX_PX`] of the ground-truth epipolar
/// geometry: (consistent, total). Keypoints are `[x, y, octave]`; the
/// per-octave counts are added to `by_octave`.
fn score_pair(
    cam: &Camera,
    k: &Mat3,
    f: &Mat3,
    kp1: &[[f64; 3]],
    kp2: &[[f64; 3]],
    m: &[(usize, usize)],
    by_octave: &mut OctaveTally,
) -> (usize, usize) {
    let mut good = 0;
    for (a, b) in m {
        let (Some(p1), Some(p2)) = (kp1.get(*a), kp2.get(*b)) else { continue };
        let ok = match (undistort(cam, k, [p1[0], p1[1]]), undistort(cam, k, [p2[0], p2[1]])) {
            // Sampson distance in pixels (first-order geometric error).
            (Some(u1), Some(u2)) => sampson_error_sq(f, &u1, &u2).sqrt() < SAMPSON_MAX_PX,
            _ => false,
        };
        good += usize::from(ok);
        // Octaves are small non-negative integers; clamp into the table.
        let o = (p1[2].max(0.0) as usize).min(OCTAVES - 1);
        if let Some(t) = by_octave.get_mut(o) {
            t[0] += usize::from(ok);
            t[1] += 1;
        }
    }
    (good, m.len())
}

/// XFeat measured on the same frames: extraction ms per frame (2 threads),
/// mutual-nearest-neighbour matching ms per pair, and the same
/// ground-truth consistency figures as ORB. `Err` carries why it could not
/// run (typically: the weights are not installed).
fn time_xfeat(
    frames: &[Frame],
    cam: &Camera,
    k: &Mat3,
    fs: &[Mat3],
    multi: &rayon::ThreadPool,
) -> std::result::Result<Value, String> {
    use colslam_features::{FeatureExtractor, Matcher};
    let xfeat = colslam_xfeat::XFeat::new(colslam_xfeat::XFeatOptions {
        top_k: XFEAT_FEATURES,
        ..colslam_xfeat::XFeatOptions::default()
    })
    .map_err(|e| e.to_string())?;
    let matcher =
        colslam_xfeat::MnnCosineMatcher::new(colslam_xfeat::MnnCosineOptions::default()).map_err(|e| e.to_string())?;
    let mut extract_ms = Vec::new();
    let mut feats = Vec::new();
    for f in frames {
        let t = Instant::now();
        let out = multi.install(|| xfeat.extract(&f.gray)).map_err(|e| e.to_string())?;
        extract_ms.push(1e3 * t.elapsed().as_secs_f64());
        feats.push(out);
    }
    let (mut match_ms, mut good, mut total) = (Vec::new(), 0usize, 0usize);
    for (w, f) in feats.windows(2).zip(fs) {
        let t = Instant::now();
        let m = multi.install(|| matcher.match_features(&w[0], &w[1])).map_err(|e| e.to_string())?;
        match_ms.push(1e3 * t.elapsed().as_secs_f64());
        let pairs: Vec<(usize, usize)> = m.iter().map(|m| (m.query as usize, m.train as usize)).collect();
        let (g, n) = score_pair(cam, k, f, &points(&w[0]), &points(&w[1]), &pairs, &mut OctaveTally::default());
        good += g;
        total += n;
    }
    let pairs = fs.len().max(1) as f64;
    Ok(json!({
        "top_k": XFEAT_FEATURES,
        "extract_ms": median(&extract_ms),
        "match_ms": median(&match_ms),
        "keypoints_mean": feats.iter().map(|f| f.len() as f64).sum::<f64>() / feats.len().max(1) as f64,
        "gt_consistent_matches": good as f64 / pairs,
        "gt_consistent_ratio": if total > 0 { good as f64 / total as f64 } else { f64::NAN },
    }))
}

/// Per-octave shares as JSON (`null` for empty octaves).
fn octave_json(t: &OctaveTally) -> Value {
    json!(
        t.iter()
            .map(|[g, n]| if *n > 0 { json!({"share": *g as f64 / *n as f64, "matches": n}) } else { Value::Null })
            .collect::<Vec<_>>()
    )
}

fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("cannot build a rayon pool")
}

fn binary(f: &Features) -> Result<&[[u64; 4]]> {
    match &f.descriptors {
        colslam_features::Descriptors::Binary(d) => Ok(d),
        colslam_features::Descriptors::Float { .. } => bail!("ORB returned float descriptors"),
    }
}

fn points(f: &Features) -> Vec<[f64; 3]> {
    f.keypoints.iter().map(|k| [f64::from(k.x), f64::from(k.y), f64::from(k.octave)]).collect()
}

fn json_points(v: &Value) -> Vec<[f64; 3]> {
    v.as_array()
        .map(|a| {
            a.iter()
                .map(|p| {
                    let c = |i: usize| p.get(i).and_then(Value::as_f64).unwrap_or(f64::NAN);
                    [c(0), c(1), c(2)]
                })
                .collect()
        })
        .unwrap_or_default()
}

fn json_matches(v: &Value) -> Vec<(usize, usize)> {
    v.as_array()
        .map(|a| a.iter().filter_map(|m| Some((m[0].as_u64()? as usize, m[1].as_u64()? as usize))).collect())
        .unwrap_or_default()
}

/// Element-wise minimum of two per-frame timing lists, into `acc`.
fn min_into(acc: &mut [f64], other: &[f64]) {
    for (a, b) in acc.iter_mut().zip(other) {
        *a = a.min(*b);
    }
}

/// Our timings of one round, and the features they produced.
struct OurTiming {
    /// `orb_ms_{n}_{1t|2t}`: per frame, the best-of-repeats time (ms).
    orb_ms: std::collections::BTreeMap<String, Vec<f64>>,
    /// Mean keypoint count per frame, by requested count.
    mean_kp: serde_json::Map<String, Value>,
    /// Matching 2000 x 2000, per pair, 1 and 2 threads (ms).
    match_ms_1t: Vec<f64>,
    match_ms_2t: Vec<f64>,
    /// Features at 2000 and at [`QUALITY_FEATURES`] keypoints, per frame.
    feats_2000: Vec<Features>,
    feats_quality: Vec<Features>,
}

impl OurTiming {
    /// Keeps, frame by frame, the smaller of each timing.
    fn merge_min(&mut self, other: &OurTiming) {
        for (k, v) in &other.orb_ms {
            let e = self.orb_ms.entry(k.clone()).or_insert_with(|| v.clone());
            min_into(e, v);
        }
        min_into(&mut self.match_ms_1t, &other.match_ms_1t);
        min_into(&mut self.match_ms_2t, &other.match_ms_2t);
    }
}

/// Times our extraction (1 and [`MULTI_THREADS`] threads) and matching.
fn time_ours(
    frames: &[Frame],
    repeats: usize,
    one: &rayon::ThreadPool,
    multi: &rayon::ThreadPool,
    matcher: &NnMatcher,
) -> Result<OurTiming> {
    let first = frames.first().ok_or_else(|| anyhow!("no frames"))?;
    let mut t = OurTiming {
        orb_ms: Default::default(),
        mean_kp: Default::default(),
        match_ms_1t: Vec::new(),
        match_ms_2t: Vec::new(),
        feats_2000: Vec::new(),
        feats_quality: Vec::new(),
    };
    for &n in &TIMING_FEATURES {
        let orb = OrbExtractor::new(OrbOptions { n_features: n, ..OrbOptions::default() })?;
        for (label, p) in [("1t", one), ("2t", multi)] {
            let mut times = Vec::with_capacity(frames.len());
            let mut feats = Vec::with_capacity(frames.len());
            // Warm-up (page faults, pool start).
            p.install(|| orb.extract_with_report(&first.gray))?;
            for f in frames {
                let (ms, (fe, _)) = best_ms(repeats, || Ok(p.install(|| orb.extract_with_report(&f.gray))?))?;
                times.push(ms);
                feats.push(fe);
            }
            t.orb_ms.insert(format!("orb_ms_{n}_{label}"), times);
            if label == "1t" {
                let mean = feats.iter().map(|f| f.len() as f64).sum::<f64>() / feats.len().max(1) as f64;
                t.mean_kp.insert(n.to_string(), json!(mean));
                if n == 2000 {
                    t.feats_2000 = feats;
                } else if n == QUALITY_FEATURES {
                    t.feats_quality = feats;
                }
            }
        }
    }
    let mut match_times = [Vec::new(), Vec::new()];
    for w in t.feats_2000.windows(2) {
        let (a, b) = (binary(&w[0])?, binary(&w[1])?);
        for (slot, p) in [(0, one), (1, multi)] {
            let (ms, _) = best_ms(repeats, || Ok(p.install(|| matcher.match_binary(a, b))))?;
            match_times[slot].push(ms);
        }
    }
    let [m1, m2] = match_times;
    t.match_ms_1t = m1;
    t.match_ms_2t = m2;
    Ok(t)
}

/// Runs `bench features`.
pub fn run(args: &Args, quiet: bool) -> Result<()> {
    if args.rounds == 0 || args.repeats == 0 {
        bail!("--rounds and --repeats must be at least 1");
    }
    if args.frames < 2 {
        bail!("--frames must be at least 2, got {}", args.frames);
    }
    let dir = find_data_dir()?.join(DATASET);
    if !dir.is_dir() {
        bail!("dataset {} not found (set COLSLAM_DATA)", dir.display());
    }
    let cam_path = dir.join("camera.yaml");
    let cam = colslam_camera::file::read_camera_file(&cam_path)
        .with_context(|| format!("cannot read camera {}", cam_path.display()))?;
    let k = cam.calibration_matrix();
    let frames = load_frames(&dir, args.frames)?;
    if !quiet && !args.json {
        eprintln!("bench features: {} frames of {}", frames.len(), dir.display());
    }

    let one = pool(1)?;
    let multi = pool(MULTI_THREADS)?;
    // Mutual nearest neighbours without ratio or distance filter, as
    // BFMatcher(NORM_HAMMING, crossCheck=True).
    let bf_like =
        NnMatcher::new(NnMatcherOptions { cross_check: true, max_ratio: 1.0, max_hamming: 256, ..Default::default() })?;
    let mut ours = time_ours(&frames, args.repeats, &one, &multi, &bf_like)?;

    // Ours: match quality at QUALITY_FEATURES keypoints.
    let default_nn = NnMatcher::new(NnMatcherOptions::default())?;
    let (mut good, mut total, mut good_def, mut total_def) = (0usize, 0usize, 0usize, 0usize);
    let mut our_octaves = OctaveTally::default();
    let mut fs = Vec::new();
    for (w, fr) in ours.feats_quality.windows(2).zip(frames.windows(2)) {
        let f = gt_fundamental(&k, &fr[0].world_from_cam, &fr[1].world_from_cam)
            .ok_or_else(|| anyhow!("{}: calibration matrix is singular", cam_path.display()))?;
        let (a, b) = (binary(&w[0])?, binary(&w[1])?);
        let (p1, p2) = (points(&w[0]), points(&w[1]));
        let m: Vec<(usize, usize)> =
            multi.install(|| bf_like.match_binary(a, b)).iter().map(|m| (m.query as usize, m.train as usize)).collect();
        let (g, t) = score_pair(&cam, &k, &f, &p1, &p2, &m, &mut our_octaves);
        good += g;
        total += t;
        let md: Vec<(usize, usize)> =
            default_nn.match_binary(a, b).iter().map(|m| (m.query as usize, m.train as usize)).collect();
        let (g, t) = score_pair(&cam, &k, &f, &p1, &p2, &md, &mut OctaveTally::default());
        good_def += g;
        total_def += t;
        fs.push(f);
    }
    let pairs = fs.len().max(1) as f64;

    // OpenCV, same frames; matching timed on our own 2000-keypoint
    // descriptors so that both libraries match identical sets.
    let desc_dir = std::env::temp_dir().join(format!("colslam-bench-desc-{}", std::process::id()));
    std::fs::create_dir_all(&desc_dir).with_context(|| format!("cannot create {}", desc_dir.display()))?;
    let mut desc_paths = Vec::new();
    for (i, f) in ours.feats_2000.iter().enumerate() {
        // Little-endian words give OpenCV's byte order (see Descriptors).
        let bytes: Vec<u8> = binary(f)?.iter().flat_map(|d| d.iter().flat_map(|w| w.to_le_bytes())).collect();
        let path = desc_dir.join(format!("desc_{i:04}.bin"));
        std::fs::write(&path, bytes).with_context(|| format!("cannot write {}", path.display()))?;
        desc_paths.push(path.display().to_string());
    }
    let input = json!({
        "images": frames.iter().map(|f| f.path.display().to_string()).collect::<Vec<_>>(),
        "timing_features": TIMING_FEATURES,
        "fast_thresholds": [OPENCV_FAST_THRESHOLD_MATCHED, OPENCV_FAST_THRESHOLD_DEFAULT],
        "quality_features": QUALITY_FEATURES,
        "repeats": args.repeats,
        "match_threads": MULTI_THREADS,
        "descriptors": desc_paths,
    });
    // Rounds alternate ours and OpenCV; every timing keeps its best round,
    // so that a burst of load from other processes does not land on one
    // side only.
    let frame_ms = |cv: &Value, th: u8, n: usize| -> Result<Vec<f64>> {
        let v = cv["extract_frame_ms"][th.to_string()][n.to_string()]
            .as_array()
            .ok_or_else(|| anyhow!("peer output lacks extract_frame_ms.{th}.{n}"))?;
        Ok(v.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect())
    };
    let pair_ms = |cv: &Value| -> Result<Vec<f64>> {
        let v = cv["match_pair_ms"].as_array().ok_or_else(|| anyhow!("peer output lacks match_pair_ms"))?;
        Ok(v.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect())
    };
    // Per-frame (per-pair) best over rounds: [fast 7 x 1000, fast 7 x 2000,
    // fast 20 x 1000, fast 20 x 2000, matching].
    let mut cv_best: Vec<Vec<f64>> = Vec::new();
    let mut cv = Value::Null;
    let mut peer_error = None;
    for round in 0..args.rounds {
        if round > 0 {
            let t = time_ours(&frames, args.repeats, &one, &multi, &bf_like)?;
            ours.merge_min(&t);
        }
        match run_peer("bench_features.py", &input) {
            Ok(v) => cv = v,
            Err(e) => {
                peer_error = Some(e);
                break;
            }
        }
        let now = vec![
            frame_ms(&cv, OPENCV_FAST_THRESHOLD_MATCHED, 1000)?,
            frame_ms(&cv, OPENCV_FAST_THRESHOLD_MATCHED, 2000)?,
            frame_ms(&cv, OPENCV_FAST_THRESHOLD_DEFAULT, 1000)?,
            frame_ms(&cv, OPENCV_FAST_THRESHOLD_DEFAULT, 2000)?,
            pair_ms(&cv)?,
        ];
        if cv_best.is_empty() {
            cv_best = now;
        } else {
            for (b, n) in cv_best.iter_mut().zip(&now) {
                min_into(b, n);
            }
        }
    }
    let _ = std::fs::remove_dir_all(&desc_dir);
    if let Some(e) = peer_error {
        return Err(e);
    }
    let cv_med = |i: usize| cv_best.get(i).map(|v| median(v)).unwrap_or(f64::NAN);
    let (cv_ms_1000, cv_ms_2000, cv_def_1000, cv_def_2000, cv_match) =
        (cv_med(0), cv_med(1), cv_med(2), cv_med(3), cv_med(4));
    let our_counts: Vec<usize> = ours
        .feats_2000
        .windows(2)
        .map(|w| Ok(bf_like.match_binary(binary(&w[0])?, binary(&w[1])?).len()))
        .collect::<Result<_>>()?;
    let cv_counts: Vec<u64> =
        cv["match_counts"].as_array().map(|a| a.iter().filter_map(Value::as_u64).collect()).unwrap_or_default();
    let same_counts =
        our_counts.len() == cv_counts.len() && our_counts.iter().zip(&cv_counts).all(|(a, b)| *a as u64 == *b);
    let cv_quality = |th: u8, by_octave: &mut OctaveTally| -> Result<(usize, usize)> {
        let pairs = cv["pairs"][th.to_string()].as_array().ok_or_else(|| anyhow!("peer output lacks pairs.{th}"))?;
        if pairs.len() != fs.len() {
            bail!("peer returned {} pairs, expected {}", pairs.len(), fs.len());
        }
        let (mut g, mut t) = (0usize, 0usize);
        for (p, f) in pairs.iter().zip(&fs) {
            let (a, b) = score_pair(
                &cam,
                &k,
                f,
                &json_points(&p["kp1"]),
                &json_points(&p["kp2"]),
                &json_matches(&p["matches"]),
                by_octave,
            );
            g += a;
            t += b;
        }
        Ok((g, t))
    };
    let mut cv_octaves = OctaveTally::default();
    let (cv_good, cv_total) = cv_quality(OPENCV_FAST_THRESHOLD_MATCHED, &mut cv_octaves)?;
    let (cv_def_good, cv_def_total) = cv_quality(OPENCV_FAST_THRESHOLD_DEFAULT, &mut OctaveTally::default())?;

    let xfeat = time_xfeat(&frames, &cam, &k, &fs, &multi);
    let (xfeat_ms, xfeat_detail) = match &xfeat {
        Ok(v) => (v["extract_ms"].clone(), v.clone()),
        Err(e) => (Value::Null, json!({ "not_run": e })),
    };
    let ratio = |g: usize, t: usize| if t > 0 { g as f64 / t as f64 } else { f64::NAN };
    let o = |key: &str| ours.orb_ms.get(key).map(|v| median(v)).unwrap_or(f64::NAN);
    let result = json!({
        "dataset": DATASET,
        "frames": frames.len(),
        "pairs": fs.len(),
        "repeats": args.repeats,
        "orb_ms_1000": o("orb_ms_1000_1t"),
        "orb_ms_2000": o("orb_ms_2000_1t"),
        "orb_ms_1000_2threads": o("orb_ms_1000_2t"),
        "orb_ms_2000_2threads": o("orb_ms_2000_2t"),
        "opencv_orb_ms_1000": cv_ms_1000,
        "opencv_orb_ms_2000": cv_ms_2000,
        "orb_keypoints_mean": ours.mean_kp,
        "rounds": args.rounds,
        "opencv_orb_keypoints_mean": cv["num_keypoints"][OPENCV_FAST_THRESHOLD_MATCHED.to_string()],
        "opencv_fast_threshold": OPENCV_FAST_THRESHOLD_MATCHED,
        "opencv_default_orb_ms_1000": cv_def_1000,
        "opencv_default_orb_ms_2000": cv_def_2000,
        "opencv_default_orb_keypoints_mean": cv["num_keypoints"][OPENCV_FAST_THRESHOLD_DEFAULT.to_string()],
        "opencv_default_gt_consistent_matches": cv_def_good as f64 / pairs,
        "opencv_default_gt_consistent_ratio": ratio(cv_def_good, cv_def_total),
        "match_counts_identical": same_counts,
        "match_ms_2000": median(&ours.match_ms_2t),
        "match_ms_2000_1thread": median(&ours.match_ms_1t),
        "opencv_match_ms_2000": cv_match,
        "quality_features": QUALITY_FEATURES,
        "sampson_max_px": SAMPSON_MAX_PX,
        "gt_consistent_matches": good as f64 / pairs,
        "opencv_gt_consistent_matches": cv_good as f64 / pairs,
        "gt_consistent_ratio": ratio(good, total),
        "opencv_gt_consistent_ratio": ratio(cv_good, cv_total),
        "gt_consistent_by_octave": octave_json(&our_octaves),
        "opencv_gt_consistent_by_octave": octave_json(&cv_octaves),
        "matches_per_pair": total as f64 / pairs,
        "opencv_matches_per_pair": cv_total as f64 / pairs,
        "default_matcher_gt_consistent_matches": good_def as f64 / pairs,
        "default_matcher_gt_consistent_ratio": ratio(good_def, total_def),
        "xfeat_ms": xfeat_ms,
        "xfeat": xfeat_detail,
        "opencv_version": cv["opencv_version"],
        "machine": machine(),
    });
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&result)?);
        return Ok(());
    }
    let r = |a: f64, b: f64| if b > 0.0 { format!("{:.2}", a / b) } else { "-".into() };
    let m = machine();
    outln!(
        "bench features: {} ({} frames, {} pairs), {} cores, {}, load {}",
        DATASET,
        frames.len(),
        fs.len(),
        m["nproc"],
        m["cpu_model"].as_str().unwrap_or("?"),
        m["loadavg"].as_str().unwrap_or("?")
    );
    outln!("{:<38} {:>10} {:>10} {:>10}", "measure", "colslam", "OpenCV", "ours/peer");
    let rows = [
        ("ORB 1000 kp, ms/frame (1 thread)", o("orb_ms_1000_1t"), cv_ms_1000),
        ("ORB 2000 kp, ms/frame (1 thread)", o("orb_ms_2000_1t"), cv_ms_2000),
        ("ORB 1000 kp, ms/frame (ours 2 threads)", o("orb_ms_1000_2t"), cv_ms_1000),
        ("ORB 2000 kp, ms/frame (ours 2 threads)", o("orb_ms_2000_2t"), cv_ms_2000),
        ("match 2000x2000, ms (2 threads)", median(&ours.match_ms_2t), cv_match),
        ("ORB 1000 kp, ms/frame (OpenCV fast 20)", o("orb_ms_1000_1t"), cv_def_1000),
        ("ORB 2000 kp, ms/frame (OpenCV fast 20)", o("orb_ms_2000_1t"), cv_def_2000),
        ("GT-consistent matches per pair", good as f64 / pairs, cv_good as f64 / pairs),
        ("GT-consistent share of matches", ratio(good, total), ratio(cv_good, cv_total)),
    ];
    for (name, a, b) in rows {
        outln!("{name:<38} {a:>10.3} {b:>10.3} {:>10}", r(a, b));
    }
    outln!(
        "(identical match counts on identical descriptors: {same_counts}; OpenCV default FAST threshold 20: {:.1} consistent matches per pair, share {:.3})",
        cv_def_good as f64 / pairs,
        ratio(cv_def_good, cv_def_total)
    );
    match &xfeat {
        Ok(v) => outln!(
            "XFeat ({} kp, 2 threads): {:.1} ms/frame, MNN matching {:.1} ms/pair, {:.1} GT-consistent matches per pair (share {:.3})",
            XFEAT_FEATURES,
            v["extract_ms"].as_f64().unwrap_or(f64::NAN),
            v["match_ms"].as_f64().unwrap_or(f64::NAN),
            v["gt_consistent_matches"].as_f64().unwrap_or(f64::NAN),
            v["gt_consistent_ratio"].as_f64().unwrap_or(f64::NAN)
        ),
        Err(e) => outln!("XFeat not run: {e}"),
    }
    outln!(
        "(ours with the default matcher, ratio 0.9 and <= 64 bits: {:.1} consistent matches per pair, share {:.3})",
        good_def as f64 / pairs,
        ratio(good_def, total_def)
    );
    Ok(())
}
