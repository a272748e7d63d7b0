//! Camera files: flat `key: value` YAML (as the datasets' `camera.yaml`),
//! the same with `key = value` (TOML-style) lines, and ORB-SLAM/OpenCV
//! `%YAML:1.0` settings files.
//!
//! Accepted content (keys are case-insensitive; `#` starts a comment; values
//! may be quoted; unknown keys are ignored and listed in the report):
//!
//! * `model:` a COLMAP model name (`SIMPLE_PINHOLE` ... `FULL_OPENCV`) or
//!   numeric id, with the model's parameters either as named keys (COLMAP's
//!   names: `f`, `fx`, `fy`, `cx`, `cy`, `k`, `k1` ... `k6`, `p1`, `p2`) or as
//!   `params: [..]` in COLMAP order.
//! * `model: PINHOLE_RADTAN` (also `RADTAN`, `PLUMB_BOB`, `BROWN`, and
//!   ORB-SLAM's `PinHole`) with `fx fy cx cy k1 k2 p1 p2` and optional
//!   `k3` (and `k4..k6`): FULL_OPENCV, or OPENCV when `k3..k6` are all zero.
//!   `PINHOLE` with distortion keys that are not all zero is read the same
//!   way, so distortion is never dropped silently.
//! * `model: KANNALA_BRANDT` (also `KannalaBrandt8`, `EQUIDISTANT`,
//!   `FISHEYE`) with `fx fy cx cy k1 k2 k3 k4`: OPENCV_FISHEYE.
//! * `width`, `height` (also `image_width`, `image_height`): positive integers.
//! * ORB-SLAM files (recognised by `Camera.`/`Camera1.` keys): keys
//!   `Camera.fx` / `Camera1.fx` (prefix stripped;
//!   `Camera2.*` of stereo rigs ignored), `Camera.width`, `Camera.height`,
//!   `Camera.type` (default `PinHole`); indented and continuation lines
//!   (OpenCV matrices) are skipped.
//! * Kalibr / EuRoC `sensor.yaml`: `camera_model: pinhole`,
//!   `resolution: [w, h]`, `intrinsics: [fx, fy, cx, cy]`,
//!   `distortion_model: radial-tangential | equidistant | none` and
//!   `distortion_coefficients: [..]`; `rate_hz` is ignored.
//! * `fps` is reported if present.
//! * `readout_s`: the rolling-shutter readout time in seconds (first row to
//!   last), in [0, 1); colslam writes it beside a run's outputs when the run
//!   compensated one, so the file reproduces the run.
//! * `refined_over`: a positive integer, the registered images of the map
//!   whose bundle adjustments refined these intrinsics; colslam writes it
//!   when a run refined them (a camera without calibration), and a run given
//!   the file refines them again from there, its maps holding them until
//!   they have as many images.
//!
//! Every error names the file and the key (see [`CameraError::File`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::{Camera, CameraError, CameraModelId};

/// Which syntax a camera file used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraFileFormat {
    /// Flat `key: value` YAML.
    FlatYaml,
    /// `key = value` lines (TOML-style).
    Toml,
    /// ORB-SLAM / OpenCV settings with `Camera.fx: ...` / `Camera1.fx: ...`
    /// keys (usually with a `%YAML:1.0` header).
    OrbSlam,
}

/// A parsed camera file.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFile {
    /// The camera (validated).
    pub camera: Camera,
    /// The syntax detected.
    pub format: CameraFileFormat,
    /// Frame rate, if the file gives `fps`.
    pub fps: Option<f64>,
    /// Rolling-shutter readout time in seconds, if the file gives
    /// `readout_s`.
    pub readout_s: Option<f64>,
    /// Registered images of the map that refined these intrinsics, if the
    /// file gives `refined_over`.
    pub refined_over: Option<usize>,
    /// Keys present in the file but not used (as written).
    pub unknown_keys: Vec<String>,
}

/// One `key: value` entry.
#[derive(Debug, Clone)]
struct Entry {
    /// The key as written (for error messages).
    key: String,
    value: String,
}

