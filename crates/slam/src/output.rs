//! Writing a run's outputs: the COLMAP model of the largest map (binary or
//! text), the other maps under `maps/<k>/`, `trajectory.tum` (every localised
//! frame), `keyframes.tum`, `points.ply`, `report.json` and, with ground
//! truth, `trajectory.eval.png`.
//!
//! The output folder is written as a whole ([`begin_run_output`], see
//! [`colslam_image::OutputDir`]): everything goes into a staging folder
//! beside it that replaces it when complete, so the folder always holds one
//! whole run (the previous or the new one), never files of two runs. A run
//! owns its output folder: one holding anything but [`RUN_OUTPUT_NAMES`] is
//! refused rather than replaced.

use crate::error::SlamError;
use crate::frame::{FrameId, FramePose};
use crate::options::SlamOptions;
use crate::pipeline::{MapResult, SlamResult};
use crate::timing::StageTimings;
use colslam_camera::PixelConvention;
use colslam_camera::file::to_run_yaml_string;
use colslam_eval::trajectory::Trajectory;
use colslam_image::OutputDir;
use colslam_scene::{MODEL_FILE_NAMES, ModelFormat, write_model_files, write_ply};
use serde::Serialize;
use std::path::Path;

/// Summary of one map.
#[derive(Debug, Clone, Serialize)]
pub struct MapSummary {
    /// Map index (order of creation).
    pub index: usize,
    /// Registered keyframes.
    pub keyframes: usize,
    /// Frames with a pose (keyframes included).
    pub localized_frames: usize,
    /// 3D points.
    pub points: usize,
    /// Observations.
    pub observations: usize,
    /// Mean track length.
    pub mean_track_length: f64,
    /// Mean reprojection error, px.
    pub mean_reprojection_error: f64,
    /// Mean 3D points observed per keyframe (the paper's "3D points per image").
    pub points_per_image: f64,
    /// First and last frame index with a pose.
    pub frame_range: Option<(usize, usize)>,
}

/// The contents of `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RunReport {
    /// Input path.
    pub input: String,
    /// Frames read.
    pub frames: usize,
    /// Keyframes of the largest map.
    pub keyframes: usize,
    /// Frames localised in the largest map.
    pub localized: usize,
    /// `localized / frames`.
    pub localized_ratio: f64,
    /// 3D points of the largest map.
    pub points: usize,
    /// Observations of the largest map.
    pub observations: usize,
    /// Mean track length of the largest map.
    pub mean_track_length: f64,
    /// Mean reprojection error (px) of the largest map.
    pub mean_reprojection_error: f64,
    /// Mean 3D points per keyframe of the largest map.
    pub points_per_image: f64,
    /// Every map, largest first.
    pub maps: Vec<MapSummary>,
    /// Frames localised in no map.
    pub not_localized: Vec<FrameId>,
    /// Keyframe candidates rejected as pure rotation.
    pub rejected_rotation: usize,
    /// Keyframes forced to keep tracking.
    pub forced_keyframes: usize,
    /// Keyframes deregistered by the point-count check.
    pub deregistered: usize,
    /// Keyframes culled as redundant (`--cull-keyframes`), all maps; their
    /// frames are localised like non-keyframes.
    pub culled_keyframes: usize,
    /// Loops closed by appearance (`--loop-closure`), all maps, in order.
    pub loops: Vec<crate::mapper::LoopClosure>,
    /// Keyframe candidates refused for too little rotation-compensated flow
    /// (`--parallax-threshold`).
    pub refused_parallax: usize,
    /// Keyframe observations moved by the observation refinement
    /// (`--refine-observations`).
    #[serde(default)]
    pub refined_observations: usize,
    /// Notable events.
    pub notes: Vec<String>,
    /// Per-stage wall times, seconds.
    pub timings_s: StageTimings,
    /// Wall time of the whole run, seconds (decode to outputs on disk).
    pub wall_time_s: f64,
    /// Wall time per frame, milliseconds.
    pub ms_per_frame: f64,
    /// Camera used (COLMAP model name and parameters, COLMAP pixel convention).
    pub camera: CameraSummary,
    /// Options of the run.
    pub options: SlamOptions,
    /// Whether the camera's focal length was guessed (no calibration given):
    /// intrinsics were then refined by bundle adjustment.
    pub camera_guessed: bool,
    /// Where the camera came from (file, preset, file beside the input,
    /// `--focal`, guessed); the camera the run ended with is `camera.yaml`.
    pub camera_source: Option<crate::run::CameraSource>,
    /// Whether the intrinsics were refined by bundle adjustment, and the
    /// focal length before and after.
    pub intrinsics: Option<IntrinsicsSummary>,
    /// Frames processed before a stop was requested, when one was.
    pub stopped_after: Option<usize>,
    /// The evaluation against ground truth (`--gt`), as printed.
    pub eval: Option<colslam_eval::EvalReport>,
}

