//! `colslam bench scale`: how time and memory grow with the length of a
//! video (issue 15). Builds long sequences, runs colslam on each length as a
//! measured subprocess (the suite's runner: wall, CPU user + system, peak
//! RSS from the child's own `VmHWM`), and prints per length the map's size,
//! peak RSS, CPU seconds per frame, ATE and the growth against the shortest
//! length; writes `scale.md` and `scale.json`.
//!
//! The sequences:
//! * `explore`: the synthetic generator's line path along a long room, so
//!   the camera keeps seeing new wall (the map should grow with the frames);
//! * `loop`: the synthetic generator's laps around the central table, one
//!   lap per [`FRAMES_PER_LAP`] frames (after the first lap everything is
//!   mapped space);
//! * `loop-drift`: the same laps at 160x120 (not measured by default),
//!   which drift past the pose-proximity revisit test within a lap: the
//!   sequence for loop closure by appearance (on by default; `--run-args
//!   "--loop-closure false"` for the run without it);
//! * `drive`: the synthetic generator's drive, straight ahead, one left
//!   turn, straight ahead (not measured by default): forward motion with
//!   exact intrinsics, issue 20's scale drift without a calibration's error;
//! * `forward-back`: a real sequence (default `tum_fr1_rpy_sub`) played
//!   forward and back (frames 0..n-1, n-2..0, 1.., ...) as a TUM folder of
//!   symbolic links with strictly increasing timestamps and the matching
//!   ground truth: after the first pass nothing is new.
//!
//! Each sequence is built once, at its longest length; the shorter lengths
//! run on its first frames (`colslam run --max-frames`), which are the same
//! path, so the lengths compare like for like. Synthetic frames are
//! rendered at a low resolution (default 320x240, no supersampling) so that
//! 10,000 frames are cheap; the generator skips a folder that already holds
//! the same sequence.

use crate::outln;
use crate::suite::{
    Ctx, DEFAULT_TIMEOUT_S, check_timeout, fresh_dir, json_f64, json_usize, output_root, run_colslam, sequences,
};
use anyhow::{Context, Result, bail};
use colslam_eval::Trajectory;
use colslam_synth::{PathShape, SynthOptions};
use serde::Serialize;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Default output folder.
pub const DEFAULT_OUT_DIR: &str = "bench-scale";
/// Default lengths of the synthetic sequences, frames.
pub const SYNTHETIC_LENGTHS: [usize; 3] = [1000, 5000, 10000];
/// Default lengths of the forward-back sequence, frames.
pub const FORWARD_BACK_LENGTHS: [usize; 4] = [1000, 2000, 4000, 10000];
/// The sequence kinds `--sequences` accepts.
pub const KINDS: [&str; 5] = ["explore", "loop", "forward-back", "loop-drift", "drive"];
/// The sequences measured when `--sequences` is not given.
pub const DEFAULT_KINDS: [&str; 3] = ["explore", "loop", "forward-back"];
/// Image size of `loop-drift`: the looping path at this size drifts past
/// the pose-proximity revisit test within a lap (about 1.25x in scale and
/// 46 degrees), so only loop closure by appearance ties the laps.
pub const LOOP_DRIFT_SIZE: (usize, usize) = (160, 120);
/// Frames per lap of the looping path (at the default 30 fps and orbit
/// radius the camera moves about 1.1 cm a frame, like the default arc).
pub const FRAMES_PER_LAP: usize = 1000;
/// Camera advance per frame of the exploring line, metres (the default
/// arc's speed).
pub const EXPLORE_STEP_M: f64 = 0.01;
/// Camera advance per frame of the drive, metres (6 m/s at 30 fps).
pub const DRIVE_STEP_M: f64 = 0.2;
/// Radius of the drive's turn, metres.
const DRIVE_TURN_RADIUS_M: f64 = 6.0;
/// Height of the drive's room (the buildings' walls), metres.
const DRIVE_ROOM_HEIGHT_M: f64 = 6.0;
/// Default image size of the synthetic sequences.
pub const DEFAULT_SYNTHETIC_SIZE: (usize, usize) = (320, 240);
/// Clutter boxes of the exploring room (the generator's maximum): they
/// stand along the walls and give the long walls some relief.
const EXPLORE_CLUTTER: usize = 64;
/// Texel edge of the synthetic scale sequences, metres: a texel still
/// covers about one pixel at 320x240 and the long room's textures stay
/// tens of megabytes.
const SCALE_TEXEL_M: f64 = 0.01;
/// Bytes per KiB / KiB per MiB.
const KIB: f64 = 1024.0;

