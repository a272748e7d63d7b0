//! Timestamped camera trajectories and the TUM RGB-D text format.
//!
//! A TUM trajectory file holds one pose per line,
//! `timestamp tx ty tz qx qy qz qw`, where `t` is the camera centre in world
//! coordinates and `q` the camera-to-world rotation (Sturm et al., "A
//! Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012). Lines
//! starting with `#` are comments; blank lines are skipped.

use crate::EvalError;
use colslam_geometry::{Quat, Rigid3, Vec3};
use std::fmt::Write as _;
use std::path::Path;

/// Number of whitespace-separated fields of a TUM pose line.
const TUM_FIELDS: usize = 8;
/// A quaternion whose norm is at most this is rejected: it names no rotation.
const MIN_QUAT_NORM: f64 = 1e-12;
/// A quaternion whose norm is within this of 1 is kept bit-exact (so that
/// write -> read round-trips); others are normalised.
const UNIT_NORM_TOL: f64 = 4.0 * f64::EPSILON;

/// A trajectory: `poses[i]` is the `world_from_cam` pose at time `stamps[i]`
/// (seconds). The translation of each pose is the camera centre in world
/// coordinates. Invariant expected by every function of this crate:
/// `stamps.len() == poses.len()` (checked by [`Trajectory::validate`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Trajectory {
    /// Timestamps in seconds.
    pub stamps: Vec<f64>,
    /// `world_from_cam` poses, one per stamp.
    pub poses: Vec<Rigid3>,
}

impl Trajectory {
    /// Builds from `world_from_cam` poses.
    pub fn new(stamps: Vec<f64>, poses: Vec<Rigid3>) -> Self {
        Self { stamps, poses }
    }

