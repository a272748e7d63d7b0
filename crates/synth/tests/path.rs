//! The camera path: smooth, hand-held-like, enough translation, overlapping frames.

mod common;

use colslam_geometry::{Vec2, Vec3};
use colslam_synth::{PathShape, SynthOptions, SyntheticSequence, Trajectory};

/// Largest linear acceleration accepted (m/s^2): brisk hand-held motion.
const MAX_ACCEL: f64 = 3.0;
/// Largest angular acceleration accepted (rad/s^2).
const MAX_ANGULAR_ACCEL: f64 = 6.0;

#[test]
fn default_path_is_smooth_and_keeps_moving() {
    let opts = SynthOptions::default();
    let tr = Trajectory::new(&opts);
    let dt = 1.0 / opts.fps;
    let poses: Vec<_> = (0..opts.frames).map(|i| tr.world_from_cam(i as f64 * dt)).collect();
    let mut length = 0.0;
    for w in poses.windows(3) {
        let (a, b, c) = (w[0].translation, w[1].translation, w[2].translation);
        let acc = (c - 2.0 * b + a).norm() / (dt * dt);
        assert!(acc < MAX_ACCEL, "acceleration {acc} m/s^2");
        // Angular velocity as a rotation vector in the world, differenced.
        let w1 = (w[1].rotation * w[0].rotation.inverse()).scaled_axis() / dt;
        let w2 = (w[2].rotation * w[1].rotation.inverse()).scaled_axis() / dt;
        let alpha = (w2 - w1).norm() / dt;
        assert!(alpha < MAX_ANGULAR_ACCEL, "angular acceleration {alpha} rad/s^2");
        assert!(w1.norm() * dt < 1.5f64.to_radians(), "rotation per frame {} deg", (w1.norm() * dt).to_degrees());
        // Never a pure rotation: at least 3 mm per frame.
        let step = (b - a).norm();
        assert!(step > 0.003, "step {step} m");
        length += step;
    }
    assert!((1.2..2.5).contains(&length), "path length {length}");
    let first_last = (poses[poses.len() - 1].translation - poses[0].translation).norm();
    assert!(first_last > 1.0, "first-last distance {first_last}");
}

#[test]
fn translation_is_large_relative_to_depth_and_frames_overlap() {
    let seq = SyntheticSequence::new(&SynthOptions { noise_sigma: 0.0, ..common::small_opts(30, 80, 60) }).unwrap();
    let (w, h) = (80usize, 60usize);
    let mut depths = seq.render_depth(0).unwrap();
    depths.sort_by(f64::total_cmp);
    let median_depth = depths[depths.len() / 2];
    let poses = seq.world_from_cam();
    let baseline = (poses[poses.len() - 1].translation - poses[0].translation).norm();
    assert!((0.8..6.0).contains(&median_depth), "median depth {median_depth}");
    assert!(baseline / median_depth > 0.3, "baseline {baseline} vs median depth {median_depth}");
    // Monocular initialisation: a third of the path already gives a good
    // baseline-to-depth ratio.
    let early = (poses[10].translation - poses[0].translation).norm();
    assert!(early / median_depth > 0.1, "early baseline {early}");
    // Consecutive frames (here 1/6 s apart) share most of the view.
    for (i, pose) in poses.iter().enumerate().take(seq.num_frames() - 1) {
        let depth = seq.render_depth(i).unwrap();
        let mut inside = 0;
        let mut total = 0;
        for j in (0..h).step_by(4) {
            for k in (0..w).step_by(4) {
                let n = seq.camera().cam_from_img(&Vec2::new(k as f64, j as f64)).unwrap();
                let p = pose.transform_point(&(Vec3::new(n.x, n.y, 1.0) * depth[j * w + k]));
                total += 1;
                if let Some((px, _)) = seq.project(i + 1, &p).unwrap()
                    && px.x >= 0.0
                    && px.y >= 0.0
                    && px.x <= (w - 1) as f64
                    && px.y <= (h - 1) as f64
                {
                    inside += 1;
                }
            }
        }
        let share = inside as f64 / total as f64;
        assert!(share > 0.8, "frames {i} and {}: overlap {share}", i + 1);
    }
}

