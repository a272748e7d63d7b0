//! Fuzzing of the sequence list parsers: TUM `rgb.txt`, EuRoC `data.csv`
//! and KITTI `times.txt`, through `ImageSequence::open_layout` on a folder
//! holding the images the valid lists name. Mutated lists give a sequence or
//! an error, never a panic, a hang or a huge allocation. See
//! `colslam_testutil::fuzz`; the long run is in docs/benchmarks.md
//! ("Fuzzing").

mod common;

use colslam_io::{ImageSequence, Layout, SourceOptions};
use colslam_testutil::fuzz::{Corpus, Scratch, fuzz};
use common::png;

colslam_testutil::fuzz_allocator!();

/// Inputs per layout in the default test run.
const CI_ITERS: u64 = 4_000;

/// Words of every list format.
const LIST_WORDS: [&str; 8] = ["rgb/1.png", "2.png", "000001.png", ".png", "/", "..", "#timestamp", "\\"];

/// Opens the sequence of `layout` with default options and lists its
/// paths.
fn open(scratch: &Scratch, layout: Layout) -> Result<usize, colslam_io::SourceError> {
    let seq = ImageSequence::open_layout(scratch.path(), layout, &SourceOptions::default())?;
    Ok(seq.paths().count())
}

#[test]
fn fuzz_tum_rgb_txt() {
    let mut scratch = Scratch::new();
    for k in 1..=3 {
        png(&scratch.path().join(format!("rgb/{k}.png")), k);
    }
    let corpus = Corpus::single("rgb.txt")
        .sample(
            "# color images\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n\
             1305031102.175304 rgb/1.png\n1305031102.211214 rgb/2.png\n1305031102.243211 rgb/3.png\n",
        )
        .sample("0.5 rgb/3.png\r\n1.0 rgb/1.png\r\n")
        .sample("  0 rgb/2.png  \n\n# end\n")
        .words(LIST_WORDS);
    fuzz("tum-rgb.txt", &corpus, CI_ITERS, |parts| {
        let list = scratch.put("rgb.txt", Some(&parts[0]));
        open(&scratch, Layout::Tum { dir: scratch.path().to_path_buf(), list })
    });
}

#[test]
fn fuzz_euroc_data_csv() {
    let mut scratch = Scratch::new();
    let stamps = ["1403636579763555584", "1403636579813555456", "1403636579863555584"];
    for (k, s) in stamps.iter().enumerate() {
        png(&scratch.path().join(format!("mav0/cam0/data/{s}.png")), k as u8);
    }
    let lines: Vec<String> = stamps.iter().map(|s| format!("{s},{s}.png\n")).collect();
    let corpus = Corpus::single("data.csv")
        .sample(format!("#timestamp [ns],filename\n{}", lines.concat()))
        .sample(format!("{}\r\n{}", lines[0].trim_end(), lines[2]))
        .sample(format!("  {} , {}.png  \n", stamps[1], stamps[1]))
        .words(stamps)
        .words(LIST_WORDS);
    fuzz("euroc-data.csv", &corpus, CI_ITERS, |parts| {
        let list = scratch.put("mav0/cam0/data.csv", Some(&parts[0]));
        let root = scratch.path().to_path_buf();
        open(&scratch, Layout::Euroc { cam_dir: root.join("mav0/cam0"), root, list })
    });
}

#[test]
fn fuzz_kitti_times_txt() {
    let mut scratch = Scratch::new();
    for k in 0..3 {
        png(&scratch.path().join(format!("image_0/{k:06}.png")), k);
    }
    let corpus = Corpus::single("times.txt")
        .sample("0.000000e+00\n1.036594e-01\n2.073188e-01\n")
        .sample("0\n0.1\n0.2\n0.3\n0.4\r\n")
        .sample("# comment\n  1.5  \n\n2.5\n3.5\n")
        .words(LIST_WORDS);
    fuzz("kitti-times.txt", &corpus, CI_ITERS, |parts| {
        let times = scratch.put("times.txt", Some(&parts[0]));
        let dir = scratch.path().to_path_buf();
        open(&scratch, Layout::Kitti { image_dir: dir.join("image_0"), dir, times })
    });
}
