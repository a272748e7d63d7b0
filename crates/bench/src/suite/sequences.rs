//! The sequences of the quick and full suites.

use anyhow::{Context, Result, bail};
use colslam_synth::SynthOptions;
use std::path::{Path, PathBuf};

/// Synthetic lengths of the quick suite.
pub const QUICK_SYNTHETIC_FRAMES: [usize; 2] = [60, 150];
/// Synthetic lengths of the full suite.
pub const FULL_SYNTHETIC_FRAMES: [usize; 3] = [60, 150, 300];
/// Name prefix of synthetic sequences (`synthetic-<frames>`).
pub const SYNTHETIC_PREFIX: &str = "synthetic-";
/// The TUM sequence of the suites and the sweeps.
pub const TUM_SEQUENCE: &str = "tum_fr1_rpy_sub";
/// The Strecha sequence of the quick suite.
pub const QUICK_STRECHA: &str = "strecha_fountain_P11";
/// All Strecha sequences (full suite).
pub const STRECHA_SEQUENCES: [&str; 4] =
    ["strecha_fountain_P11", "strecha_herzjesu_P25", "strecha_castle_P19", "strecha_entry_P10"];
/// The KITTI clip: folder and file (no ground truth, camera preset).
pub const KITTI_FOLDER: &str = colslam_testutil::KITTI_CLIP_FOLDER;
/// The video inside [`KITTI_FOLDER`].
pub const KITTI_VIDEO: &str = colslam_testutil::KITTI_CLIP_VIDEO;
/// Camera preset of the KITTI clip (focal 984 px).
pub const KITTI_PRESET: &str = "kitti-984";

/// Rolling-shutter readout of the TUM fr1 camera (a Kinect v1 RGB sensor
/// streaming 30 frames per second, read out row by row over one frame
/// period): 1/30 s.
pub const TUM_FR1_READOUT_S: f64 = 1.0 / 30.0;

/// How the camera of a sequence is given to `colslam run`.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraSpec {
    /// The camera file beside the input.
    Auto,
    /// A built-in preset.
    Preset(String),
}

/// One sequence of a suite.
#[derive(Debug, Clone)]
pub struct Sequence {
    /// Name in the report.
    pub name: String,
    /// Input of `colslam run` (folder or video).
    pub input: PathBuf,
    /// Ground truth (TUM), if any.
    pub gt: Option<PathBuf>,
    /// Camera.
    pub camera: CameraSpec,
    /// Set for synthetic sequences: generated into `input` before running.
    pub synth: Option<SynthOptions>,
    /// Given by the user (`--sequence`): run even when the input is missing,
    /// so that the run's own error shows as a failure row.
    pub user: bool,
    /// Rolling-shutter readout time of its camera, seconds (`colslam run
    /// --rolling-shutter`), when known.
    pub rolling_shutter: Option<f64>,
}

impl Sequence {
    /// A real sequence in TUM layout under `data` (ground truth when present).
    fn tum_layout(data: &Path, name: &str) -> Self {
        let dir = data.join(name);
        let gt = dir.join("groundtruth.txt");
        Sequence {
            name: name.to_string(),
            gt: Some(gt),
            input: dir,
            camera: CameraSpec::Auto,
            synth: None,
            user: false,
            rolling_shutter: name.starts_with("tum_fr1").then_some(TUM_FR1_READOUT_S),
        }
    }

    /// A user-given sequence: ground truth when `groundtruth.txt` lies in it.
    pub fn user(path: &Path) -> Self {
        let name = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        let gt = path.join("groundtruth.txt");
        Sequence {
            name,
            input: path.to_path_buf(),
            gt: gt.is_file().then_some(gt),
            camera: CameraSpec::Auto,
            synth: None,
            user: true,
            rolling_shutter: None,
        }
    }

    /// A synthetic sequence with `frames` frames, generated under `gen_dir`.
    pub fn synthetic(frames: usize, size: Option<(usize, usize)>, gen_dir: &Path) -> Self {
        let mut o = SynthOptions { frames, ..SynthOptions::default() };
        if let Some((w, h)) = size {
            o.width = w;
            o.height = h;
        }
        let name = format!("{SYNTHETIC_PREFIX}{frames}");
        let dir = gen_dir.join(&name);
        Sequence {
            name,
            gt: Some(dir.join("groundtruth.txt")),
            input: dir,
            camera: CameraSpec::Auto,
            synth: Some(o),
            user: false,
            rolling_shutter: None,
        }
    }

    /// Whether the sequence is in TUM layout (rgb.txt and camera.yaml), as the
    /// Python peers need.
    pub fn has_tum_layout(&self) -> bool {
        self.input.join("rgb.txt").is_file() && self.input.join("camera.yaml").is_file()
    }
}