impl RunReport {
    /// The run in one line, e.g. `38 of 40 frames localised, 6 keyframes,
    /// 1234 points, 1 map` (the numbers of the largest map; every front end
    /// that names a run's outcome uses this line).
    /// A run that closed loops says how many (`, 1 loop closed`).
    pub fn headline(&self) -> String {
        headline(self.localized, self.frames, self.keyframes, self.points, self.maps.len(), self.loops.len())
    }

    /// The headline and where the run's outputs are: the line that ends a
    /// run for scripts (`-q`) and in the viewer's status.
    pub fn outcome(&self, output: &std::path::Path) -> String {
        format!("{}; outputs in {}", self.headline(), output.display())
    }
}

/// What happened to the camera's focal length (see `RunReport::intrinsics`).
#[derive(Debug, Clone, Serialize)]
pub struct IntrinsicsSummary {
    /// Refined by bundle adjustment (a prior: `--focal`, EXIF, the guess;
    /// or `--refine-intrinsics`), or kept as given.
    pub refined: bool,
    /// Focal length the run started from, pixels.
    pub focal_start_px: f64,
    /// Focal length the largest map ended with, pixels.
    pub focal_end_px: f64,
    /// Registered keyframes of the largest map that constrained it.
    pub keyframes: usize,
}

/// A camera in the report.
#[derive(Debug, Clone, Serialize)]
pub struct CameraSummary {
    /// COLMAP model name.
    pub model: String,
    /// Width.
    pub width: u64,
    /// Height.
    pub height: u64,
    /// Parameters (after refinement, if enabled).
    pub params: Vec<f64>,
    /// Rolling-shutter readout the largest map was compensated with,
    /// seconds (0: none).
    pub readout_s: f64,
    /// Whether that readout was estimated (`--rolling-shutter auto`) rather
    /// than given.
    pub readout_estimated: bool,
}

/// Output format of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutputFormat {
    /// COLMAP binary (default).
    #[default]
    Binary,
    /// COLMAP text.
    Text,
}

fn summarize(m: &MapResult) -> MapSummary {
    let rec = m.map.reconstruction();
    MapSummary {
        index: m.map.index(),
        keyframes: rec.num_registered_images(),
        localized_frames: m.poses.len(),
        points: rec.num_points3d(),
        observations: rec.num_observations(),
        mean_track_length: rec.mean_track_length(),
        mean_reprojection_error: rec.mean_reprojection_error(),
        points_per_image: rec.mean_observations_per_registered_image(),
        frame_range: m.poses.first().zip(m.poses.last()).map(|(a, b)| (a.frame.index, b.frame.index)),
    }
}

fn trajectory(poses: &[FramePose], keyframes_only: bool) -> Trajectory {
    let sel: Vec<&FramePose> = poses.iter().filter(|p| !keyframes_only || p.keyframe).collect();
    Trajectory::from_cam_from_world(
        sel.iter().map(|p| p.frame.timestamp).collect(),
        &sel.iter().map(|p| p.cam_from_world).collect::<Vec<_>>(),
    )
}

