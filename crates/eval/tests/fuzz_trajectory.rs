//! Fuzzing of the TUM trajectory reader (ground truth and estimates):
//! mutated files give a trajectory or an error, never a panic, a hang or a
//! huge allocation; an accepted trajectory is valid and survives its own
//! writer. See `colslam_testutil::fuzz`; the long run is in
//! docs/benchmarks.md ("Fuzzing").

use std::path::Path;

use colslam_eval::Trajectory;
use colslam_geometry::{Quat, Rigid3, Vec3};
use colslam_testutil::fuzz::{Corpus, fuzz};

colslam_testutil::fuzz_allocator!();

/// Inputs in the default test run.
const CI_ITERS: u64 = 6_000;

fn corpus() -> Corpus {
    let poses: Vec<Rigid3> = (0..4)
        .map(|k| {
            let a = 0.1 * k as f64;
            Rigid3::new(Quat::from_euler_angles(a, -a, 0.5 * a), Vec3::new(a, 1.0 - a, 2.0 * a))
        })
        .collect();
    let written = Trajectory::new(vec![1305031102.1753, 1305031102.2112, 1305031102.2432, 1305031102.2752], poses);
    Corpus::single("groundtruth.txt")
        .sample(written.to_tum_string())
        .sample(
            "# ground truth trajectory\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp tx ty tz qx qy qz qw\n\
             1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n\
             1305031098.6758 1.3543 0.6306 1.6360 0.6129 0.5966 -0.3316 -0.3980\n",
        )
        .sample("\u{feff}0 0 0 0 0 0 0 1\r\n1 0.1 0 0 0 0 0 2\r\n")
        .words(["#", "\u{feff}"])
}

#[test]
fn fuzz_tum_trajectory() {
    let path = Path::new("fuzz/groundtruth.txt");
    fuzz("tum-trajectory", &corpus(), CI_ITERS, |parts| {
        // As read_tum: the bytes must be UTF-8 text.
        let text = std::str::from_utf8(&parts[0]).map_err(|e| e.to_string())?;
        let traj = Trajectory::parse_tum(text, path).map_err(|e| e.to_string())?;
        traj.validate("fuzzed").unwrap_or_else(|e| panic!("accepted an invalid trajectory: {e}"));
        let again = Trajectory::parse_tum(&traj.to_tum_string(), path)
            .unwrap_or_else(|e| panic!("the written accepted trajectory does not parse: {e}"));
        assert_eq!(again, traj, "the trajectory changed through its own writer");
        Ok::<_, String>(())
    });
}
