//! `colslam run`: the SLAM pipeline on a video or an image sequence.

use anyhow::{Context, Result, bail};
use colslam_camera::{Camera, presets};
use colslam_io::{FrameSource, SourceOptions, open_source};
use colslam_slam::{EventSink, OutputFormat, RunReport, Slam, SlamOptions, Stage, write_outputs, write_report};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Focal length prior for unknown cameras, as a multiple of the larger image
/// side (COLMAP's default prior, `default_focal_length_factor` 1.2).
pub const DEFAULT_FOCAL_FACTOR: f64 = 1.2;

/// Pipeline options shared by `run` and `demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct PipelineArgs {
    /// Feature extractor.
    #[arg(long, default_value = "orb")]
    pub features: String,
    /// Matcher.
    #[arg(long, default_value = "nn")]
    pub matcher: String,
    /// Keypoints per frame; 0 scales them with the image area (1000 at 640x480, 2300 at 1241x376, at most 8000).
    #[arg(long, default_value_t = SlamOptions::default().num_features)]
    pub num_features: usize,
    /// Use every s-th frame.
    #[arg(long, default_value_t = 1)]
    pub skip: usize,
    /// Process at most this many frames (after skip).
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Frames considered for map initialisation.
    #[arg(long, default_value_t = SlamOptions::default().init_frames)]
    pub init_frames: usize,
    /// Flow score a frame must exceed to become a keyframe.
    #[arg(long, default_value_t = SlamOptions::default().flow_threshold)]
    pub flow_threshold: f64,
    /// Matches to the last keyframe a keyframe needs.
    #[arg(long, default_value_t = SlamOptions::default().min_matches)]
    pub min_matches: usize,
    /// Refine focal length and distortion in bundle adjustment.
    #[arg(long)]
    pub refine_intrinsics: bool,
    /// Largest Hamming distance (of 256 bits) of an ORB match.
    #[arg(long, default_value_t = SlamOptions::default().max_hamming)]
    pub max_hamming: u32,
    /// Lowe's ratio of the nearest-neighbour matcher.
    #[arg(long, default_value_t = SlamOptions::default().max_ratio)]
    pub max_ratio: f32,
    /// Minimum triangulation angle of a 3D point, degrees.
    #[arg(long, default_value_t = SlamOptions::default().min_tri_angle_deg)]
    pub min_tri_angle: f64,
    /// Minimum median triangulation angle of the initial pair, degrees.
    #[arg(long, default_value_t = SlamOptions::default().init_min_tri_angle_deg)]
    pub init_min_tri_angle: f64,
    /// Previous keyframes a new keyframe is matched against.
    #[arg(long, default_value_t = SlamOptions::default().match_keyframes)]
    pub match_keyframes: usize,
    /// Older keyframes looking the same way a new keyframe is matched against too (0: off).
    #[arg(long, default_value_t = SlamOptions::default().match_revisited)]
    pub match_revisited: usize,
    /// Below this many matches to the last keyframe a keyframe is forced.
    #[arg(long, default_value_t = SlamOptions::default().force_keyframe_matches)]
    pub force_keyframe_matches: usize,
    /// Rolling-shutter readout time of the camera in seconds (first row to last; 0: global
    /// shutter). Observations are moved to their frame's middle-row time after mapping.
    #[arg(long, value_name = "SECONDS", default_value_t = SlamOptions::default().rolling_shutter_readout)]
    pub rolling_shutter: f64,
    /// Keyframes in a local bundle adjustment (the new one and its most connected).
    #[arg(long, default_value_t = SlamOptions::default().local_ba_images)]
    pub local_ba_images: usize,
    /// Global bundle adjustment once the registered images or the points grew by this factor.
    #[arg(long, default_value_t = SlamOptions::default().global_ba_growth)]
    pub global_ba_growth: f64,
    /// At the end, add every localised frame to the model and bundle adjust
    /// all of them together.
    #[arg(long)]
    pub refine_all_frames: bool,
    /// Weight bundle-adjustment observations by the keypoint's pyramid level.
    #[arg(long)]
    pub weight_by_level: bool,
    /// Accept keyframe candidates even when their motion is a pure rotation.
    #[arg(long)]
    pub allow_pure_rotation: bool,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the COLMAP model as text instead of binary.
    #[arg(long)]
    pub text: bool,
}

