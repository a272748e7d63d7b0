//! Loop closure by appearance (`--loop-closure`, `mapper/loop_closure.rs`)
//! on the exact synthetic scenes of the mapper's tests: a camera circling
//! inside a ring of wall points comes back to where it started.

use super::*;

/// Radius of the camera's circle and of the wall.
const CIRCLE_R: f64 = 3.0;
const WALL_R: f64 = 6.0;
/// Degrees the camera turns per frame; frames per lap.
const STEP_DEG: f64 = 10.0;
const LAP: usize = 36;

/// Frame `k` on the circle, looking outwards at the wall.
fn circle_pose(k: usize) -> Rigid3 {
    let a = (k as f64 * STEP_DEG).to_radians();
    let z = Vec3::new(a.cos(), a.sin(), 0.0);
    let y = Vec3::new(0.0, 0.0, -1.0);
    let x = y.cross(&z);
    let world_from_cam = colslam_geometry::Mat3::from_columns(&[x, y, z]);
    let rotation = Quat::from_matrix(&world_from_cam.transpose());
    let centre = CIRCLE_R * z;
    Rigid3::new(rotation, -(rotation * centre))
}

/// A lap and `extra` frames of the circle, 2400 points on the wall.
fn circling(extra: usize) -> Scene {
    let mut r = SplitMix64::new(11);
    let points = (0..2400)
        .map(|_| {
            let a = r.uniform(0.0, std::f64::consts::TAU);
            Vec3::new(WALL_R * a.cos(), WALL_R * a.sin(), r.uniform(-2.0, 2.0))
        })
        .collect();
    Scene::new((0..LAP + extra).map(circle_pose).collect(), points, 5)
}

fn loop_opts() -> SlamOptions {
    let mut o = opts();
    // Revisit matching by pose would tie the lap's end to its start by
    // itself: off, so only appearance can.
    o.mapper.match_revisited = 0;
    o.mapper.loop_closure = true;
    o
}

/// Registers every frame after the initial pair as a keyframe, looking for
/// a loop after each when `close` (the pipeline's order); returns the map.
/// The initial pair is frames 0 and `second`.
fn run(scene: &Scene, o: &SlamOptions, close: bool, second: usize) -> Mapper {
    let frontend = scene.frontend();
    let (mut map, _, _) = initialize(scene, &[0, second], o).expect("initialises");
    for f in second + 1..scene.poses.len() {
        let id = registered(&mut map, scene, f, &frontend, o);
        if close {
            map.close_loop(id, &frontend, o, &mut StageTimings::default()).unwrap();
        }
    }
    map
}

/// Scene points the map holds as more than one 3D point.
fn duplicated(scene: &Scene, map: &Mapper) -> usize {
    let mut count: BTreeMap<usize, usize> = BTreeMap::new();
    for (_, t) in scene.point_truths(map) {
        *count.entry(t).or_default() += 1;
    }
    count.values().filter(|&&c| c > 1).count()
}

#[test]
fn a_lap_back_to_the_start_closes_the_loop_and_fuses_its_points() {
    let scene = circling(1);
    let open = run(&scene, &loop_opts(), false, 1);
    let before = duplicated(&scene, &open);
    assert!(before > 30, "without closure the lap's end maps its start again: {before} duplicates");
    let map = run(&scene, &loop_opts(), true, 1);
    let loops = map.loops();
    assert_eq!(loops.len(), 1, "{loops:?}");
    let l = &loops[0];
    assert!(l.frame >= LAP && l.loop_frame < 8, "{l:?}");
    assert!(l.inliers >= super::super::loop_closure::LOOP_MIN_INLIERS, "{l:?}");
    let after = duplicated(&scene, &map);
    eprintln!("{l:?} {after} {before}");
    assert!(after * 10 < before, "{after} duplicates left of {before}");
    scene.assert_within(&map, 1e-3);
}

#[test]
fn no_loop_is_closed_on_a_path_that_never_comes_back() {
    // Half a lap: the wall ahead is always new.
    let scene = circling(0);
    let half = Scene::new(scene.poses[..LAP / 2].to_vec(), scene.points.clone(), 5);
    let map = run(&half, &loop_opts(), true, 1);
    assert!(map.loops().is_empty(), "{:?}", map.loops());
    // A path along a wall whose last stretch repeats the first stretch's
    // texture on other geometry: the words say "been here", the Sim(3)
    // between the two stretches' points must say no.
    let mut r = SplitMix64::new(5);
    let mut slab = |n: usize, x0: f64, x1: f64| -> Vec<Vec3> {
        (0..n).map(|_| Vec3::new(r.uniform(x0, x1), r.uniform(-2.0, 2.0), r.uniform(6.0, 12.0))).collect()
    };
    let (first, middle) = (slab(500, -4.0, 3.0), slab(700, 3.0, 11.0));
    // The same columns 15 units on, at other heights and depths.
    let last: Vec<Vec3> =
        first.iter().map(|p| Vec3::new(p.x + 15.0, r.uniform(-2.0, 2.0), r.uniform(6.0, 12.0))).collect();
    let tags: Vec<u64> = (0..500).chain(500..1200).chain(0..500).collect();
    let points = [first, middle, last].concat();
    let mut line = Scene::new((0..61).map(path_pose).collect(), points, 9);
    line.desc_tags = tags;
    let map = run(&line, &loop_opts(), true, 4);
    assert!(map.loops().is_empty(), "{:?}", map.loops());
}