/// The files and folders of a run's output folder besides the model files
/// ([`MODEL_FILE_NAMES`]).
const RUN_FILE_NAMES: [&str; 7] =
    ["maps", "trajectory.tum", "keyframes.tum", "points.ply", "camera.yaml", "report.json", "trajectory.eval.png"];

/// The names a run's output folder holds: what [`begin_run_output`] accepts
/// to replace.
pub const RUN_OUTPUT_NAMES: [&str; MODEL_FILE_NAMES.len() + RUN_FILE_NAMES.len()] = {
    let mut all = [""; MODEL_FILE_NAMES.len() + RUN_FILE_NAMES.len()];
    let mut i = 0;
    while i < all.len() {
        all[i] =
            if i < MODEL_FILE_NAMES.len() { MODEL_FILE_NAMES[i] } else { RUN_FILE_NAMES[i - MODEL_FILE_NAMES.len()] };
        i += 1;
    }
    all
};

/// Starts writing the run output folder `out` as a whole: checks that it
/// can be written (a folder, or missing, not under a file, holding nothing
/// but a run's outputs), takes its lock (a second run or export into it is
/// refused while this one lives) and creates the staging folder to write
/// into. [`OutputDir::commit`] puts the outputs in place.
pub fn begin_run_output(out: &Path) -> Result<OutputDir, SlamError> {
    Ok(OutputDir::begin(out, &RUN_OUTPUT_NAMES)?)
}

fn create_dir(dir: &Path) -> Result<(), SlamError> {
    std::fs::create_dir_all(dir).map_err(|source| SlamError::Io { path: dir.to_path_buf(), source })
}

/// Writes the camera the run ended with (refined when intrinsics were, with
/// the readout its rolling-shutter compensation used) as `camera.yaml`, a
/// camera file that `--camera` reads back (OpenCV's pixel convention);
/// nothing without a map. Refined intrinsics say over how many registered
/// images (`refined_over`), so that a run given the file refines them
/// again as this one did, from where it ended.
fn write_camera_file(result: &SlamResult, opts: &SlamOptions, out: &Path) -> Result<(), SlamError> {
    let Some((map, camera)) = result.maps.first().and_then(|m| m.map.camera().ok().map(|c| (m, c))) else {
        return Ok(());
    };
    let opencv = camera.convert_pixel_convention(PixelConvention::Colmap, PixelConvention::OpenCv);
    let path = out.join("camera.yaml");
    let refined_over = opts.refine.refine_intrinsics.then(|| map.map.reconstruction().num_registered_images());
    let text = to_run_yaml_string(&opencv, map.readout_s, refined_over);
    colslam_image::write_atomic(&path, text.as_bytes()).map_err(|source| SlamError::Io { path, source })
}

/// The report's camera: the first map's (empty without a map) and the
/// readout its rolling-shutter compensation used.
fn camera_summary(result: &SlamResult, opts: &SlamOptions) -> CameraSummary {
    let first = result.maps.first();
    let empty = CameraSummary {
        model: String::new(),
        width: 0,
        height: 0,
        params: Vec::new(),
        readout_s: 0.0,
        readout_estimated: false,
    };
    let Some((map, camera)) = first.and_then(|m| m.map.camera().ok().map(|c| (m, c))) else {
        return empty;
    };
    CameraSummary {
        model: camera.model.name().to_string(),
        width: camera.width,
        height: camera.height,
        params: camera.params.clone(),
        readout_s: map.readout_s,
        readout_estimated: opts.refine.rolling_shutter == crate::options::RollingShutter::Auto,
    }
}