#[test]
fn trajectory_is_deterministic_and_seeded() {
    let a = Trajectory::new(&SynthOptions::default());
    let b = Trajectory::new(&SynthOptions::default());
    let c = Trajectory::new(&SynthOptions { seed: 99, ..Default::default() });
    for k in 0..10 {
        let t = k as f64 * 0.5;
        assert_eq!(a.world_from_cam(t), b.world_from_cam(t));
        assert_ne!(a.world_from_cam(t), c.world_from_cam(t));
    }
}

#[test]
fn any_seed_gives_a_collision_free_path() {
    // Coarse textures and a tiny image: only the layout and the path matter.
    for seed in 0..60 {
        let opts =
            SynthOptions { seed, texel_size: 0.1, width: 16, height: 12, focal: 13.0, ..SynthOptions::default() };
        if let Err(e) = SyntheticSequence::new(&opts) {
            panic!("seed {seed}: {e}");
        }
    }
    // A low path through a small room crowded with clutter runs into boxes:
    // refused with a clear error (for some seeds), never a panic.
    let mut refused = 0;
    for seed in 0..10 {
        let opts = SynthOptions {
            seed,
            room_size: [4.0, 3.5, 2.2],
            orbit_radius: 1.45,
            camera_height: 0.45,
            path_length: 4.0,
            clutter_boxes: 64,
            texel_size: 0.1,
            width: 16,
            height: 12,
            focal: 13.0,
            ..SynthOptions::default()
        };
        if let Err(e) = SyntheticSequence::new(&opts) {
            let e = e.to_string();
            assert!(e.contains("camera path") && e.contains("nearest surface"), "{e}");
            refused += 1;
        }
    }
    assert!(refused > 0, "no crowded configuration was refused");
}

/// The long shapes of `colslam bench scale`: laps come back to their start
/// (a looping sequence), a line never does and its frames see new wall.
#[test]
fn laps_revisit_and_lines_explore() {
    let base = SynthOptions { texel_size: 0.05, width: 32, height: 24, focal: 26.0, ..SynthOptions::default() };
    let lap = std::f64::consts::TAU * base.orbit_radius;
    // Two laps over 240 frames: around frame 120 (the speed varies) the
    // camera is back where frame 0 was.
    let laps = SynthOptions { path: PathShape::Laps, frames: 241, path_length: 2.0 * lap, ..base.clone() };
    let seq = SyntheticSequence::new(&laps).unwrap();
    let p = seq.world_from_cam();
    let back = p[90..150].iter().map(|q| (q.translation - p[0].translation).norm()).fold(f64::INFINITY, f64::min);
    let across = (p[60].translation - p[0].translation).norm();
    assert!(back < 0.5 && across > 2.5, "lap returns {back} m from its start, half a lap {across} m");
    // The default arc refuses laps.
    let arc = SynthOptions { path: PathShape::Arc, ..laps };
    assert!(SyntheticSequence::new(&arc).unwrap_err().to_string().contains("half a turn"));

    // A 20 m line in a 23 m room: it moves along x by its length, keeps
    // clear of everything, and its last frame sees none of the first's wall.
    let line = SynthOptions {
        path: PathShape::Line,
        frames: 200,
        path_length: 20.0,
        room_size: [23.0, 5.0, 2.8],
        clutter_boxes: 30,
        ..base.clone()
    };
    let seq = SyntheticSequence::new(&line).unwrap();
    let p = seq.world_from_cam();
    let dx = p[199].translation.x - p[0].translation.x;
    assert!((19.0..21.5).contains(&dx.abs()), "line moved {dx} m along x");
    let first = seq.visible_points(0, 50, 1).unwrap();
    let seen_at_end = first.iter().filter(|s| seq.observe(199, &s.world).unwrap().is_some()).count();
    assert_eq!(seen_at_end, 0, "the last frame sees the first frame's points");
    // A line longer than the room allows is refused by name.
    let long = SynthOptions { path_length: 22.0, ..line };
    assert!(SyntheticSequence::new(&long).unwrap_err().to_string().contains("path_length"));
}
