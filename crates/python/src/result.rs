//! `colslam.Result` and `colslam.Camera`: a run's trajectory and model as
//! numpy arrays, and its writers (the library's model, TUM and PLY writers).

use crate::errors::{Kind, raise};
use crate::shown;
use colslam_eval::trajectory::Trajectory;
use colslam_geometry::Rigid3;
use colslam_scene::{ModelFormat, Reconstruction};
use colslam_slam::{ExportError, FrameSelection, SceneExport, SceneFormat, export_scene};
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3};
use pyo3::exceptions::{PyImportError, PyRuntimeError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};

/// A run's result (see `colslam.Result` in python/colslam/_colslam.pyi).
#[pyclass(name = "Result", module = "colslam", frozen)]
pub struct RunResult {
    /// Every localised frame, world_from_cam, in frame order.
    trajectory: Trajectory,
    /// Each frame's name, where known.
    names: Vec<Option<String>>,
    /// Whether each frame is a keyframe (an image of the model).
    keyframes: Vec<bool>,
    /// The model of the largest map.
    model: Reconstruction,
    /// `report.json`'s text, when there is one.
    report: Option<String>,
    /// The output folder.
    output: PathBuf,
    /// The rolling-shutter readout time the run used, seconds.
    readout: f64,
    /// The temporary output folder of a run given no output: it lives as
    /// long as the result.
    _tmp: Option<tempfile::TempDir>,
}

/// Row-major 4x4 of a pose.
fn matrix_rows(p: &Rigid3) -> [f64; 16] {
    let m = p.matrix4();
    std::array::from_fn(|i| m[(i / 4, i % 4)])
}

/// The runtime error for an array shape that the lengths already fix.
fn shape_error(e: impl std::fmt::Display) -> PyErr {
    PyRuntimeError::new_err(format!("array shape: {e}"))
}

impl RunResult {
    /// The result of a finished run: its largest map, as the output folder's
    /// model and trajectory hold it.
    pub fn from_run(
        out: &colslam_slam::RunOutput,
        output: PathBuf,
        readout: f64,
        tmp: Option<tempfile::TempDir>,
    ) -> Self {
        // The driver serialised this report into report.json already, so
        // it serialises; `None` would only mean no report, as for a model.
        let report = serde_json::to_string(&out.report).ok();
        let Some(map) = out.result.maps.first() else {
            return Self {
                trajectory: Trajectory::default(),
                names: Vec::new(),
                keyframes: Vec::new(),
                model: Reconstruction::new(),
                report,
                output,
                readout,
                _tmp: tmp,
            };
        };
        let poses = &map.poses;
        let trajectory = Trajectory::from_cam_from_world(
            poses.iter().map(|p| p.frame.timestamp).collect(),
            &poses.iter().map(|p| p.cam_from_world).collect::<Vec<_>>(),
        );
        Self {
            trajectory,
            names: poses.iter().map(|p| Some(p.frame.name.clone())).collect(),
            keyframes: poses.iter().map(|p| p.keyframe).collect(),
            model: map.map.reconstruction().clone(),
            report,
            output,
            readout,
            _tmp: tmp,
        }
    }

