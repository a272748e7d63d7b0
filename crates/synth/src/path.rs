//! The hand-held-like camera path: an arc (or laps) around the central
//! table, looking at a smoothly wandering point on the table, or a line
//! along the room looking across it ([`PathShape`]), with sum-of-sines
//! jitter in position and orientation.
//!
//! The base path is a function of the normalised progress `s = t / T`
//! (`T` = time of the last frame), the jitter a function of the time `t` in
//! seconds. A sequence with fewer frames and a proportionally lower frame rate
//! therefore samples exactly the same trajectory, which tests use to stay fast.

use colslam_geometry::{Mat3, Quat, Rigid3, SplitMix64, Vec3};
use std::f64::consts::{PI, TAU};

use crate::options::{DriveLayout, PathShape, SynthOptions, drive_layout};

/// Sine components per jitter axis.
const JITTER_COMPONENTS: usize = 3;
/// Frequency range of the jitter sines, Hz (hand tremor and sway).
const JITTER_FREQ: (f64, f64) = (0.3, 1.6);
/// Relative amplitude of the progress modulation (speed varies by +-25 %).
const PROGRESS_WOBBLE: f64 = 0.04;
/// Amplitude of the in/out motion relative to the orbit, metres.
const RADIAL_WOBBLE: f64 = 0.12;
/// Amplitude of the slow height change, metres.
const HEIGHT_WOBBLE: f64 = 0.1;
/// Radius of the looked-at point's wander on the table, metres.
const TARGET_WANDER: f64 = 0.3;
/// Height of the looked-at point (a little above the table top), metres.
const TARGET_HEIGHT: f64 = 0.85;
/// Where a [`PathShape::Line`] runs: this fraction of the room's width on
/// the -y side of its centre line (clear of the table and the cabinets).
const LINE_OFFSET: f64 = 0.25;
/// How far across the room a [`PathShape::Line`] camera looks, metres.
const LINE_LOOK_DISTANCE: f64 = 2.5;

/// How far ahead a [`PathShape::Drive`] camera looks, metres.
const DRIVE_LOOK_DISTANCE: f64 = 10.0;
/// How far below the camera's height its looked-at point lies, metres
/// (a car's camera pitched slightly down towards the road).
const DRIVE_LOOK_DOWN: f64 = 0.5;

/// One jittered scalar: a sum of sines.
#[derive(Debug, Clone)]
struct SumOfSines {
    /// (amplitude, angular frequency rad/s, phase).
    terms: [(f64, f64, f64); JITTER_COMPONENTS],
}

impl SumOfSines {
    /// Amplitudes sum to `amplitude`, so `|value| <= amplitude`.
    fn new(rng: &mut SplitMix64, amplitude: f64) -> Self {
        let mut terms = [(0.0, 0.0, 0.0); JITTER_COMPONENTS];
        let mut wsum = 0.0;
        for t in terms.iter_mut() {
            let w = rng.uniform(0.5, 1.0);
            wsum += w;
            *t = (w, TAU * rng.uniform(JITTER_FREQ.0, JITTER_FREQ.1), rng.uniform(0.0, TAU));
        }
        for t in terms.iter_mut() {
            t.0 *= amplitude / wsum;
        }
        Self { terms }
    }

    fn eval(&self, t: f64) -> f64 {
        self.terms.iter().map(|(a, w, p)| a * (w * t + p).sin()).sum()
    }
}

/// The camera trajectory, deterministic from the seed.
#[derive(Debug, Clone)]
pub struct Trajectory {
    shape: PathShape,
    /// Path length (line) in metres.
    length: f64,
    /// y of the line path.
    line_y: f64,
    /// Where a drive runs.
    drive: DriveLayout,
    duration: f64,
    radius: f64,
    height: f64,
    theta0: f64,
    sweep: f64,
    phase_progress: f64,
    phase_radius: f64,
    phase_height: f64,
    phase_target: f64,
    target_turn: f64,
    position_jitter: [SumOfSines; 3],
    rotation_jitter: [SumOfSines; 3],
}