/// Arguments of `bench scale`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Which sequences (comma separated): explore (synthetic, new space all
    /// along), loop (synthetic laps of a room), forward-back (a real
    /// sequence played forward and back), loop-drift (the laps at 160x120,
    /// which drift past the revisit test: the sequence for loop closure),
    /// drive (a synthetic forward drive with one left turn: issue 20).
    #[arg(long, value_delimiter = ',', default_values_t = DEFAULT_KINDS.map(String::from))]
    pub sequences: Vec<String>,
    /// Lengths in frames (comma separated) for every selected sequence.
    /// Default: 1000,5000,10000 synthetic; 1000,2000,4000,10000 forward-back.
    #[arg(long, value_delimiter = ',', value_name = "N,...")]
    pub lengths: Vec<usize>,
    /// Output folder of scale.md, scale.json, the generated sequences and the runs.
    #[arg(long, value_name = "DIR", default_value = DEFAULT_OUT_DIR)]
    pub out: PathBuf,
    /// The real sequence of `forward-back` (a TUM folder under the datasets
    /// folder, with groundtruth.txt).
    #[arg(long, value_name = "NAME", default_value = sequences::TUM_SEQUENCE)]
    pub real: String,
    /// Datasets folder (default: $COLSLAM_DATA, else ./datasets or ../shared/datasets).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// Image size of the synthetic sequences, WxH.
    #[arg(long, value_name = "WxH", default_value = "320x240")]
    pub synthetic_size: String,
    /// Per-run timeout, seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = DEFAULT_TIMEOUT_S)]
    pub timeout: u64,
    /// The colslam executable to measure (default: this one), e.g. another
    /// build for a before/after table.
    #[arg(long, value_name = "PATH")]
    pub exe: Option<PathBuf>,
    /// Extra arguments of every `colslam run` (one string, split at spaces).
    #[arg(long, value_name = "ARGS", allow_hyphen_values = true)]
    pub run_args: Option<String>,
}

/// One sequence to measure at several lengths.
struct ScaleSequence {
    kind: &'static str,
    seq: sequences::Sequence,
    lengths: Vec<usize>,
}

/// One length of one sequence.
#[derive(Debug, Clone, Serialize)]
pub struct ScaleRow {
    /// Sequence name.
    pub sequence: String,
    /// Frames asked for.
    pub length: usize,
    /// Why the run failed, if it did.
    pub reason: Option<String>,
    /// Frames read.
    pub frames: Option<usize>,
    /// Frames localised.
    pub localized: Option<usize>,
    /// Keyframes of the largest map.
    pub keyframes: Option<usize>,
    /// 3D points.
    pub points: Option<usize>,
    /// Observations (track elements).
    pub observations: Option<usize>,
    /// Peak resident set, MiB.
    pub peak_rss_mib: Option<f64>,
    /// CPU seconds (user + system) of the run.
    pub cpu_s: Option<f64>,
    /// CPU seconds per frame read.
    pub cpu_s_per_frame: Option<f64>,
    /// Wall seconds.
    pub wall_s: Option<f64>,
    /// ATE RMSE (Sim(3)-aligned), metres.
    pub ate_rmse_m: Option<f64>,
    /// Per-stage wall seconds from report.json.
    pub timings_s: Option<Value>,
    /// Growth against the shortest length of the same sequence that ran.
    pub growth: Option<Growth>,
    /// The run's folder, relative to the output folder.
    pub output_dir: String,
}