impl PipelineArgs {
    /// The pipeline options these arguments select.
    pub fn slam_options(&self) -> SlamOptions {
        SlamOptions {
            features: self.features.clone(),
            matcher: self.matcher.clone(),
            num_features: self.num_features,
            init_frames: self.init_frames,
            flow_threshold: self.flow_threshold,
            min_matches: self.min_matches,
            refine_intrinsics: self.refine_intrinsics,
            min_tri_angle_deg: self.min_tri_angle,
            max_hamming: self.max_hamming,
            max_ratio: self.max_ratio,
            init_min_tri_angle_deg: self.init_min_tri_angle,
            match_keyframes: self.match_keyframes,
            match_revisited: self.match_revisited,
            force_keyframe_matches: self.force_keyframe_matches,
            local_ba_images: self.local_ba_images,
            rolling_shutter_readout: self.rolling_shutter,
            global_ba_growth: self.global_ba_growth,
            reject_pure_rotation: !self.allow_pure_rotation,
            refine_all_frames: self.refine_all_frames,
            weight_by_level: self.weight_by_level,
            seed: self.seed,
            ..SlamOptions::default()
        }
    }
}

/// Arguments of `run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Video file or image sequence folder (TUM, EuRoC, KITTI layouts or plain images).
    pub input: PathBuf,
    /// Output folder.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Camera file (YAML/TOML; see the camera crate). Default: a camera file
    /// found beside the input.
    #[arg(long, conflicts_with = "preset")]
    pub camera: Option<PathBuf>,
    /// Built-in camera preset (tum-fr1, tum-fr2, tum-fr3, kitti-984).
    #[arg(long)]
    pub preset: Option<String>,
    /// Focal length in pixels for an unknown camera (principal point at the
    /// image centre; refined by bundle adjustment).
    #[arg(long, conflicts_with_all = ["camera", "preset"])]
    pub focal: Option<f64>,
    /// Ground-truth trajectory (TUM format) to evaluate the result against.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
}

/// The camera of a run, and whether it is a guess to be refined.
fn resolve_camera(args: &RunArgs, source: &dyn FrameSource) -> Result<(Camera, bool)> {
    if let Some(path) = &args.camera {
        return Ok((colslam_camera::file::read_camera_file(path)?, false));
    }
    if let Some(name) = &args.preset {
        let cam = presets::preset(name).with_context(|| {
            format!("unknown camera preset {name:?} (known: {})", presets::preset_names().join(", "))
        })?;
        return Ok((cam, false));
    }
    let size = source.image_size();
    if args.focal.is_none()
        && let Some(path) = source.camera_file()
    {
        let cam = colslam_camera::file::read_camera_file(&path)?;
        tracing::info!("camera from {}", path.display());
        return Ok((cam, false));
    }
    let Some((w, h)) = size else {
        bail!("{}: cannot tell the image size; give --camera or --preset", args.input.display());
    };
    let f = args.focal.unwrap_or(DEFAULT_FOCAL_FACTOR * w.max(h) as f64);
    if !(f.is_finite() && f > 0.0) {
        bail!("--focal must be a positive number of pixels, got {f}");
    }
    // OpenCV convention: the centre of a w-pixel row is at (w - 1) / 2.
    let cam = Camera::simple_pinhole(w as u64, h as u64, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    tracing::info!("unknown camera: focal {f:.1} px, principal point at the centre, refined by bundle adjustment");
    Ok((cam, args.focal.is_none()))
}

/// What a pipeline run produced.
pub struct RunOutcome {
    /// The report written to `report.json`.
    pub report: RunReport,
    /// Evaluation against ground truth, when given.
    pub eval: Option<colslam_eval::EvalReport>,
}

/// A hook called with a value of the run (see [`RunHooks`]).
pub type Hook<'a, T> = Box<dyn FnMut(&T) + 'a>;

/// Optional hooks into a run (the live viewer uses them); the default has
/// none and costs nothing. Hooks run on the pipeline's thread, so they must
/// not block.
#[derive(Default)]
pub struct RunHooks<'a> {
    /// Checked before every frame: once set, no more frames are read and the
    /// run finishes with the frames so far (outputs are written as usual, with
    /// a note in the report).
    pub cancel: Option<Arc<AtomicBool>>,
    /// Called once with the run's camera, before the first frame.
    pub on_camera: Option<Hook<'a, Camera>>,
    /// Called with every decoded frame before the pipeline processes it.
    pub before_frame: Option<Hook<'a, colslam_io::Frame>>,
    /// Called with the pipeline after every processed frame.
    pub after_frame: Option<Hook<'a, Slam>>,
}