    /// A run's output folder (model, `trajectory.tum`, `keyframes.tum`,
    /// `report.json`) or a bare COLMAP model folder (its images in id order,
    /// timestamps NaN).
    pub fn read(dir: &Path) -> Result<Self, String> {
        if !dir.is_dir() {
            return Err(format!("{}: not a folder (a run's output or a COLMAP model)", shown(dir)));
        }
        let chain = |e: &dyn std::error::Error| colslam_slam::error_chain(e);
        let model = colslam_scene::read_model(dir).map_err(|e| chain(&e))?;
        let report_path = dir.join("report.json");
        let report = if report_path.is_file() {
            Some(std::fs::read_to_string(&report_path).map_err(|e| format!("{}: {e}", shown(&report_path)))?)
        } else {
            None
        };
        let readout = report
            .as_deref()
            .and_then(|r| serde_json::from_str::<serde_json::Value>(r).ok())
            .and_then(|v| {
                // The readout used (estimated with `auto`); older reports have only the option.
                let used = v.pointer("/camera/readout_s").or_else(|| v.pointer("/options/refine/rolling_shutter"));
                used.and_then(serde_json::Value::as_f64)
            })
            .unwrap_or(0.0);
        let traj_path = dir.join("trajectory.tum");
        let (trajectory, names, keyframes) = if traj_path.is_file() {
            let trajectory = Trajectory::read_tum(&traj_path).map_err(|e| chain(&e))?;
            let kf_path = dir.join("keyframes.tum");
            let kf_stamps =
                if kf_path.is_file() { Trajectory::read_tum(&kf_path).map_err(|e| chain(&e))?.stamps } else { vec![] };
            let keyframes: Vec<bool> = trajectory.stamps.iter().map(|t| kf_stamps.contains(t)).collect();
            let names = trajectory
                .poses
                .iter()
                .zip(&keyframes)
                .map(|(pose, &kf)| if kf { image_with_pose(&model, pose) } else { None })
                .collect();
            (trajectory, names, keyframes)
        } else {
            let mut images: Vec<_> = model.images().filter(|i| i.registered).collect();
            images.sort_by_key(|i| i.id);
            let trajectory = Trajectory::from_cam_from_world(
                vec![f64::NAN; images.len()],
                &images.iter().map(|i| i.cam_from_world).collect::<Vec<_>>(),
            );
            let names = images.iter().map(|i| Some(i.name.clone())).collect();
            (trajectory, names, vec![true; images.len()])
        };
        Ok(Self { trajectory, names, keyframes, model, report, output: dir.to_path_buf(), readout, _tmp: None })
    }
}

impl RunResult {
    /// An export of the run's output folder (the library reads the folder
    /// the run wrote, not this object).
    fn export<'py>(
        &self,
        py: Python<'py>,
        format: SceneFormat,
        path: PathBuf,
        keyframes_only: bool,
        images: Option<PathBuf>,
        map: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        let mut req = SceneExport::new(&self.output, path, format);
        req.frames = if keyframes_only { FrameSelection::Keyframes } else { FrameSelection::All };
        req.images = images;
        req.map = map;
        let summary = py.detach(|| export_scene(&req)).map_err(|e| {
            let kind = match &e {
                ExportError::Output(_) | ExportError::Write { .. } => Kind::Output,
                ExportError::Camera { .. } | ExportError::Undistort(_) => Kind::Camera,
                _ => Kind::Input,
            };
            raise(py, kind, colslam_slam::error_chain(&e))
        })?;
        let d = PyDict::new(py);
        d.set_item("output", &summary.output)?;
        d.set_item("frames", summary.frames)?;
        d.set_item("keyframes", summary.keyframes)?;
        d.set_item("not_localized", summary.not_localized)?;
        d.set_item("points", summary.points)?;
        d.set_item("camera_model", &summary.camera_model)?;
        d.set_item("undistorted", summary.undistorted)?;
        d.set_item("width", summary.width)?;
        d.set_item("height", summary.height)?;
        Ok(d)
    }
}

/// The name of the registered image whose pose is `world_from_cam`: a run
/// writes each keyframe's pose to the model and to the trajectory, which
/// stores no names. Matched on the camera centre and the rotation to well
/// below any two frames' difference.
fn image_with_pose(model: &Reconstruction, world_from_cam: &Rigid3) -> Option<String> {
    let c = world_from_cam.translation;
    let r = world_from_cam.rotation_matrix();
    let tol = 1e-6 * c.norm().max(1.0);
    model
        .images()
        .filter(|i| i.registered)
        .find(|i| {
            let w = i.cam_from_world.inverse();
            (w.translation - c).norm() <= tol && (w.rotation_matrix() - r).abs().max() <= 1e-6
        })
        .map(|i| i.name.clone())
}