/// Reads a camera file; see the module docs for the accepted formats.
pub fn read_camera_file(path: &Path) -> Result<Camera, CameraError> {
    Ok(read_camera_file_report(path)?.camera)
}

/// Reads a camera file and reports the format, `fps` and unused keys.
pub fn read_camera_file_report(path: &Path) -> Result<CameraFile, CameraError> {
    let bytes = std::fs::read(path).map_err(|source| CameraError::Io {
        path: path.to_path_buf(),
        action: "cannot read camera file",
        source,
    })?;
    let text = String::from_utf8(bytes).map_err(|_| CameraError::File {
        path: path.to_path_buf(),
        key: "(file)".into(),
        reason: "is not UTF-8 text".into(),
    })?;
    parse_camera(&text, path)
}

/// Parses camera-file text; `origin` names the source in errors.
pub fn parse_camera(text: &str, origin: &Path) -> Result<CameraFile, CameraError> {
    let mut p = Parser::new(text, origin)?;
    p.build()
}

/// Writes `cam` as a flat YAML camera file with COLMAP's model name and
/// parameter names, atomically (temp file then rename). Values are written
/// with Rust's shortest round-trip formatting, so reading the file back
/// gives the identical camera.
pub fn write_camera_file(cam: &Camera, path: &Path) -> Result<(), CameraError> {
    cam.validate().map_err(|e| file_error_from_validation(path, e, &BTreeMap::new()))?;
    let text = to_yaml_string(cam);
    colslam_image::write_atomic(path, text.as_bytes()).map_err(|source| CameraError::Io {
        path: path.to_path_buf(),
        action: "cannot write camera file",
        source,
    })
}

/// The flat YAML text [`write_camera_file`] writes.
pub fn to_yaml_string(cam: &Camera) -> String {
    let mut s = String::new();
    s.push_str(&format!("# colslam camera file: COLMAP model {} ({})\n", cam.model.name(), cam.model.param_names()));
    s.push_str(&format!("model: {}\n", cam.model.name()));
    s.push_str(&format!("width: {}\n", cam.width));
    s.push_str(&format!("height: {}\n", cam.height));
    for (name, v) in cam.model.param_name_list().zip(&cam.params) {
        s.push_str(&format!("{name}: {v:?}\n"));
    }
    s
}

/// [`to_yaml_string`] followed by what a run adds: the rolling-shutter
/// readout time (the `readout_s` key) when one was compensated
/// (`readout_s > 0`), and the registered images the intrinsics were refined
/// over (`refined_over`) when they were.
pub fn to_run_yaml_string(cam: &Camera, readout_s: f64, refined_over: Option<usize>) -> String {
    let mut s = to_yaml_string(cam);
    if readout_s > 0.0 {
        s.push_str(&format!("readout_s: {readout_s:?}\n"));
    }
    if let Some(n) = refined_over {
        s.push_str(&format!("refined_over: {n}\n"));
    }
    s
}

/// Model families a file can name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ModelSpec {
    Colmap(CameraModelId),
    RadTan,
    KannalaBrandt,
}

fn model_spec(name: &str) -> Option<ModelSpec> {
    let n = name.trim().to_ascii_uppercase().replace(['-', ' '], "_");
    if let Ok(id) = n.parse::<i32>() {
        return CameraModelId::from_id(id).map(ModelSpec::Colmap);
    }
    match n.as_str() {
        "PINHOLE_RADTAN" | "RADTAN" | "PLUMB_BOB" | "BROWN" | "BROWN_CONRADY" | "PINHOLE_RADIAL_TANGENTIAL" => {
            Some(ModelSpec::RadTan)
        }
        "KANNALABRANDT8" | "KANNALA_BRANDT" | "KANNALA_BRANDT8" | "EQUIDISTANT" | "FISHEYE" | "PINHOLE_EQUI" => {
            Some(ModelSpec::KannalaBrandt)
        }
        _ => CameraModelId::from_name(&n).map(ModelSpec::Colmap),
    }
}