/// Ratios of one length to the shortest length of its sequence.
#[derive(Debug, Clone, Serialize)]
pub struct Growth {
    /// The length compared against.
    pub base_length: usize,
    /// Frames ratio.
    pub frames: f64,
    /// Keyframes ratio.
    pub keyframes: Option<f64>,
    /// Points ratio.
    pub points: Option<f64>,
    /// Peak RSS ratio.
    pub peak_rss: Option<f64>,
    /// CPU seconds per frame ratio.
    pub cpu_s_per_frame: Option<f64>,
    /// ATE ratio.
    pub ate: Option<f64>,
    /// Peak RSS added per added frame, KiB.
    pub rss_kib_per_added_frame: Option<f64>,
}

/// `(frames played, source frame)`: position `k` of a forward-back
/// playback of `n` frames shows source frame `0, 1, .., n-1, n-2, .., 0, 1, ..`
/// (period `2 (n - 1)`; the turning frames are shown once per turn).
pub fn forward_back_index(k: usize, n: usize) -> usize {
    if n < 2 {
        return 0;
    }
    let period = 2 * (n - 1);
    let m = k % period;
    if m < n { m } else { period - m }
}

/// The synthetic options of `kind` (`explore` or `loop`) at `frames` frames.
pub fn synthetic_options(kind: &str, frames: usize, size: (usize, usize)) -> Result<SynthOptions> {
    let (kind, (width, height)) = if kind == "loop-drift" { ("loop", LOOP_DRIFT_SIZE) } else { (kind, size) };
    let d = SynthOptions::default();
    let base = SynthOptions {
        frames,
        width,
        height,
        focal: d.focal * width as f64 / d.width as f64,
        supersample: 1,
        texel_size: SCALE_TEXEL_M,
        ..d
    };
    Ok(match kind {
        "explore" => {
            let length = frames as f64 * EXPLORE_STEP_M;
            let margin = 2.0 * colslam_synth::options::LINE_END_MARGIN;
            SynthOptions {
                path: PathShape::Line,
                path_length: length,
                room_size: [(length + margin + 0.5).max(base.room_size[0]), base.room_size[1], base.room_size[2]],
                clutter_boxes: EXPLORE_CLUTTER,
                ..base
            }
        }
        "drive" => {
            let length = frames as f64 * DRIVE_STEP_M;
            let drive =
                SynthOptions { path: PathShape::Drive, path_length: length, orbit_radius: DRIVE_TURN_RADIUS_M, ..base };
            let straight = colslam_synth::options::drive_layout(&drive).straight.max(0.0);
            // Room for one straight, the turn, the lane's inset and the end margin, with 2 m to spare.
            let side = straight
                + DRIVE_TURN_RADIUS_M
                + colslam_synth::options::DRIVE_INSET
                + colslam_synth::options::LINE_END_MARGIN
                + 2.0;
            SynthOptions {
                room_size: [side.max(base.room_size[0]), side.max(base.room_size[1]), DRIVE_ROOM_HEIGHT_M],
                clutter_boxes: EXPLORE_CLUTTER,
                ..drive
            }
        }
        "loop" => SynthOptions {
            path: PathShape::Laps,
            path_length: frames as f64 / FRAMES_PER_LAP as f64 * std::f64::consts::TAU * base.orbit_radius,
            ..base
        },
        _ => bail!("no synthetic sequence {kind:?}"),
    })
}