#[pymethods]
impl RunResult {
    /// (N, 4, 4) float64: world_from_cam of every localised frame.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let n = self.trajectory.len();
        let flat: Vec<f64> = self.trajectory.poses.iter().flat_map(matrix_rows).collect();
        Ok(Array3::from_shape_vec((n, 4, 4), flat).map_err(shape_error)?.into_pyarray(py))
    }

    /// (N,) float64: each frame's timestamp, seconds.
    #[getter]
    fn timestamps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        Array1::from_vec(self.trajectory.stamps.clone()).into_pyarray(py)
    }

    /// Each frame's name (None where a model folder does not tell it).
    #[getter]
    fn frame_names(&self) -> Vec<Option<String>> {
        self.names.clone()
    }

    /// (N,) bool: whether each frame is a keyframe (an image of the model).
    #[getter]
    fn keyframe_mask<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        Array1::from_vec(self.keyframes.clone()).into_pyarray(py)
    }

    /// The camera of the model (None when the run mapped nothing).
    #[getter]
    fn camera(&self) -> Option<PyCamera> {
        self.model.cameras().next().map(|c| PyCamera::new(&c.camera, self.readout))
    }

    /// (M, 3) float64: the model's 3D points, in point-id order.
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let flat: Vec<f64> = self.model.points3d().flat_map(|(_, p)| [p.xyz.x, p.xyz.y, p.xyz.z]).collect();
        Ok(Array2::from_shape_vec((flat.len() / 3, 3), flat).map_err(shape_error)?.into_pyarray(py))
    }

    /// (M, 3) uint8: the points' RGB colours.
    #[getter]
    fn colors<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let flat: Vec<u8> = self.model.points3d().flat_map(|(_, p)| p.color).collect();
        Ok(Array2::from_shape_vec((flat.len() / 3, 3), flat).map_err(shape_error)?.into_pyarray(py))
    }

    /// (M,) float64: the points' mean reprojection errors, pixels.
    #[getter]
    fn point_errors<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        Array1::from_vec(self.model.points3d().map(|(_, p)| p.error).collect()).into_pyarray(py)
    }

    /// (M,) uint64: the points' ids in the COLMAP model.
    #[getter]
    fn point_ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        Array1::from_vec(self.model.points3d().map(|(id, _)| id.0).collect()).into_pyarray(py)
    }

    /// `report.json` as a dict (None for a bare model folder).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        match &self.report {
            Some(text) => Ok(Some(py.import("json")?.call_method1("loads", (text,))?)),
            None => Ok(None),
        }
    }

    /// The output folder (a temporary one, removed with the result, when
    /// the run was given none).
    #[getter]
    fn output(&self) -> PathBuf {
        self.output.clone()
    }

    /// Writes the model as a COLMAP model folder (binary; text with `text=True`), as a whole.
    #[pyo3(signature = (path, text=false))]
    fn write_colmap(&self, py: Python<'_>, path: PathBuf, text: bool) -> PyResult<()> {
        let format = if text { ModelFormat::Text } else { ModelFormat::Binary };
        py.detach(|| colslam_scene::write_model(&self.model, &path, format))
            .map_err(|e| raise(py, Kind::Output, colslam_slam::error_chain(&e)))
    }

    /// Writes the trajectory as a TUM file (`time tx ty tz qx qy qz qw`, world_from_cam).
    fn write_tum(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.trajectory.write_tum(&path).map_err(|e| raise(py, Kind::Output, colslam_slam::error_chain(&e)))
    }

    /// Writes the points as a coloured PLY point cloud.
    fn write_ply(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        colslam_scene::write_ply(&self.model, &path).map_err(|e| raise(py, Kind::Output, colslam_slam::error_chain(&e)))
    }

    /// The model as a `pycolmap.Reconstruction` (read back from the bytes
    /// `write_colmap` writes).
    fn to_pycolmap<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let pycolmap = py.import("pycolmap").map_err(|e| {
            PyImportError::new_err(format!(
                "Result.to_pycolmap() needs pycolmap, which cannot be imported ({e}); install it with \
                 `pip install pycolmap`"
            ))
        })?;
        let dir = tempfile::Builder::new()
            .prefix("colslam-pycolmap-")
            .tempdir()
            .map_err(|e| raise(py, Kind::Output, format!("creating a temporary folder: {e}")))?;
        colslam_scene::write_model_files(&self.model, dir.path(), ModelFormat::Binary)
            .map_err(|e| raise(py, Kind::Output, colslam_slam::error_chain(&e)))?;
        pycolmap.getattr("Reconstruction")?.call1((shown(dir.path()),))
    }

    /// Exports the run for nerfstudio (`transforms.json`, `images/`,
    /// `sparse_pc.ply`) with `colslam export -f nerfstudio`'s library call.
    /// `map` picks one map of a run that ended with several (0: the largest).
    #[pyo3(signature = (path, keyframes_only=false, images=None, map=0))]
    fn export_nerfstudio<'py>(
        &self,
        py: Python<'py>,
        path: PathBuf,
        keyframes_only: bool,
        images: Option<PathBuf>,
        map: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.export(py, SceneFormat::Nerfstudio, path, keyframes_only, images, map)
    }

    /// Exports the run for 3D Gaussian splatting (undistorted `images/`, a
    /// PINHOLE model in `sparse/0/`) with `colslam export -f 3dgs`'s library call.
    /// `map` picks one map of a run that ended with several (0: the largest).
    #[pyo3(signature = (path, keyframes_only=false, images=None, map=0))]
    fn export_3dgs<'py>(
        &self,
        py: Python<'py>,
        path: PathBuf,
        keyframes_only: bool,
        images: Option<PathBuf>,
        map: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.export(py, SceneFormat::Gaussian3d, path, keyframes_only, images, map)
    }

    fn __len__(&self) -> usize {
        self.trajectory.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "colslam.Result({} frames, {} keyframes, {} points, output='{}')",
            self.trajectory.len(),
            self.keyframes.iter().filter(|k| **k).count(),
            self.model.num_points3d(),
            shown(&self.output)
        )
    }
}