/// Frames decoded and extracted ahead of the mapper (bounds the memory the
/// reader thread can hold: a VGA frame with its features is about 1.2 MB).
const PREFETCH_FRAMES: usize = 4;

/// A frame with its features, from the reader thread.
struct ExtractedFrame {
    frame: colslam_io::Frame,
    data: Result<colslam_slam::frontend::FrameData, colslam_slam::SlamError>,
    decode: std::time::Duration,
    features: std::time::Duration,
}

/// What the reader thread hands to the mapper.
enum Extracted {
    Frame(Box<ExtractedFrame>),
    Skipped { error: String, decode: std::time::Duration },
}

/// Runs the pipeline on `args.input` into `args.output`.
pub fn run_pipeline(args: &RunArgs, quiet: bool, events: EventSink) -> Result<RunOutcome> {
    run_pipeline_with(args, quiet, events, RunHooks::default())
}

/// [`run_pipeline`] with hooks (cancellation, frames and pipeline state for a viewer).
pub fn run_pipeline_with(
    args: &RunArgs,
    quiet: bool,
    events: EventSink,
    mut hooks: RunHooks<'_>,
) -> Result<RunOutcome> {
    let started = Instant::now();
    let p = &args.pipeline;
    if p.threads > 0 {
        // Fails only when a global pool already exists (a second run in one
        // process), which keeps the first setting.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(p.threads).build_global();
    }
    let src_opts = SourceOptions { skip: p.skip, max_frames: p.max_frames, ..SourceOptions::default() };
    let mut source = open_source(&args.input, &src_opts)?;
    let (camera, guessed) = resolve_camera(args, source.as_ref())?;
    let mut opts = p.slam_options();
    opts.refine_intrinsics |= guessed;
    if let Some(f) = hooks.on_camera.as_mut() {
        f(&camera);
    }
    let mut slam = Slam::new(opts.clone(), &camera, events)?;
    let (mut cancelled_at, mut processed) = (None, 0usize);
    if let Some(gt) = &args.gt {
        slam.set_debug_ground_truth(colslam_eval::trajectory::Trajectory::read_tum(gt)?);
    }
    tracing::info!("{}", source.describe());
    let pb = crate::logging::progress_bar(source.len_hint().unwrap_or(0) as u64, quiet, "frames");
    // Decoding and feature extraction run up to PREFETCH_FRAMES frames ahead
    // of the mapping on a thread of their own, so the second core has work
    // while the mapper runs its serial parts; features are the same as on
    // one thread, so the output is too.
    let frontend = slam.frontend();
    std::thread::scope(|scope| -> Result<()> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Extracted>(PREFETCH_FRAMES);
        let producer = scope.spawn(move || {
            loop {
                let t = Instant::now();
                let Some(next) = source.next() else { break };
                let decode = t.elapsed();
                let item = match next {
                    Ok(frame) => {
                        let t = Instant::now();
                        let data = frontend.process(&frame);
                        Extracted::Frame(Box::new(ExtractedFrame { frame, data, decode, features: t.elapsed() }))
                    }
                    Err(e) => Extracted::Skipped { error: e.to_string(), decode },
                };
                // The receiver is gone once the run stops early.
                if tx.send(item).is_err() {
                    break;
                }
            }
        });
        for item in rx.iter() {
            if hooks.cancel.as_ref().is_some_and(|c| c.load(Ordering::SeqCst)) {
                cancelled_at = Some(processed);
                break;
            }
            let ExtractedFrame { frame, data, decode, features } = match item {
                Extracted::Frame(f) => *f,
                Extracted::Skipped { error, decode } => {
                    slam.timings_mut().add(Stage::Decode, decode);
                    tracing::warn!("skipping a frame: {error}");
                    continue;
                }
            };
            slam.timings_mut().add(Stage::Decode, decode);
            slam.timings_mut().add(Stage::Features, features);
            if let Some(f) = hooks.before_frame.as_mut() {
                f(&frame);
            }
            let context = || format!("processing frame {} ({})", frame.index, frame.name);
            slam.process_features(data.with_context(context)?).with_context(context)?;
            processed += 1;
            if let Some(f) = hooks.after_frame.as_mut() {
                f(&slam);
            }
            pb.inc(1);
            pb.set_message(format!("{} kf", slam.num_keyframes()));
        }
        drop(rx);
        producer.join().map_err(|_| anyhow::anyhow!("the frame reader thread panicked"))?;
        Ok(())
    })?;
    pb.finish_and_clear();
    let mut result = slam.finish()?;
    let t = Instant::now();
    let format = if p.text { OutputFormat::Text } else { OutputFormat::Binary };
    let input = args.input.display().to_string();
    let mut report = write_outputs(&result, &args.output, &input, &opts, format)?;
    result.timings.add(Stage::Output, t.elapsed());
    if let Some(n) = cancelled_at {
        report.notes.push(format!("stopped on request after {n} frames"));
    }
    report.timings_s = result.timings.clone();
    report.wall_time_s = started.elapsed().as_secs_f64();
    report.ms_per_frame = if report.frames > 0 { 1e3 * report.wall_time_s / report.frames as f64 } else { 0.0 };
    write_report(&report, &args.output)?;
    let eval = match &args.gt {
        Some(gt) => Some(evaluate(gt, &args.output)?),
        None => None,
    };
    Ok(RunOutcome { report, eval })
}