/// Writes `dir` as a TUM folder playing the TUM sequence `src` forward and
/// back for `frames` frames: `rgb/NNNNNN.png` links to the source images,
/// `rgb.txt` with the source's median frame interval, `groundtruth.txt`
/// with the source's ground-truth pose nearest each shown frame, and the
/// source's camera file.
pub fn write_forward_back(src: &Path, dir: &Path, frames: usize) -> Result<()> {
    let seq = colslam_io::ImageSequence::open(src, &colslam_io::SourceOptions::default())
        .with_context(|| format!("reading {}", src.display()))?;
    let listed: Vec<(PathBuf, f64)> = seq.listed().map(|f| (f.path.to_path_buf(), f.timestamp)).collect();
    if listed.len() < 2 {
        bail!("{}: a forward-back playback needs at least 2 frames", src.display());
    }
    let gt_path = src.join("groundtruth.txt");
    let gt = Trajectory::read_tum(&gt_path).with_context(|| format!("reading {}", gt_path.display()))?;
    if gt.is_empty() {
        bail!("{}: no poses", gt_path.display());
    }
    let dts: Vec<f64> = listed.windows(2).map(|w| w[1].1 - w[0].1).collect();
    let dt = crate::median(&dts);
    if !(dt.is_finite() && dt > 0.0) {
        bail!("{}: the frame timestamps do not increase", src.display());
    }
    fresh_dir(dir)?;
    let rgb = dir.join("rgb");
    std::fs::create_dir_all(&rgb).with_context(|| format!("creating {}", rgb.display()))?;
    let mut list = String::from("# timestamp filename (forward-back playback)\n");
    let mut out = Trajectory::default();
    for k in 0..frames {
        let (path, stamp) = &listed[forward_back_index(k, listed.len())];
        let name = format!("{k:06}.png");
        let target = std::fs::canonicalize(path).with_context(|| format!("resolving {}", path.display()))?;
        let link = rgb.join(&name);
        std::os::unix::fs::symlink(&target, &link).with_context(|| format!("linking {}", link.display()))?;
        let t = k as f64 * dt;
        writeln!(list, "{t:.6} rgb/{name}")?;
        out.stamps.push(t);
        out.poses.push(gt.poses[nearest_stamp(&gt.stamps, *stamp)]);
    }
    colslam_image::write_atomic(&dir.join("rgb.txt"), list.as_bytes()).context("writing rgb.txt")?;
    out.write_tum(&dir.join("groundtruth.txt")).context("writing groundtruth.txt")?;
    let camera = colslam_io::find_camera_file(&[src])
        .with_context(|| format!("{}: no camera file beside the images", src.display()))?;
    let name = camera.file_name().context("camera file without a name")?;
    std::fs::copy(&camera, dir.join(name)).with_context(|| format!("copying {}", camera.display()))?;
    Ok(())
}

/// Index of the stamp nearest `t` in sorted `stamps` (not empty).
fn nearest_stamp(stamps: &[f64], t: f64) -> usize {
    let i = stamps.partition_point(|&s| s < t);
    match (i.checked_sub(1), stamps.get(i)) {
        (Some(j), Some(&s)) if t - stamps[j] <= s - t => j,
        (Some(j), None) => j,
        _ => i,
    }
}

/// The sequences and lengths selected.
fn select(args: &Args, out: &Path) -> Result<Vec<ScaleSequence>> {
    let size = sequences::parse_size(&args.synthetic_size)?;
    let mut picked = Vec::new();
    for name in &args.sequences {
        let kind = KINDS
            .iter()
            .copied()
            .find(|k| *k == name.trim())
            .with_context(|| format!("--sequences {name:?} is not one of {}", KINDS.join(", ")))?;
        let mut lengths = if !args.lengths.is_empty() {
            args.lengths.clone()
        } else if kind == "forward-back" {
            FORWARD_BACK_LENGTHS.to_vec()
        } else {
            SYNTHETIC_LENGTHS.to_vec()
        };
        lengths.sort_unstable();
        lengths.dedup();
        let Some(&longest) = lengths.last() else { bail!("--lengths lists no length") };
        if lengths[0] < 2 {
            bail!("--lengths must be at least 2 frames");
        }
        let seq = if kind == "forward-back" {
            let name = format!("{}-forward-back", args.real);
            let dir = out.join("data").join(&name);
            sequences::Sequence {
                gt: Some(dir.join("groundtruth.txt")),
                input: dir,
                name,
                camera: sequences::CameraSpec::Auto,
                synth: None,
                user: false,
                rolling_shutter: None,
            }
        } else {
            let name = format!("synthetic-{kind}");
            let dir = out.join("data").join(&name);
            let opts = synthetic_options(kind, longest, size)?;
            opts.validate().with_context(|| format!("the {name} sequence at {longest} frames"))?;
            sequences::Sequence {
                gt: Some(dir.join("groundtruth.txt")),
                input: dir,
                name,
                camera: sequences::CameraSpec::Auto,
                synth: Some(opts),
                user: false,
                rolling_shutter: None,
            }
        };
        picked.push(ScaleSequence { kind, seq, lengths });
    }
    Ok(picked)
}