/// Distortion keys whose presence turns `PINHOLE` into a radial-tangential model.
const RADTAN_KEYS: [&str; 8] = ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"];

struct Parser {
    path: PathBuf,
    format: CameraFileFormat,
    /// Normalised key -> entry.
    entries: BTreeMap<String, Entry>,
    used: std::collections::BTreeSet<String>,
}

/// Removes a trailing `# comment` (a `#` at the start or after whitespace,
/// outside quotes).
fn strip_comment(line: &str) -> &str {
    let mut in_quote: Option<char> = None;
    let mut prev_ws = true;
    for (i, ch) in line.char_indices() {
        match in_quote {
            Some(q) if ch == q => in_quote = None,
            Some(_) => {}
            None if ch == '"' || ch == '\'' => in_quote = Some(ch),
            None if ch == '#' && prev_ws => return line.get(..i).unwrap_or(line),
            None => {}
        }
        prev_ws = ch.is_whitespace();
    }
    line
}

fn unquote(v: &str) -> &str {
    let v = v.trim();
    for q in ['"', '\''] {
        if let Some(inner) = v.strip_prefix(q).and_then(|s| s.strip_suffix(q)) {
            return inner.trim();
        }
    }
    v
}

impl Parser {
    fn new(text: &str, origin: &Path) -> Result<Self, CameraError> {
        let path = origin.to_path_buf();
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let first = text.lines().map(str::trim).find(|l| !l.is_empty());
        let orb_keys = text.lines().any(|l| {
            let t = l.trim_start().to_ascii_lowercase();
            t.starts_with("camera.") || t.starts_with("camera1.")
        });
        // `%YAML:1.0` alone does not make an ORB-SLAM file: EuRoC's Kalibr
        // `sensor.yaml` has the header but flat keys.
        let yaml_header = first.is_some_and(|l| l.starts_with("%YAML"));
        let format = if orb_keys {
            CameraFileFormat::OrbSlam
        } else {
            // The first key line decides between ':' and '='.
            let eq = text
                .lines()
                .map(|l| strip_comment(l).trim())
                .find(|l| !l.is_empty() && !l.starts_with('[') && !l.starts_with("---"))
                .is_some_and(|l| match (l.find(':'), l.find('=')) {
                    (Some(c), Some(e)) => e < c,
                    (None, Some(_)) => true,
                    _ => false,
                });
            if eq && !yaml_header { CameraFileFormat::Toml } else { CameraFileFormat::FlatYaml }
        };
        let mut entries = BTreeMap::new();
        for (lineno, raw) in text.lines().enumerate() {
            let line_no = lineno + 1;
            let stripped = strip_comment(raw);
            let line = stripped.trim();
            if line.is_empty() || line.starts_with('%') || line == "---" || line == "..." {
                continue;
            }
            // TOML table headers; YAML indentation or continuation lines
            // (nested maps, OpenCV matrices) are not part of a flat file.
            let indented = raw.starts_with([' ', '\t']);
            if line.starts_with('[') && line.ends_with(']') && !line.contains([':', '=']) {
                continue;
            }
            let sep = match format {
                CameraFileFormat::Toml => '=',
                _ => ':',
            };
            // Nested YAML blocks and continuation lines of multi-line lists
            // (OpenCV/Kalibr matrices) are indented; none carries intrinsics.
            if indented {
                continue;
            }
            let split = line.split_once(sep);
            if format == CameraFileFormat::OrbSlam && split.is_none() {
                continue;
            }
            let Some((k, v)) = split else {
                return Err(CameraError::File {
                    path,
                    key: format!("(line {line_no})"),
                    reason: format!("expected `key{}value`, got {:?}", if sep == '=' { " = " } else { ": " }, line),
                });
            };
            let key_written = unquote(k).to_string();
            let mut norm = key_written.to_ascii_lowercase();
            if format == CameraFileFormat::OrbSlam {
                if let Some(rest) = norm.strip_prefix("camera.").or_else(|| norm.strip_prefix("camera1.")) {
                    norm = rest.to_string();
                } else {
                    // Not a camera key (ORBextractor.*, Viewer.*, Camera2.*, ...).
                    norm = format!("\u{0}{norm}");
                }
            }
            let value = v.trim();
            // ORB-SLAM writes OpenCV matrices as `key: !!opencv-matrix`.
            let value = unquote(value).to_string();
            if entries.contains_key(&norm) && !norm.starts_with('\u{0}') {
                return Err(CameraError::File { path, key: key_written, reason: "appears more than once".into() });
            }
            entries.insert(norm, Entry { key: key_written, value });
        }
        Ok(Self { path, format, entries, used: Default::default() })
    }