    /// Builds from `cam_from_world` poses (COLMAP's image poses), inverting each.
    pub fn from_cam_from_world(stamps: Vec<f64>, cam_from_world: &[Rigid3]) -> Self {
        Self { stamps, poses: cam_from_world.iter().map(Rigid3::inverse).collect() }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when the trajectory holds no poses.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Camera centres in world coordinates.
    pub fn positions(&self) -> Vec<Vec3> {
        self.poses.iter().map(|p| p.translation).collect()
    }

    /// Checks the length invariant and that every number is finite; `name`
    /// labels the trajectory in the error.
    pub fn validate(&self, name: &str) -> Result<(), EvalError> {
        let invalid = |problem: String| EvalError::InvalidTrajectory { name: name.to_string(), problem };
        if self.stamps.len() != self.poses.len() {
            return Err(invalid(format!("{} stamps but {} poses", self.stamps.len(), self.poses.len())));
        }
        for (i, (t, p)) in self.stamps.iter().zip(&self.poses).enumerate() {
            let q = p.rotation.quaternion();
            let finite =
                t.is_finite() && p.translation.iter().all(|v| v.is_finite()) && q.coords.iter().all(|v| v.is_finite());
            if !finite {
                return Err(invalid(format!("pose {i} (stamp {t}) holds a non-finite value")));
            }
        }
        Ok(())
    }

    /// Sorts the poses by timestamp (stable: equal stamps keep their order).
    pub fn sort_by_time(&mut self) {
        let mut order: Vec<usize> = (0..self.len().min(self.stamps.len())).collect();
        order.sort_by(|&a, &b| self.stamps[a].total_cmp(&self.stamps[b]));
        *self = self.select(&order);
    }

    /// The poses at `indices` (in that order; repeats allowed). Indices out
    /// of range are skipped.
    pub fn select(&self, indices: &[usize]) -> Trajectory {
        let mut out = Trajectory::default();
        for &i in indices {
            if let (Some(&t), Some(&p)) = (self.stamps.get(i), self.poses.get(i)) {
                out.stamps.push(t);
                out.poses.push(p);
            }
        }
        out
    }

    /// Reads a TUM trajectory file. Errors name the file, the 1-based line
    /// and the problem.
    pub fn read_tum(path: &Path) -> Result<Trajectory, EvalError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| EvalError::Io { path: path.to_path_buf(), source })?;
        Self::parse_tum(&text, path)
    }

    /// Parses TUM text; `path` only names the source in errors. Timestamps
    /// must increase strictly from line to line, as in the TUM benchmark's
    /// files: a repeated or earlier stamp (a concatenated or hand-edited
    /// file) would pair one pose with several and make an evaluation fail
    /// much later with a message that no longer names the line.
    pub fn parse_tum(text: &str, path: &Path) -> Result<Trajectory, EvalError> {
        // A UTF-8 byte-order mark would otherwise make the first stamp non-numeric.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut traj = Trajectory::default();
        let mut previous: Option<(f64, usize)> = None;
        for (index, raw) in text.lines().enumerate() {
            let line_no = index + 1;
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let err = |problem: String| EvalError::Parse { path: path.to_path_buf(), line: line_no, problem };
            let fields: Vec<&str> = line.split_whitespace().collect();
            if fields.len() != TUM_FIELDS {
                return Err(err(format!(
                    "expected {TUM_FIELDS} fields (timestamp tx ty tz qx qy qz qw), found {}",
                    fields.len()
                )));
            }
            let mut v = [0.0f64; TUM_FIELDS];
            for (k, (slot, field)) in v.iter_mut().zip(&fields).enumerate() {
                let x: f64 = field
                    .parse()
                    .map_err(|_| err(format!("field {} ({}) is not a number: '{field}'", k + 1, FIELD_NAMES[k])))?;
                if !x.is_finite() {
                    return Err(err(format!("field {} ({}) is not finite: '{field}'", k + 1, FIELD_NAMES[k])));
                }
                *slot = x;
            }
            let [t, tx, ty, tz, qx, qy, qz, qw] = v;
            let q = nalgebra_quat(qw, qx, qy, qz);
            let norm = q.norm();
            if norm <= MIN_QUAT_NORM {
                return Err(err(format!("quaternion ({qx} {qy} {qz} {qw}) has zero norm")));
            }
            // Finite components can still overflow the norm (1e308): normalising
            // by an infinite norm would give the zero quaternion.
            if !norm.is_finite() {
                return Err(err(format!("quaternion ({qx} {qy} {qz} {qw}) is too large to normalise")));
            }
            let rotation =
                if (norm - 1.0).abs() <= UNIT_NORM_TOL { Quat::new_unchecked(q) } else { Quat::new_normalize(q) };
            if let Some((prev, prev_line)) = previous
                && t <= prev
            {
                let how = if t == prev { "repeats" } else { "is earlier than" };
                return Err(err(format!(
                    "timestamp {t} {how} the one on line {prev_line} ({prev}); timestamps must increase strictly"
                )));
            }
            previous = Some((t, line_no));
            traj.stamps.push(t);
            traj.poses.push(Rigid3::new(rotation, Vec3::new(tx, ty, tz)));
        }
        Ok(traj)
    }

    /// The trajectory as TUM text. Numbers use Rust's shortest round-trip
    /// representation, so reading the text back gives bit-identical values
    /// (TUM stamps near 1.3e9 s keep all their sub-microsecond digits).
    pub fn to_tum_string(&self) -> String {
        let mut s = String::with_capacity(self.len() * 96);
        s.push_str("# timestamp tx ty tz qx qy qz qw\n");
        for (t, p) in self.stamps.iter().zip(&self.poses) {
            let [qx, qy, qz, qw] = p.quat_xyzw();
            let c = p.translation;
            // Writing to a String cannot fail.
            let _ = writeln!(s, "{t} {} {} {} {qx} {qy} {qz} {qw}", c.x, c.y, c.z);
        }
        s
    }

    /// Writes a TUM trajectory file atomically, after [`Trajectory::validate`]
    /// (so that the file can be read back).
    pub fn write_tum(&self, path: &Path) -> Result<(), EvalError> {
        self.validate(&path.display().to_string())?;
        colslam_image::write_atomic(path, self.to_tum_string().as_bytes())
            .map_err(|source| EvalError::Io { path: path.to_path_buf(), source })
    }
}

