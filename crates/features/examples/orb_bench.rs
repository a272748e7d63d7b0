//! Timing of ORB extraction and brute-force Hamming matching on TUM frames.
//!
//! `cargo run --release -p colslam-features --example orb_bench [frames_dir] [n_frames]`
//! (default: the `tum_fr1_rpy_sub` dataset). Set `RAYON_NUM_THREADS` to fix
//! the thread count. `ORB_REPORT=1` prints the per-level report of the first
//! frame; `ORB_ONLY=1` times extraction alone (`ORB_FAST_SCORE=1`: FAST
//! ranking instead of Harris). Reports wall time and process CPU time; on a
//! shared, loaded machine the CPU time is the meaningful one.

use colslam_features::{FeatureExtractor, Matcher, NnMatcher, NnMatcherOptions, OrbExtractor, OrbOptions};
use colslam_image::Image;
use std::path::PathBuf;
use std::time::Instant;

/// CPU time of the whole process (all threads) in milliseconds, from the
/// per-thread scheduler statistics (nanosecond resolution, Linux only; 0
/// elsewhere). On a loaded machine this is closer to the true cost than wall
/// time.
fn cpu_ms() -> f64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else { return 0.0 };
    dir.filter_map(|e| e.ok())
        .filter_map(|e| std::fs::read_to_string(e.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next().and_then(|v| v.parse::<f64>().ok()))
        .sum::<f64>()
        / 1e6
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let dir = match args.get(1) {
        Some(d) => PathBuf::from(d),
        None => colslam_testutil::dataset("tum_fr1_rpy_sub").ok_or("no dataset")?.join("rgb"),
    };
    let n: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(20);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    files.truncate(n);
    let frames: Vec<Image> = files.iter().map(|f| Image::read(f).map(|i| i.to_gray())).collect::<Result<_, _>>()?;
    println!(
        "{} frames {}x{}, rayon threads {}",
        frames.len(),
        frames[0].width(),
        frames[0].height(),
        rayon::current_num_threads()
    );
    if std::env::var_os("ORB_REPORT").is_some() {
        let ex = OrbExtractor::new(OrbOptions::default())?;
        let (_, rep) = ex.extract_with_report(&frames[0])?;
        for l in &rep.levels {
            println!("{l:?}");
        }
    }
    if std::env::var_os("ORB_ONLY").is_some() {
        let score = if std::env::var_os("ORB_FAST_SCORE").is_some() {
            colslam_features::ScoreType::Fast
        } else {
            colslam_features::ScoreType::Harris
        };
        let ex = OrbExtractor::new(OrbOptions { score, ..Default::default() })?;
        let c = cpu_ms();
        for _ in 0..10 {
            for f in &frames {
                ex.extract(f)?;
            }
        }
        println!("extract only: cpu {:.2} ms/frame", (cpu_ms() - c) / (10 * frames.len()) as f64);
        return Ok(());
    }
    for nf in [1000usize, 2000] {
        let ex = OrbExtractor::new(OrbOptions { n_features: nf, ..Default::default() })?;
        let _ = ex.extract(&frames[0])?; // warm up
        let t = Instant::now();
        let c = cpu_ms();
        let mut total = 0;
        let mut feats = Vec::new();
        for f in &frames {
            let r = ex.extract(f)?;
            total += r.len();
            feats.push(r);
        }
        let ms = t.elapsed().as_secs_f64() * 1e3 / frames.len() as f64;
        let cms = (cpu_ms() - c) / frames.len() as f64;
        println!(
            "extract n_features={nf}: wall {ms:.2} ms/frame, cpu {cms:.2} ms/frame, {:.0} keypoints/frame",
            total as f64 / frames.len() as f64
        );
        let m = NnMatcher::new(NnMatcherOptions::default())?;
        let pairs = feats.len() - 1;
        let t = Instant::now();
        let c = cpu_ms();
        let mut nm = 0;
        for w in feats.windows(2) {
            nm += m.match_features(&w[0], &w[1])?.len();
        }
        let ms = t.elapsed().as_secs_f64() * 1e3 / pairs as f64;
        let cms = (cpu_ms() - c) / pairs as f64;
        println!(
            "match consecutive (cross-check+ratio) {nf}x{nf}: wall {ms:.2} ms/pair, cpu {cms:.2} ms/pair, {:.0} matches/pair",
            nm as f64 / pairs as f64
        );
    }
    Ok(())
}