    fn err(&self, key: &str, reason: impl Into<String>) -> CameraError {
        CameraError::File { path: self.path.clone(), key: key.to_string(), reason: reason.into() }
    }

    /// How a normalised key is written in this file (for error messages).
    fn written(&self, norm: &str) -> String {
        match self.entries.get(norm) {
            Some(e) => e.key.clone(),
            None if self.format == CameraFileFormat::OrbSlam => format!("Camera.{norm}"),
            None => norm.to_string(),
        }
    }

    fn raw(&mut self, norm: &str) -> Option<Entry> {
        let e = self.entries.get(norm).cloned();
        if e.is_some() {
            self.used.insert(norm.to_string());
        }
        e
    }

    /// First present key among `aliases`.
    fn raw_any(&mut self, aliases: &[&str]) -> Option<Entry> {
        aliases.iter().find_map(|a| self.raw(a))
    }

    fn number(&self, e: &Entry) -> Result<f64, CameraError> {
        let v: f64 = e.value.parse().map_err(|_| self.err(&e.key, format!("expected a number, got {:?}", e.value)))?;
        if !v.is_finite() {
            return Err(self.err(&e.key, format!("value {} is not finite", e.value)));
        }
        Ok(v)
    }

    fn required_number(&mut self, norm: &str, model: &str) -> Result<f64, CameraError> {
        match self.raw(norm) {
            Some(e) => self.number(&e),
            None => Err(self.err(&self.written(norm), format!("missing parameter (required by model {model})"))),
        }
    }

    fn optional_number(&mut self, norm: &str) -> Result<Option<f64>, CameraError> {
        match self.raw(norm) {
            Some(e) => self.number(&e).map(Some),
            None => Ok(None),
        }
    }

    fn size(&mut self, aliases: &[&str]) -> Result<u64, CameraError> {
        let Some(e) = self.raw_any(aliases) else {
            return Err(self.err(&self.written(aliases.first().copied().unwrap_or("width")), "missing image size"));
        };
        let v: f64 =
            e.value.parse().map_err(|_| self.err(&e.key, format!("expected a positive integer, got {:?}", e.value)))?;
        if !(v.is_finite() && v >= 1.0 && v.fract() == 0.0 && v <= u32::MAX as f64) {
            return Err(self.err(&e.key, format!("expected a positive integer, got {}", e.value)));
        }
        Ok(v as u64)
    }