/// Writes every output of `result` but the report into the folder `out`
/// (the staging folder of [`begin_run_output`]) and returns the report
/// (without wall time, stop and evaluation, which the driver fills in
/// before it writes it with [`write_report`]).
pub fn write_outputs(
    result: &SlamResult,
    out: &Path,
    input: &str,
    opts: &SlamOptions,
    format: OutputFormat,
) -> Result<RunReport, SlamError> {
    create_dir(out)?;
    let fmt = match format {
        OutputFormat::Binary => ModelFormat::Binary,
        OutputFormat::Text => ModelFormat::Text,
    };
    for (k, m) in result.maps.iter().enumerate() {
        let dir = if k == 0 { out.to_path_buf() } else { out.join("maps").join(k.to_string()) };
        create_dir(&dir)?;
        write_model_files(m.map.reconstruction(), &dir, fmt)?;
        write_ply(m.map.reconstruction(), &dir.join("points.ply"))?;
        trajectory(&m.poses, false).write_tum(&dir.join("trajectory.tum"))?;
        trajectory(&m.poses, true).write_tum(&dir.join("keyframes.tum"))?;
    }
    if result.maps.is_empty() {
        // Still write empty trajectories so consumers find the files.
        Trajectory::default().write_tum(&out.join("trajectory.tum"))?;
        Trajectory::default().write_tum(&out.join("keyframes.tum"))?;
    }
    write_camera_file(result, opts, out)?;
    let maps: Vec<MapSummary> = result.maps.iter().map(summarize).collect();
    let first = maps.first();
    let camera = camera_summary(result, opts);
    let frames = result.frames.len();
    let localized = first.map_or(0, |m| m.localized_frames);
    Ok(RunReport {
        input: input.to_string(),
        frames,
        keyframes: first.map_or(0, |m| m.keyframes),
        localized,
        localized_ratio: if frames == 0 { 0.0 } else { localized as f64 / frames as f64 },
        points: first.map_or(0, |m| m.points),
        observations: first.map_or(0, |m| m.observations),
        mean_track_length: first.map_or(0.0, |m| m.mean_track_length),
        mean_reprojection_error: first.map_or(0.0, |m| m.mean_reprojection_error),
        points_per_image: first.map_or(0.0, |m| m.points_per_image),
        maps,
        not_localized: result.not_localized.clone(),
        rejected_rotation: result.stats.rejected_rotation,
        forced_keyframes: result.stats.forced_keyframes,
        deregistered: result.stats.deregistered,
        culled_keyframes: result.maps.iter().map(|m| m.map.culled_keyframes()).sum(),
        loops: result.maps.iter().flat_map(|m| m.map.loops().iter().cloned()).collect(),
        refused_parallax: result.stats.refused_parallax,
        refined_observations: result.stats.refined_observations,
        notes: result.stats.notes.clone(),
        timings_s: result.timings.clone(),
        wall_time_s: 0.0,
        ms_per_frame: 0.0,
        camera,
        options: opts.clone(),
        camera_guessed: false,
        camera_source: None,
        intrinsics: None,
        stopped_after: None,
        eval: None,
    })
}

/// [`RunReport::headline`] from its numbers.
fn headline(localized: usize, frames: usize, keyframes: usize, points: usize, maps: usize, loops: usize) -> String {
    let plural = |n: usize| if n == 1 { "" } else { "s" };
    let mut line = format!(
        "{localized} of {frames} frames localised, {keyframes} keyframes, {points} points, {maps} map{}",
        plural(maps)
    );
    if loops > 0 {
        line.push_str(&format!(", {loops} loop{} closed", plural(loops)));
    }
    line
}

/// Writes `report.json` atomically.
pub fn write_report(report: &RunReport, out: &Path) -> Result<(), SlamError> {
    let path = out.join("report.json");
    let mut text = serde_json::to_string_pretty(report)?;
    text.push('\n');
    colslam_image::write_atomic(&path, text.as_bytes()).map_err(|source| SlamError::Io { path, source })
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_headline_names_the_loops_closed() {
        assert_eq!(
            super::headline(38, 40, 6, 1234, 1, 0),
            "38 of 40 frames localised, 6 keyframes, 1234 points, 1 map"
        );
        assert_eq!(
            super::headline(38, 40, 6, 1234, 2, 1),
            "38 of 40 frames localised, 6 keyframes, 1234 points, 2 maps, 1 loop closed"
        );
        assert!(super::headline(3000, 3000, 198, 9000, 1, 2).ends_with(", 2 loops closed"));
    }
}