/// A camera (see `colslam.Camera` in python/colslam/_colslam.pyi).
#[pyclass(name = "Camera", module = "colslam", frozen, skip_from_py_object)]
#[derive(Clone)]
pub struct PyCamera {
    camera: colslam_camera::Camera,
    readout: f64,
}

impl PyCamera {
    fn new(camera: &colslam_camera::Camera, readout: f64) -> Self {
        Self { camera: camera.clone(), readout }
    }
}

#[pymethods]
impl PyCamera {
    /// COLMAP model name, e.g. "PINHOLE", "OPENCV".
    #[getter]
    fn model(&self) -> &'static str {
        self.camera.model.name()
    }

    /// Parameters in COLMAP's order and pixel convention.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        Array1::from_vec(self.camera.params.clone()).into_pyarray(py)
    }

    /// Rolling-shutter readout time, seconds (0: global shutter).
    #[getter]
    fn readout(&self) -> f64 {
        self.readout
    }

    /// (3, 3) calibration matrix of the pinhole part (COLMAP pixel convention).
    #[getter(K)]
    fn k<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let k = self.camera.calibration_matrix();
        let flat: Vec<f64> = (0..9).map(|i| k[(i / 3, i % 3)]).collect();
        Ok(Array2::from_shape_vec((3, 3), flat).map_err(shape_error)?.into_pyarray(py))
    }

    /// Image width, pixels.
    #[getter]
    fn width(&self) -> u64 {
        self.camera.width
    }

    /// Image height, pixels.
    #[getter]
    fn height(&self) -> u64 {
        self.camera.height
    }

    fn __repr__(&self) -> String {
        format!(
            "colslam.Camera({} {}x{}, params={:?}, readout={})",
            self.camera.model.name(),
            self.camera.width,
            self.camera.height,
            self.camera.params,
            self.readout
        )
    }
}