impl Trajectory {
    /// Builds the trajectory of a sequence with these (validated) options.
    pub fn new(opts: &SynthOptions) -> Self {
        let mut rng = SplitMix64::new(opts.seed ^ 0x9A74_0000_0000_0003);
        // frames >= 1 after validation; a single frame still gets a positive
        // duration so that `s` stays finite.
        let duration = if opts.frames > 1 { (opts.frames - 1) as f64 / opts.fps } else { 1.0 / opts.fps };
        let theta0 = rng.uniform(0.0, TAU);
        let direction = if rng.below(2) == 0 { 1.0 } else { -1.0 };
        let rot_amp = opts.jitter_rotation_deg.to_radians();
        Self {
            shape: opts.path,
            length: opts.path_length,
            line_y: -LINE_OFFSET * opts.room_size[1],
            drive: drive_layout(opts),
            duration,
            radius: opts.orbit_radius,
            height: opts.camera_height,
            theta0,
            sweep: direction * opts.path_length / opts.orbit_radius,
            phase_progress: rng.uniform(0.0, TAU),
            phase_radius: rng.uniform(0.0, TAU),
            phase_height: rng.uniform(0.0, TAU),
            phase_target: rng.uniform(0.0, TAU),
            target_turn: direction * rng.uniform(1.0, 2.0),
            position_jitter: std::array::from_fn(|_| SumOfSines::new(&mut rng, opts.jitter_position)),
            rotation_jitter: std::array::from_fn(|_| SumOfSines::new(&mut rng, rot_amp)),
        }
    }

    /// Time of the last frame, seconds.
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// Progress along the path at normalised time `s`, with a varying speed.
    fn progress(&self, s: f64) -> f64 {
        s + PROGRESS_WOBBLE * ((TAU * s + self.phase_progress).sin() - self.phase_progress.sin())
    }

    /// Camera centre at time `t` (seconds) without the jitter.
    fn base_center(&self, t: f64) -> Vec3 {
        let s = t / self.duration;
        // Progress with a varying speed; d/ds = 1 + 2 pi w cos(.) > 0 since
        // 2 pi w < 1, so the camera never stops (no pure rotation).
        let p = self.progress(s);
        let wobble = RADIAL_WOBBLE * (PI * s + self.phase_radius).sin();
        let h = self.height + HEIGHT_WOBBLE * (TAU * 0.7 * s + self.phase_height).sin();
        match self.shape {
            PathShape::Arc | PathShape::Laps => {
                let theta = self.theta0 + self.sweep * (p - 0.5);
                let r = self.radius + wobble;
                Vec3::new(r * theta.cos(), r * theta.sin(), h)
            }
            PathShape::Line => Vec3::new(self.length * (p - 0.5), self.line_y + wobble, h),
            PathShape::Drive => {
                let (xy, dir) = self.drive_at(p);
                // The lateral wobble: left of the direction of travel.
                Vec3::new(xy[0] - wobble * dir[1], xy[1] + wobble * dir[0], h)
            }
        }
    }

    /// A drive's point and unit direction of travel at progress `p` (0 at
    /// the first straight's start, 1 at the second's end).
    fn drive_at(&self, p: f64) -> ([f64; 2], [f64; 2]) {
        let d = &self.drive;
        let along = p * self.length;
        let turn = std::f64::consts::FRAC_PI_2 * d.radius;
        if along < d.straight {
            ([d.corner_x - d.straight + along, d.first_y], [1.0, 0.0])
        } else if along < d.straight + turn {
            // Counter-clockwise about the turn's centre (corner_x, corner_y).
            let phi = (along - d.straight) / d.radius;
            ([d.corner_x + d.radius * phi.sin(), d.corner_y - d.radius * phi.cos()], [phi.cos(), phi.sin()])
        } else {
            ([d.corner_x + d.radius, d.corner_y + along - d.straight - turn], [0.0, 1.0])
        }
    }

    /// Camera centre at time `t` (seconds), world coordinates.
    pub fn center(&self, t: f64) -> Vec3 {
        let j = Vec3::new(
            self.position_jitter[0].eval(t),
            self.position_jitter[1].eval(t),
            self.position_jitter[2].eval(t),
        );
        self.base_center(t) + j
    }

    /// The looked-at point at time `t`.
    pub fn target(&self, t: f64) -> Vec3 {
        let s = t / self.duration;
        let a = self.phase_target + self.target_turn * s;
        if self.shape == PathShape::Drive {
            let c = self.base_center(t);
            let (_, dir) = self.drive_at(self.progress(s));
            return Vec3::new(
                c.x + DRIVE_LOOK_DISTANCE * dir[0],
                c.y + DRIVE_LOOK_DISTANCE * dir[1],
                c.z - DRIVE_LOOK_DOWN,
            );
        }
        if self.shape == PathShape::Line {
            // Across the room, wandering along it and in height.
            let c = self.base_center(t);
            return Vec3::new(
                c.x + TARGET_WANDER * a.cos(),
                c.y + LINE_LOOK_DISTANCE,
                TARGET_HEIGHT + 0.3 * (TAU * 0.5 * s + self.phase_target).sin(),
            );
        }
        Vec3::new(
            TARGET_WANDER * a.cos(),
            TARGET_WANDER * 0.6 * a.sin(),
            TARGET_HEIGHT + 0.08 * (TAU * 0.5 * s + self.phase_target).sin(),
        )
    }