/// Builds the input of a sequence at its longest length.
fn build(s: &ScaleSequence, args: &Args, quiet: bool) -> Result<()> {
    let longest = s.lengths.last().copied().unwrap_or(0);
    if !quiet {
        eprintln!("building {} ({longest} frames) in {}", s.seq.name, s.seq.input.display());
    }
    if let Some(opts) = &s.seq.synth {
        colslam_synth::generate(opts, &s.seq.input, None)
            .with_context(|| format!("generating {}", s.seq.input.display()))?;
        return Ok(());
    }
    let data = sequences::data_dir(args.data.as_deref());
    write_forward_back(&data.join(&args.real), &s.seq.input, longest)
}

/// Runs one length and reads what the suite's row lacks.
fn measure(ctx: &Ctx, s: &ScaleSequence, length: usize, extra: &[String]) -> ScaleRow {
    let mut args = vec!["--max-frames".to_string(), length.to_string()];
    args.extend(extra.iter().cloned());
    let row = run_colslam(ctx, &s.seq, &length.to_string(), &args, 0);
    let report = std::fs::read(ctx.out.join(&row.output_dir).join("report.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok());
    let frames = row.frames;
    ScaleRow {
        sequence: s.seq.name.clone(),
        length,
        reason: row.reason,
        frames,
        localized: row.localized,
        keyframes: row.keyframes,
        points: row.points,
        observations: report.as_ref().and_then(|r| json_usize(r, "observations")),
        peak_rss_mib: row.peak_rss_mib,
        cpu_s: row.cpu_s,
        cpu_s_per_frame: row.cpu_s.zip(frames.filter(|&n| n > 0)).map(|(c, n)| c / n as f64),
        wall_s: row.wall_s.or_else(|| report.as_ref().and_then(|r| json_f64(r, "wall_s"))),
        ate_rmse_m: row.ate_rmse_m,
        timings_s: row.timings_s,
        growth: None,
        output_dir: row.output_dir,
    }
}

fn ratio<T: Into<f64>>(a: Option<T>, b: Option<T>) -> Option<f64> {
    let (a, b) = (a?.into(), b?.into());
    (b > 0.0).then(|| a / b)
}

fn as_f64(v: Option<usize>) -> Option<f64> {
    v.map(|x| x as f64)
}

/// Fills each row's growth against the first successful row of its sequence.
pub fn fill_growth(rows: &mut [ScaleRow]) {
    let mut base: Option<ScaleRow> = None;
    for r in rows.iter_mut() {
        if base.as_ref().is_none_or(|b| b.sequence != r.sequence) {
            base = None;
        }
        if r.reason.is_some() {
            continue;
        }
        let b = base.get_or_insert_with(|| r.clone());
        let (Some(f), Some(bf)) = (r.frames, b.frames) else { continue };
        let added = f.saturating_sub(bf);
        r.growth = Some(Growth {
            base_length: b.length,
            frames: f as f64 / bf.max(1) as f64,
            keyframes: ratio(as_f64(r.keyframes), as_f64(b.keyframes)),
            points: ratio(as_f64(r.points), as_f64(b.points)),
            peak_rss: ratio(r.peak_rss_mib, b.peak_rss_mib),
            cpu_s_per_frame: ratio(r.cpu_s_per_frame, b.cpu_s_per_frame),
            ate: ratio(r.ate_rmse_m, b.ate_rmse_m),
            rss_kib_per_added_frame: r
                .peak_rss_mib
                .zip(b.peak_rss_mib)
                .filter(|_| added > 0)
                .map(|(m, bm)| (m - bm) * KIB / added as f64),
        });
    }
}

fn cell<T>(v: Option<T>, f: impl Fn(T) -> String) -> String {
    v.map_or_else(|| "-".into(), f)
}

fn stage(r: &ScaleRow, key: &str) -> String {
    cell(r.timings_s.as_ref().and_then(|t| json_f64(t, key)), |v| format!("{v:.1}"))
}

/// The markdown table.
pub fn markdown(rows: &[ScaleRow], header: &str) -> String {
    let mut md = format!("# colslam bench scale\n\n{header}\n\n");
    md.push_str(
        "| sequence | frames | keyframes | 3D points | observations | peak RSS MiB | KiB/added frame | CPU s/frame | wall s | ATE cm | triangulation s | global BA s | localisation s | growth (kf, RSS, CPU/frame, ATE) |\n",
    );
    md.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in rows {
        if let Some(reason) = &r.reason {
            let _ =
                writeln!(md, "| {} | {} | FAILED: {} |||||||||||| |", r.sequence, r.length, reason.replace('|', "/"));
            continue;
        }
        let g = r.growth.as_ref();
        let x = |v: Option<f64>| cell(v, |v| format!("{v:.2}x"));
        let growth = g.map_or_else(
            || "-".into(),
            |g| format!("{}, {}, {}, {}", x(g.keyframes), x(g.peak_rss), x(g.cpu_s_per_frame), x(g.ate)),
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.sequence,
            cell(r.frames, |v| v.to_string()),
            cell(r.keyframes, |v| v.to_string()),
            cell(r.points, |v| v.to_string()),
            cell(r.observations, |v| v.to_string()),
            cell(r.peak_rss_mib, |v| format!("{v:.0}")),
            cell(g.and_then(|g| g.rss_kib_per_added_frame), |v| format!("{v:.0}")),
            cell(r.cpu_s_per_frame, |v| format!("{v:.3}")),
            cell(r.wall_s, |v| format!("{v:.1}")),
            cell(r.ate_rmse_m, |v| format!("{:.2}", 100.0 * v)),
            stage(r, "triangulation"),
            stage(r, "global_ba"),
            stage(r, "localization"),
            growth,
        );
    }
    md
}

/// Runs `bench scale`.
pub fn run(args: &Args, quiet: bool, threads: Option<usize>) -> Result<()> {
    check_timeout(args.timeout)?;
    let out = output_root(&args.out)?;
    let picked = select(args, &out)?;
    let ctx = Ctx::new(args.exe.as_deref(), out.clone(), args.timeout, threads, quiet)?;
    let extra: Vec<String> =
        args.run_args.as_deref().map(|a| a.split_whitespace().map(String::from).collect()).unwrap_or_default();
    let mut rows = Vec::new();
    for s in &picked {
        if let Err(e) = build(s, args, quiet) {
            for &length in &s.lengths {
                rows.push(failed_row(s, length, format!("{e:#}")));
            }
            continue;
        }
        for &length in &s.lengths {
            let row = measure(&ctx, s, length, &extra);
            if !quiet {
                eprintln!(
                    "{} ({}) {length}: {}",
                    s.seq.name,
                    s.kind,
                    row.reason.clone().unwrap_or_else(|| format!(
                        "{} keyframes, peak RSS {} MiB, {} CPU s/frame",
                        cell(row.keyframes, |v| v.to_string()),
                        cell(row.peak_rss_mib, |v| format!("{v:.0}")),
                        cell(row.cpu_s_per_frame, |v| format!("{v:.3}"))
                    ))
                );
            }
            rows.push(row);
        }
    }
    fill_growth(&mut rows);
    let header = format!(
        "Executable `{}`, threads {}, run arguments `{}`; growth against the shortest length of each sequence.",
        ctx.exe.display(),
        threads.map_or_else(|| "all".into(), |t| t.to_string()),
        extra.join(" ")
    );
    let md = markdown(&rows, &header);
    let json = serde_json::to_vec_pretty(&serde_json::json!({ "executable": ctx.exe, "rows": rows }))?;
    colslam_image::write_atomic(&out.join("scale.json"), &json).context("writing scale.json")?;
    colslam_image::write_atomic(&out.join("scale.md"), md.as_bytes()).context("writing scale.md")?;
    if !quiet {
        outln!("{md}");
        outln!("report: {}", out.join("scale.md").display());
    }
    Ok(())
}

fn failed_row(s: &ScaleSequence, length: usize, reason: String) -> ScaleRow {
    ScaleRow {
        sequence: s.seq.name.clone(),
        length,
        reason: Some(reason),
        frames: None,
        localized: None,
        keyframes: None,
        points: None,
        observations: None,
        peak_rss_mib: None,
        cpu_s: None,
        cpu_s_per_frame: None,
        wall_s: None,
        ate_rmse_m: None,
        timings_s: None,
        growth: None,
        output_dir: String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_back_indices() {
        let shown: Vec<usize> = (0..12).map(|k| forward_back_index(k, 4)).collect();
        assert_eq!(shown, [0, 1, 2, 3, 2, 1, 0, 1, 2, 3, 2, 1]);
        assert_eq!(forward_back_index(5, 1), 0);
    }

    #[test]
    fn nearest_stamps() {
        let s = [1.0, 2.0, 3.0];
        assert_eq!([0.0, 1.4, 1.6, 2.5, 9.0].map(|t| nearest_stamp(&s, t)), [0, 0, 1, 1, 2]);
    }

    #[test]
    fn synthetic_shapes_validate_at_every_default_length() {
        for kind in ["explore", "loop", "loop-drift"] {
            for n in SYNTHETIC_LENGTHS {
                let o = synthetic_options(kind, n, DEFAULT_SYNTHETIC_SIZE).unwrap();
                o.validate().unwrap_or_else(|e| panic!("{kind} {n}: {e}"));
            }
        }
        assert!(synthetic_options("spiral", 10, DEFAULT_SYNTHETIC_SIZE).is_err());
        let drift = synthetic_options("loop-drift", 1000, DEFAULT_SYNTHETIC_SIZE).unwrap();
        assert_eq!((drift.width, drift.height, drift.path), (160, 120, PathShape::Laps));
    }

    fn row(seq: &str, length: usize, kf: usize, rss: f64, cpu: f64) -> ScaleRow {
        ScaleRow {
            frames: Some(length),
            keyframes: Some(kf),
            peak_rss_mib: Some(rss),
            cpu_s_per_frame: Some(cpu),
            ate_rmse_m: Some(0.01),
            reason: None,
            ..failed_row(
                &ScaleSequence { kind: "loop", seq: sequences::Sequence::user(Path::new(seq)), lengths: vec![] },
                length,
                String::new(),
            )
        }
    }

    #[test]
    fn growth_is_against_the_shortest_successful_length_of_each_sequence() {
        let mut failed = row("a", 500, 1, 1.0, 1.0);
        failed.reason = Some("timeout".into());
        let mut rows =
            vec![failed, row("a", 1000, 10, 100.0, 0.01), row("a", 2000, 30, 300.0, 0.02), row("b", 100, 5, 50.0, 0.1)];
        fill_growth(&mut rows);
        assert!(rows[0].growth.is_none());
        let g = rows[1].growth.as_ref().unwrap();
        assert_eq!((g.base_length, g.frames, g.keyframes), (1000, 1.0, Some(1.0)));
        let g = rows[2].growth.as_ref().unwrap();
        assert_eq!((g.frames, g.keyframes, g.peak_rss, g.cpu_s_per_frame), (2.0, Some(3.0), Some(3.0), Some(2.0)));
        assert_eq!(g.rss_kib_per_added_frame, Some(200.0 * 1024.0 / 1000.0));
        assert_eq!(rows[3].growth.as_ref().unwrap().base_length, 100);
        let md = markdown(&rows, "h");
        assert!(md.contains("| a | 500 | FAILED: timeout |") && md.contains("3.00x, 3.00x, 2.00x, 1.00x"), "{md}");
    }
}