/// ATE of `out/trajectory.tum` against `gt`, with a plot beside it.
pub fn evaluate(gt: &Path, out: &Path) -> Result<colslam_eval::EvalReport> {
    let est = out.join("trajectory.tum");
    let report = colslam_eval::evaluate_files(gt, &est, &colslam_eval::EvalOptions::default())?;
    colslam_eval::plot::plot_evaluation(&report, &out.join("trajectory.eval.png"))?;
    Ok(report)
}

/// A short summary table of a run.
pub fn summary(r: &RunReport) -> String {
    let t = &r.timings_s;
    let mut s = String::new();
    s.push_str(&format!("frames            {:>8}\n", r.frames));
    s.push_str(&format!("localized         {:>8}  ({:.1} %)\n", r.localized, 100.0 * r.localized_ratio));
    s.push_str(&format!("keyframes         {:>8}\n", r.keyframes));
    s.push_str(&format!("maps              {:>8}\n", r.maps.len()));
    s.push_str(&format!("3D points         {:>8}\n", r.points));
    s.push_str(&format!("observations      {:>8}\n", r.observations));
    s.push_str(&format!("mean track length {:>8.2}\n", r.mean_track_length));
    s.push_str(&format!("mean reproj. err  {:>8.3} px\n", r.mean_reprojection_error));
    s.push_str(&format!("points per image  {:>8.1}\n", r.points_per_image));
    s.push_str(&format!("wall time         {:>8.2} s  ({:.1} ms/frame)\n", r.wall_time_s, r.ms_per_frame));
    s.push_str(&format!(
        "stages (s)        decode {:.2}, features {:.2}, matching {:.2}, keyframe test {:.2}, init {:.2},\n                  registration {:.2}, triangulation {:.2}, local BA {:.2}, global BA {:.2}, localisation {:.2}, output {:.2}",
        t.decode, t.features, t.matching, t.keyframe_test, t.initialization, t.registration, t.triangulation, t.local_ba,
        t.global_ba, t.localization, t.output
    ));
    for n in &r.notes {
        s.push_str(&format!("\nnote: {n}"));
    }
    s
}

/// Runs `run`.
pub fn run(args: &RunArgs, quiet: bool) -> Result<()> {
    let outcome = run_pipeline(args, quiet, EventSink::none())?;
    println!("{}", summary(&outcome.report));
    println!("outputs in {}", args.output.display());
    if let Some(e) = &outcome.eval {
        println!("{e}");
    }
    Ok(())
}