    /// The `world_from_cam` pose at time `t` (camera x right, y down, z forward).
    pub fn world_from_cam(&self, t: f64) -> Rigid3 {
        let c = self.center(t);
        let z = (self.target(t) - c).normalize();
        let up = Vec3::new(0.0, 0.0, 1.0);
        // The target is always well below the horizon-to-zenith range (it is
        // on the table, the camera above it at >= 1 m horizontal distance, or
        // 2.5 m across the room from a line path, or 10 m ahead of a drive
        // and 0.5 m below its height), so
        // z is never parallel to up.
        let x = z.cross(&up).normalize();
        let y = z.cross(&x);
        let look = Mat3::from_columns(&[x, y, z]);
        let jitter = Quat::from_euler_angles(
            self.rotation_jitter[0].eval(t),
            self.rotation_jitter[1].eval(t),
            self.rotation_jitter[2].eval(t),
        );
        let r =
            Quat::from_rotation_matrix(&colslam_geometry::nalgebra::Rotation3::from_matrix_unchecked(look)) * jitter;
        Rigid3::new(r, c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_is_proper_and_looks_at_target() {
        let opts = SynthOptions { jitter_rotation_deg: 0.0, ..Default::default() };
        let tr = Trajectory::new(&opts);
        for k in 0..10 {
            let t = k as f64 * 0.5;
            let p = tr.world_from_cam(t);
            let r = p.rotation_matrix();
            assert!((r.determinant() - 1.0).abs() < 1e-12);
            // The target projects onto the optical axis.
            let tc = p.inverse().transform_point(&tr.target(t));
            assert!(tc.z > 0.5 && tc.x.abs() < 1e-9 && tc.y.abs() < 1e-9, "{tc:?}");
            // Camera y (down) points downwards in the world.
            assert!(r.column(1).z < 0.0);
        }
    }

    /// A valid drive: 60 m with a turn of radius 6 in a 40 x 40 m room.
    pub(crate) fn drive_options() -> SynthOptions {
        SynthOptions {
            path: PathShape::Drive,
            path_length: 60.0,
            orbit_radius: 6.0,
            room_size: [40.0, 40.0, 6.0],
            frames: 300,
            ..Default::default()
        }
    }

    #[test]
    fn a_drive_goes_straight_turns_left_once_and_looks_where_it_goes() {
        let opts = drive_options();
        opts.validate().unwrap();
        let tr = Trajectory::new(&opts);
        let n = 600;
        let heading = |t: f64| {
            let z = tr.world_from_cam(t).rotation_matrix().column(2).into_owned();
            z.y.atan2(z.x)
        };
        let (first, last) = (heading(0.0), heading(tr.duration()));
        // Along +x first, along +y at the end (within the rotation jitter).
        assert!(first.abs() < 0.05, "{first}");
        assert!((last - std::f64::consts::FRAC_PI_2).abs() < 0.05, "{last}");
        let mut length = 0.0;
        for k in 0..n {
            let (t0, t1) = (tr.duration() * k as f64 / n as f64, tr.duration() * (k + 1) as f64 / n as f64);
            let (c0, c1) = (tr.base_center(t0), tr.base_center(t1));
            length += ((c1 - c0).xy()).norm();
            // Moving forward: the optical axis points along the motion.
            let z = tr.world_from_cam(t0).rotation_matrix().column(2).into_owned();
            assert!(z.xy().normalize().dot(&(c1 - c0).xy().normalize()) > 0.98, "step {k}");
            // The heading never turns right nor by more than the quarter turn.
            assert!(heading(t1) > heading(t0) - 0.02 && heading(t1) < std::f64::consts::FRAC_PI_2 + 0.05);
        }
        // The path length, within the lateral wobble's share.
        assert!((length - opts.path_length).abs() < 0.02 * opts.path_length, "{length}");
    }

    #[test]
    fn a_drive_too_long_for_its_room_is_refused() {
        let opts = SynthOptions { path_length: 90.0, ..drive_options() };
        assert!(opts.validate().is_err());
        let opts = SynthOptions { path_length: 5.0, ..drive_options() };
        assert!(opts.validate().is_err());
    }

    #[test]
    fn jitter_is_bounded() {
        let mut rng = SplitMix64::new(1);
        let s = SumOfSines::new(&mut rng, 0.01);
        for k in 0..1000 {
            assert!(s.eval(k as f64 * 0.01).abs() <= 0.01 + 1e-15);
        }
    }
}