/// Names of the TUM fields, for error messages.
const FIELD_NAMES: [&str; TUM_FIELDS] = ["timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];

fn nalgebra_quat(w: f64, x: f64, y: f64, z: f64) -> colslam_geometry::nalgebra::Quaternion<f64> {
    colslam_geometry::nalgebra::Quaternion::new(w, x, y, z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_geometry::SplitMix64;

    fn random_traj(n: usize, seed: u64) -> Trajectory {
        let mut rng = SplitMix64::new(seed);
        let mut t = Trajectory::default();
        for i in 0..n {
            let rot = Quat::from_euler_angles(rng.uniform(-3.0, 3.0), rng.uniform(-1.5, 1.5), rng.uniform(-3.0, 3.0));
            t.stamps.push(1_305_031_225.933_4 + i as f64 * 0.0333 + rng.uniform(0.0, 1e-6));
            t.poses.push(Rigid3::new(rot, Vec3::new(rng.normal(), rng.normal() * 1e-7, rng.normal() * 1e5)));
        }
        t
    }

    #[test]
    fn tum_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("traj.txt");
        let t = random_traj(50, 11);
        t.write_tum(&path).unwrap();
        let back = Trajectory::read_tum(&path).unwrap();
        assert_eq!(back.stamps, t.stamps);
        for (a, b) in back.poses.iter().zip(&t.poses) {
            assert_eq!(a.translation, b.translation);
            assert_eq!(a.quat_xyzw(), b.quat_xyzw());
        }
    }

    #[test]
    fn reads_comments_blank_lines_and_normalises() {
        let text = "# header\n\n1.0 1 2 3 0 0 0 2\n  \n# mid\n2.5\t4 5 6 0 0 1 0\n";
        let t = Trajectory::parse_tum(text, Path::new("x.txt")).unwrap();
        assert_eq!(t.stamps, vec![1.0, 2.5]);
        assert_eq!(t.poses[0].quat_wxyz(), [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(t.poses[1].translation, Vec3::new(4.0, 5.0, 6.0));
        assert!((t.poses[1].rotation.angle() - std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let good = "1 0 0 0 0 0 0 1\n";
        let cases = [
            ("1 0 0 0 0 0 1\n", "expected 8 fields"),
            ("1 0 0 0 0 0 0 1 9\n", "found 9"),
            ("1 0 zero 0 0 0 0 1\n", "field 3 (ty) is not a number"),
            ("1 0 0 0 0 0 0 nan\n", "field 8 (qw) is not finite"),
            ("inf 0 0 0 0 0 0 1\n", "field 1 (timestamp) is not finite"),
            ("1 0 0 0 0 0 0 0\n", "zero norm"),
            ("1 0 0 0 0 0 0 1\n", "timestamp 1 repeats the one on line 2"),
            ("0.5 0 0 0 0 0 0 1\n", "timestamp 0.5 is earlier than the one on line 2"),
            // Found by fuzzing: the norm overflowed and normalising gave the zero quaternion.
            ("1 0 0 0 0.6 0.5 -0.3 -1e308\n", "too large to normalise"),
        ];
        for (bad, expect) in cases {
            let text = format!("# c\n{good}\n{bad}");
            let err = Trajectory::parse_tum(&text, Path::new("dir/est.txt")).unwrap_err();
            let msg = err.to_string();
            assert!(msg.starts_with("dir/est.txt:4: "), "{msg}");
            assert!(msg.contains(expect), "{msg} lacks {expect}");
        }
        let mut nan = Trajectory::parse_tum(good, Path::new("g")).unwrap();
        nan.stamps[0] = f64::NAN;
        let err = nan.write_tum(Path::new("/tmp/never-written.txt")).unwrap_err().to_string();
        assert!(err.contains("never-written.txt") && err.contains("non-finite"), "{err}");
        let missing = Trajectory::read_tum(Path::new("/nonexistent/gt.txt")).unwrap_err();
        assert!(missing.to_string().contains("/nonexistent/gt.txt"));
    }

    #[test]
    fn select_sort_and_cam_from_world() {
        let mut t = random_traj(5, 3);
        t.stamps = vec![5.0, 1.0, 3.0, 1.0, 2.0];
        let orig = t.clone();
        t.sort_by_time();
        assert_eq!(t.stamps, vec![1.0, 1.0, 2.0, 3.0, 5.0]);
        // Stable: the two 1.0 stamps keep their input order (indices 1, 3).
        assert_eq!(t.poses[0], orig.poses[1]);
        assert_eq!(t.poses[1], orig.poses[3]);
        let s = orig.select(&[4, 0, 9]);
        assert_eq!(s.stamps, vec![2.0, 5.0]);
        let cfw: Vec<Rigid3> = orig.poses.iter().map(Rigid3::inverse).collect();
        let back = Trajectory::from_cam_from_world(orig.stamps.clone(), &cfw);
        for (a, b) in back.positions().iter().zip(orig.positions()) {
            assert!((a - b).norm() < 1e-6 * b.norm().max(1.0));
        }
        assert!(orig.validate("x").is_ok());
        let mut bad = orig.clone();
        bad.stamps.pop();
        assert!(bad.validate("x").unwrap_err().to_string().contains("4 stamps but 5 poses"));
    }
}