/// The datasets folder: `--data`, else the shared lookup
/// ([`colslam_testutil::find_data_dir`]), else `datasets` (whose sequences
/// then show as not found).
pub fn data_dir(arg: Option<&Path>) -> PathBuf {
    if let Some(d) = arg {
        return d.to_path_buf();
    }
    colslam_testutil::find_data_dir().unwrap_or_else(|e| {
        tracing::warn!("{e:#}");
        PathBuf::from("datasets")
    })
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> Result<(usize, usize)> {
    let (w, h) = s.split_once('x').with_context(|| format!("size {s:?} is not WIDTHxHEIGHT"))?;
    let w: usize = w.trim().parse().with_context(|| format!("width in {s:?}"))?;
    let h: usize = h.trim().parse().with_context(|| format!("height in {s:?}"))?;
    if w == 0 || h == 0 {
        bail!("size {s:?} has a zero side");
    }
    Ok((w, h))
}

/// The sequences of `suite` that `only` names (all when empty), from the
/// datasets in `data` (default: [`data_dir`]'s), the synthetic ones
/// generated under `out/data` at `size`.
pub fn selected(
    suite: &str,
    data: Option<&Path>,
    only: &[String],
    size: Option<(usize, usize)>,
    out: &Path,
) -> Result<Vec<Sequence>> {
    let gen_dir = out.join("data");
    let all = suite_sequences(suite, &data_dir(data), size, &gen_dir)?;
    restrict(all, only, size, &gen_dir)
}

/// The sequences of `suite` ("quick" or "full").
pub fn suite_sequences(
    suite: &str,
    data: &Path,
    size: Option<(usize, usize)>,
    gen_dir: &Path,
) -> Result<Vec<Sequence>> {
    let (synth, strecha): (&[usize], &[&str]) = match suite {
        "quick" => (&QUICK_SYNTHETIC_FRAMES, &[QUICK_STRECHA]),
        "full" => (&FULL_SYNTHETIC_FRAMES, &STRECHA_SEQUENCES),
        other => bail!("unknown suite {other:?} (quick or full)"),
    };
    let mut v: Vec<Sequence> = synth.iter().map(|&n| Sequence::synthetic(n, size, gen_dir)).collect();
    v.push(Sequence::tum_layout(data, TUM_SEQUENCE));
    v.extend(strecha.iter().map(|s| Sequence::tum_layout(data, s)));
    v.push(Sequence {
        name: KITTI_FOLDER.to_string(),
        input: data.join(KITTI_FOLDER).join(KITTI_VIDEO),
        gt: None,
        camera: CameraSpec::Preset(KITTI_PRESET.to_string()),
        synth: None,
        user: false,
        rolling_shutter: None,
    });
    Ok(v)
}

/// Restricts `all` to the names in `only` (empty: keep all). A name
/// `synthetic-<N>` not in the suite adds that synthetic sequence; any other
/// unknown name is an error.
pub fn restrict(
    all: Vec<Sequence>,
    only: &[String],
    size: Option<(usize, usize)>,
    gen_dir: &Path,
) -> Result<Vec<Sequence>> {
    if only.is_empty() {
        return Ok(all);
    }
    let mut out = Vec::new();
    for name in only {
        if let Some(s) = all.iter().find(|s| &s.name == name) {
            out.push(s.clone());
        } else if let Some(n) = name.strip_prefix(SYNTHETIC_PREFIX) {
            let frames: usize = n.parse().with_context(|| format!("--only {name:?}: frames must be a number"))?;
            if frames == 0 {
                bail!("--only {name:?}: a synthetic sequence needs at least one frame");
            }
            out.push(Sequence::synthetic(frames, size, gen_dir));
        } else {
            let known: Vec<&str> = all.iter().map(|s| s.name.as_str()).collect();
            bail!(
                "--only {name:?}: no such sequence in this suite (known: {}, or synthetic-<frames>)",
                known.join(", ")
            );
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suites_and_restriction() {
        let data = Path::new("/data");
        let gen_dir = Path::new("/gen");
        let q = suite_sequences("quick", data, None, gen_dir).unwrap();
        let names: Vec<&str> = q.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["synthetic-60", "synthetic-150", TUM_SEQUENCE, QUICK_STRECHA, KITTI_FOLDER]);
        let f = suite_sequences("full", data, None, gen_dir).unwrap();
        assert_eq!(f.len(), 3 + 1 + 4 + 1);
        assert!(suite_sequences("medium", data, None, gen_dir).is_err());
        let kitti = q.iter().find(|s| s.name == KITTI_FOLDER).unwrap();
        assert!(kitti.gt.is_none());
        assert_eq!(kitti.camera, CameraSpec::Preset(KITTI_PRESET.into()));

        let r = restrict(q.clone(), &["synthetic-40".into(), TUM_SEQUENCE.into()], Some((320, 240)), gen_dir).unwrap();
        assert_eq!(r.len(), 2);
        let s = r[0].synth.as_ref().unwrap();
        assert_eq!((s.frames, s.width, s.height), (40, 320, 240));
        assert!(restrict(q.clone(), &["nope".into()], None, gen_dir).is_err());
        assert!(restrict(q, &["synthetic-x".into()], None, gen_dir).is_err());
    }

    #[test]
    fn sizes() {
        assert_eq!(parse_size("320x240").unwrap(), (320, 240));
        assert!(parse_size("320").is_err());
        assert!(parse_size("0x240").is_err());
    }
}