    /// Kalibr / EuRoC `sensor.yaml` lists: `resolution: [w, h]`,
    /// `intrinsics: [fx, fy, cx, cy]`, `distortion_model` and
    /// `distortion_coefficients: [..]` become the named keys. Returns the
    /// model family the distortion model implies, if any.
    fn expand_kalibr(&mut self) -> Result<Option<ModelSpec>, CameraError> {
        let synth = |p: &mut Self, list_key: &str, names: &[&str]| -> Result<bool, CameraError> {
            let Some(e) = p.entries.get(list_key).cloned() else { return Ok(false) };
            if names.iter().any(|n| p.entries.contains_key(*n)) {
                return Ok(false);
            }
            let list = p.number_list(&e)?;
            if list.len() != names.len() {
                return Err(p.err(
                    &e.key,
                    format!("expected {} values ({}), got {}", names.len(), names.join(", "), list.len()),
                ));
            }
            p.used.insert(list_key.to_string());
            for (n, v) in names.iter().zip(list) {
                let key = format!("{}[{n}]", e.key);
                p.entries.insert(n.to_string(), Entry { key, value: format!("{v:?}") });
            }
            Ok(true)
        };
        synth(self, "resolution", &["width", "height"])?;
        synth(self, "intrinsics", &["fx", "fy", "cx", "cy"])?;
        let Some(dm) = self.raw("distortion_model") else { return Ok(None) };
        let spec = match dm.value.to_ascii_lowercase().replace('_', "-").as_str() {
            "radtan" | "radial-tangential" | "plumb-bob" => ModelSpec::RadTan,
            "equidistant" | "equi" | "kannala-brandt" => ModelSpec::KannalaBrandt,
            "none" | "" => return Ok(None),
            other => return Err(self.err(&dm.key, format!("unknown distortion model {other:?}"))),
        };
        let names: &[&str] = match spec {
            ModelSpec::KannalaBrandt => &["k1", "k2", "k3", "k4"],
            _ => match self.entries.get("distortion_coefficients").map(|e| self.number_list(e)).transpose()? {
                Some(l) if l.len() == 5 => &["k1", "k2", "p1", "p2", "k3"],
                _ => &["k1", "k2", "p1", "p2"],
            },
        };
        synth(self, "distortion_coefficients", names)?;
        Ok(Some(spec))
    }

    fn build(&mut self) -> Result<CameraFile, CameraError> {
        let kalibr = self.expand_kalibr()?;
        let model_entry = self.raw_any(&["model", "camera_model", "type", "model_name"]);
        let spec = match &model_entry {
            Some(e) => model_spec(&e.value).ok_or_else(|| {
                self.err(
                    &e.key,
                    format!(
                        "unknown camera model {:?} (expected a COLMAP model name such as PINHOLE or FULL_OPENCV, \
                         PINHOLE_RADTAN, or KANNALA_BRANDT)",
                        e.value
                    ),
                )
            })?,
            None if self.format == CameraFileFormat::OrbSlam => ModelSpec::Colmap(CameraModelId::Pinhole),
            None => return Err(self.err("model", "missing camera model")),
        };
        // Kalibr: `camera_model: pinhole` plus a distortion model.
        let spec = match (spec, kalibr) {
            (ModelSpec::Colmap(CameraModelId::Pinhole), Some(k)) => k,
            (s, _) => s,
        };
        let model_name = model_entry.as_ref().map(|e| e.value.clone()).unwrap_or_else(|| "PinHole".into());
        let width = self.size(&["width", "image_width"])?;
        let height = self.size(&["height", "image_height"])?;
        let fps = match self.raw("fps") {
            Some(e) => Some(self.number(&e)?),
            None => None,
        };
        let readout_s = match self.raw("readout_s") {
            Some(e) => {
                let r = self.number(&e)?;
                if !(0.0..1.0).contains(&r) {
                    return Err(self.err(&e.key, format!("must be a readout time in seconds in [0, 1), got {r}")));
                }
                Some(r)
            }
            None => None,
        };
        let refined_over = match self.raw("refined_over") {
            Some(_) => Some(self.size(&["refined_over"])? as usize),
            None => None,
        };

        // PINHOLE plus non-zero distortion keys is a radial-tangential camera.
        let spec = if spec == ModelSpec::Colmap(CameraModelId::Pinhole) && !self.entries.contains_key("params") {
            let mut any_nonzero = false;
            for k in RADTAN_KEYS {
                if let Some(e) = self.entries.get(k).cloned() {
                    any_nonzero |= self.number(&e)? != 0.0;
                }
            }
            if any_nonzero { ModelSpec::RadTan } else { spec }
        } else {
            spec
        };

        // Map from COLMAP parameter name to the key written in the file.
        let mut written = BTreeMap::new();
        let (model, params) = match spec {
            ModelSpec::Colmap(m) => {
                if let Some(e) = self.raw("params") {
                    let list = self.number_list(&e)?;
                    if list.len() != m.num_params() {
                        return Err(self.err(
                            &e.key,
                            format!(
                                "model {} takes {} parameters ({}), got {}",
                                m.name(),
                                m.num_params(),
                                m.param_names(),
                                list.len()
                            ),
                        ));
                    }
                    for n in m.param_name_list() {
                        written.insert(n.to_string(), format!("{} ({n})", e.key));
                    }
                    (m, list)
                } else {
                    let mut params = Vec::with_capacity(m.num_params());
                    for n in m.param_name_list() {
                        params.push(self.required_number(n, m.name())?);
                        written.insert(n.to_string(), self.written(n));
                    }
                    // PINHOLE with all-zero distortion keys: those keys are used.
                    for k in RADTAN_KEYS {
                        if self.entries.contains_key(k) && m == CameraModelId::Pinhole {
                            self.used.insert(k.to_string());
                        }
                    }
                    (m, params)
                }
            }
            ModelSpec::RadTan => {
                let mut v = Vec::with_capacity(12);
                for n in ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"] {
                    v.push(self.required_number(n, &model_name)?);
                    written.insert(n.to_string(), self.written(n));
                }
                let mut high = [0.0; 4];
                for (slot, n) in high.iter_mut().zip(["k3", "k4", "k5", "k6"]) {
                    *slot = self.optional_number(n)?.unwrap_or(0.0);
                    written.insert(n.to_string(), self.written(n));
                }
                if high.iter().all(|&k| k == 0.0) {
                    (CameraModelId::OpenCv, v)
                } else {
                    v.extend_from_slice(&high);
                    (CameraModelId::FullOpenCv, v)
                }
            }
            ModelSpec::KannalaBrandt => {
                let mut v = Vec::with_capacity(8);
                for n in ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"] {
                    v.push(self.required_number(n, &model_name)?);
                    written.insert(n.to_string(), self.written(n));
                }
                (CameraModelId::OpenCvFisheye, v)
            }
        };
        let camera = Camera::new(model, width, height, params).map_err(|e| self.err("params", e.to_string()))?;
        let mut size_keys = BTreeMap::new();
        size_keys.insert("width".to_string(), self.written("width"));
        size_keys.insert("height".to_string(), self.written("height"));
        written.extend(size_keys);
        camera.validate().map_err(|e| file_error_from_validation(&self.path, e, &written))?;
        let unknown_keys =
            self.entries.iter().filter(|(k, _)| !self.used.contains(*k)).map(|(_, e)| e.key.clone()).collect();
        Ok(CameraFile { camera, format: self.format, fps, readout_s, refined_over, unknown_keys })
    }

    /// Parses `[a, b, c]` (or a bare comma/space separated list).
    fn number_list(&self, e: &Entry) -> Result<Vec<f64>, CameraError> {
        let inner = e.value.trim();
        let inner = inner.strip_prefix('[').and_then(|s| s.strip_suffix(']')).unwrap_or(inner);
        let mut out = Vec::new();
        for (i, tok) in inner.split([',', ' ', '\t']).filter(|t| !t.trim().is_empty()).enumerate() {
            let tok = tok.trim();
            let v: f64 =
                tok.parse().map_err(|_| self.err(&e.key, format!("element {i}: expected a number, got {tok:?}")))?;
            if !v.is_finite() {
                return Err(self.err(&e.key, format!("element {i}: value {tok} is not finite")));
            }
            out.push(v);
        }
        Ok(out)
    }
}

/// Turns a [`Camera::validate`] error into a file error naming the key as
/// written in the file.
fn file_error_from_validation(path: &Path, e: CameraError, written: &BTreeMap<String, String>) -> CameraError {
    match e {
        CameraError::InvalidParam { name, value, reason } => CameraError::File {
            path: path.to_path_buf(),
            key: written.get(&name).cloned().unwrap_or(name),
            reason: format!("value {value} is out of range: {reason}"),
        },
        other => CameraError::File { path: path.to_path_buf(), key: "params".into(), reason: other.to_string() },
    }
}
