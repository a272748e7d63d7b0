//! Image-sequence layouts on small fixtures: plain folder, TUM, EuRoC, KITTI;
//! skip / start / max_frames and len_hint on each.

mod common;

use std::path::Path;

use colslam_io::{Frame, FrameSource, Layout, SourceKind, SourceOptions, detect_layout, open_source, probe_source};
use common::{H, W, jpeg, png};

fn collect(path: &Path, opts: &SourceOptions) -> (Box<dyn FrameSource>, Vec<Frame>) {
    let mut src = open_source(path, opts).unwrap();
    let frames: Vec<Frame> = src.by_ref().map(|f| f.unwrap()).collect();
    (src, frames)
}

fn opts(skip: usize, max: Option<usize>, start: usize) -> SourceOptions {
    SourceOptions { skip, max_frames: max, start, ..Default::default() }
}

fn names(frames: &[Frame]) -> Vec<&str> {
    frames.iter().map(|f| f.name.as_str()).collect()
}

#[test]
fn plain_folder_natural_sort_skip_and_limit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    png(&d.join("frame10.png"), 10);
    png(&d.join("frame2.png"), 2);
    png(&d.join("frame1.png"), 1);
    jpeg(&d.join("frame3.JPG"));
    png(&d.join(".frame0.png"), 0); // hidden: ignored
    std::fs::write(d.join("notes.txt"), "not an image").unwrap();
    std::fs::create_dir(d.join("sub.png")).unwrap(); // a folder named like an image: ignored

    assert_eq!(detect_layout(d).unwrap(), Layout::Folder { dir: d.to_path_buf() });
    let (src, frames) = collect(d, &SourceOptions::default());
    assert_eq!(src.kind(), SourceKind::Folder);
    assert_eq!(names(&frames), ["frame1.png", "frame2.png", "frame3.JPG", "frame10.png"]);
    assert_eq!(src.len_hint(), Some(4));
    assert_eq!(src.total_source_frames(), Some(4));
    assert_eq!(src.image_size(), Some((W, H)));
    assert!(src.camera_file().is_none());
    assert_eq!(frames[0].image.get(0, 0, 0), 1);
    assert_eq!(frames[1].image.get(0, 0, 0), 2);
    assert_eq!(frames[3].image.get(0, 0, 0), 10);
    assert!((frames[2].image.get(3, 3, 0) as i32 - 77).abs() <= 1);
    let ts: Vec<f64> = frames.iter().map(|f| f.timestamp).collect();
    assert_eq!(ts, [0.0, 1.0, 2.0, 3.0]);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!((f.index, f.source_index), (i, i));
    }

    // Sizes from headers alone (PNG IHDR, JPEG SOF), and a cut JPEG header fails cleanly.
    assert_eq!(colslam_io::image_size(&d.join("frame3.JPG")).unwrap(), (W, H));
    assert_eq!(colslam_io::image_size(&d.join("frame10.png")).unwrap(), (W, H));
    std::fs::write(d.join("cut.bin"), &common::TINY_JPEG[..40]).unwrap();
    let msg = common::chain(&colslam_io::image_size(&d.join("cut.bin")).unwrap_err());
    assert!(msg.contains("cut.bin"), "{msg}");
    std::fs::remove_file(d.join("cut.bin")).unwrap();

    // skip 2: source frames 0 and 2.
    let (src, frames) = collect(d, &opts(2, None, 0));
    assert_eq!(src.len_hint(), Some(2));
    assert_eq!(names(&frames), ["frame1.png", "frame3.JPG"]);
    assert_eq!(frames[1].source_index, 2);
    assert_eq!(frames[1].index, 1);
    // start 1, skip 2: source frames 1 and 3.
    let (src, frames) = collect(d, &opts(2, None, 1));
    assert_eq!(src.len_hint(), Some(2));
    assert_eq!(names(&frames), ["frame2.png", "frame10.png"]);
    // max_frames 3.
    let (src, frames) = collect(d, &opts(1, Some(3), 0));
    assert_eq!(src.len_hint(), Some(3));
    assert_eq!(frames.len(), 3);
    // fps gives index / fps timestamps.
    let o = SourceOptions { fps: Some(10.0), skip: 3, ..Default::default() };
    let (_, frames) = collect(d, &o);
    assert_eq!(frames.iter().map(|f| f.timestamp).collect::<Vec<_>>(), [0.0, 0.3]);

    // camera.yml beside the images is reported.
    std::fs::write(d.join("camera.yml"), "model: PINHOLE\n").unwrap();
    let info = probe_source(d, &SourceOptions::default()).unwrap();
    assert_eq!(info.camera_file, Some(d.join("camera.yml")));
    assert_eq!(info.frames, Some(4));
    assert_eq!(info.image_size, Some((W, H)));
    assert!(info.description.contains("image folder") && info.description.contains("4 frames"), "{}", info.description);
}

fn tum_fixture(d: &Path, n: usize) -> Vec<f64> {
    let mut list = String::from("# color images\n# file: 'fixture'\n# timestamp filename\n");
    let mut stamps = Vec::new();
    for i in 0..n {
        let t = 1305031229.5 + 0.0333 * i as f64;
        let name = format!("rgb/{t:.6}.png");
        png(&d.join(&name), i as u8);
        list.push_str(&format!("{t:.6} {name}\n"));
        stamps.push(format!("{t:.6}").parse().unwrap());
        if i == 2 {
            list.push('\n'); // blank lines are allowed
        }
    }
    std::fs::write(d.join("rgb.txt"), list).unwrap();
    stamps
}

#[test]
fn tum_layout() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let stamps = tum_fixture(d, 5);
    png(&d.join("stray_image_not_listed.png"), 99);
    let (src, frames) = collect(d, &SourceOptions::default());
    assert_eq!(src.kind(), SourceKind::Tum);
    assert_eq!(frames.len(), 5);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.timestamp, stamps[i]);
        assert_eq!(f.image.get(0, 0, 0), i as u8);
    }
    assert_eq!(frames[0].name, format!("{:.6}.png", stamps[0]));
    assert!(src.describe().starts_with("TUM sequence"), "{}", src.describe());

    let (src, frames) = collect(d, &opts(2, None, 0));
    assert_eq!(src.len_hint(), Some(3));
    assert_eq!(frames.iter().map(|f| f.timestamp).collect::<Vec<_>>(), [stamps[0], stamps[2], stamps[4]]);
    assert_eq!(frames.iter().map(|f| f.source_index).collect::<Vec<_>>(), [0, 2, 4]);
    let (src, frames) = collect(d, &opts(2, Some(2), 0));
    assert_eq!(src.len_hint(), Some(2));
    assert_eq!(frames.len(), 2);
    assert_eq!(src.total_source_frames(), Some(5));

    // The rgb.txt path itself selects the layout; camera.yaml is found.
    std::fs::write(d.join("camera.yaml"), "model: PINHOLE\n").unwrap();
    let (src, frames) = collect(&d.join("rgb.txt"), &SourceOptions::default());
    assert_eq!(src.kind(), SourceKind::Tum);
    assert_eq!(frames.len(), 5);
    assert_eq!(src.camera_file(), Some(d.join("camera.yaml")));
}

#[test]
fn euroc_layout() {
    for cam in ["mav0/cam0", "cam0"] {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cam_dir = d.join(cam);
        let ns: Vec<u64> = (0..4).map(|i| 1_403_636_579_763_555_584 + i * 50_000_000).collect();
        let mut csv = String::from("#timestamp [ns],filename\n");
        for (i, t) in ns.iter().enumerate() {
            png(&cam_dir.join(format!("data/{t}.png")), i as u8 + 1);
            csv.push_str(&format!("{t},{t}.png\r\n")); // CRLF as in some copies
        }
        std::fs::write(cam_dir.join("data.csv"), csv).unwrap();
        std::fs::write(
            cam_dir.join("sensor.yaml"),
            "sensor_type: camera\nintrinsics: [458.654, 457.296, 367.215, 248.375]\n",
        )
        .unwrap();

        let (src, frames) = collect(d, &SourceOptions::default());
        assert_eq!(src.kind(), SourceKind::Euroc, "{cam}");
        assert_eq!(frames.len(), 4);
        assert!((frames[0].timestamp - 1_403_636_579.763_555_5).abs() < 1e-6, "{}", frames[0].timestamp);
        assert!((frames[1].timestamp - frames[0].timestamp - 0.05).abs() < 1e-6);
        assert_eq!(frames[3].image.get(0, 0, 0), 4);
        assert_eq!(frames[0].name, format!("{}.png", ns[0]));
        // sensor.yaml is EuRoC's own format: reported as native calibration, not a camera file.
        assert_eq!(src.camera_file(), None);
        assert_eq!(src.native_calibration_file(), Some(cam_dir.join("sensor.yaml")));
        // A sensor.yaml that colslam_camera can read is the camera file.
        std::fs::write(
            cam_dir.join("sensor.yaml"),
            "model: PINHOLE\nwidth: 8\nheight: 6\nfx: 5\nfy: 5\ncx: 4\ncy: 3\n",
        )
        .unwrap();
        let src = open_source(d, &SourceOptions::default()).unwrap();
        assert_eq!(src.camera_file(), Some(cam_dir.join("sensor.yaml")));
        // A camera.yaml at the root wins.
        std::fs::write(d.join("camera.yaml"), "model: PINHOLE\n").unwrap();
        let src = open_source(d, &SourceOptions::default()).unwrap();
        assert_eq!(src.camera_file(), Some(d.join("camera.yaml")));

        let (src, frames) = collect(d, &opts(3, None, 0));
        assert_eq!(src.len_hint(), Some(2));
        assert_eq!(frames.iter().map(|f| f.image.get(0, 0, 0)).collect::<Vec<_>>(), [1, 4]);
        let (src, frames) = collect(d, &opts(1, Some(1), 2));
        assert_eq!(src.len_hint(), Some(1));
        assert_eq!(frames[0].image.get(0, 0, 0), 3);
        assert_eq!(frames[0].source_index, 2);
        assert_eq!(frames[0].index, 0);
    }
}

#[test]
fn kitti_layout() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let times = [0.0, 0.103_66, 0.207_32, 0.310_98, 0.414_64, 0.518_3];
    let mut txt = String::new();
    for (i, t) in times.iter().enumerate() {
        png(&d.join(format!("image_0/{i:06}.png")), i as u8 + 1);
        txt.push_str(&format!("{t:.6e}\n"));
    }
    std::fs::write(d.join("times.txt"), txt).unwrap();
    std::fs::write(d.join("calib.txt"), "P0: 7.188560e+02 0 6.071928e+02 0 0 7.188560e+02 1.852157e+02 0 0 0 1 0\n")
        .unwrap();
    png(&d.join("image_1/000000.png"), 200); // right camera: ignored

    let (src, frames) = collect(d, &SourceOptions::default());
    assert_eq!(src.kind(), SourceKind::Kitti);
    assert_eq!(frames.len(), 6);
    for (i, f) in frames.iter().enumerate() {
        assert!((f.timestamp - times[i]).abs() < 1e-9);
        assert_eq!(f.image.get(0, 0, 0), i as u8 + 1);
    }
    assert_eq!(src.native_calibration_file(), Some(d.join("calib.txt")));
    let (src, frames) = collect(d, &opts(4, None, 0));
    assert_eq!(src.len_hint(), Some(2));
    assert_eq!(frames.iter().map(|f| f.name.as_str()).collect::<Vec<_>>(), ["000000.png", "000004.png"]);
    let (src, frames) = collect(d, &opts(2, Some(2), 1));
    assert_eq!(src.len_hint(), Some(2));
    assert_eq!(frames.iter().map(|f| f.source_index).collect::<Vec<_>>(), [1, 3]);
    assert!((frames[1].timestamp - times[3]).abs() < 1e-9);

    // A numbered subset of images takes its timestamps by number, not position.
    std::fs::remove_file(d.join("image_0/000000.png")).unwrap();
    std::fs::remove_file(d.join("image_0/000001.png")).unwrap();
    let (_, frames) = collect(d, &SourceOptions::default());
    assert_eq!(frames.len(), 4);
    assert!((frames[0].timestamp - times[2]).abs() < 1e-9);
    // times.txt selects the layout too.
    let (src, _) = collect(&d.join("times.txt"), &SourceOptions::default());
    assert_eq!(src.kind(), SourceKind::Kitti);
}

#[test]
fn kitti_colour_folder_and_count_mismatch() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for name in ["left_a.png", "left_b.png", "left_c.png"] {
        png(&d.join("image_2").join(name), 1);
    }
    std::fs::write(d.join("times.txt"), "0.0\n0.1\n0.2\n").unwrap();
    let (src, frames) = collect(d, &SourceOptions::default());
    assert_eq!(src.kind(), SourceKind::Kitti);
    assert!((frames[2].timestamp - 0.2).abs() < 1e-12);
    std::fs::write(d.join("times.txt"), "0.0\n0.1\n").unwrap();
    let e = open_source(d, &SourceOptions::default()).err().unwrap().to_string();
    assert!(e.contains("times.txt") && e.contains("2 timestamps") && e.contains("3 images"), "{e}");
}

#[test]
fn skipping_frames_reads_only_the_frames_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for i in 0..6u8 {
        png(&d.join(format!("frame{i}.png")), i);
    }
    // A file that cannot be decoded is skipped over without being read.
    std::fs::write(d.join("frame1.png"), b"not a png").unwrap();
    let mut src = open_source(d, &SourceOptions::default()).unwrap();
    let third = src.nth(2).unwrap().unwrap();
    assert_eq!((third.index, third.image.get(0, 0, 0)), (2, 2));
    let fifth = src.nth(1).unwrap().unwrap();
    assert_eq!((fifth.index, fifth.image.get(0, 0, 0)), (4, 4));
    assert!(src.nth(5).is_none(), "past the end");
    assert!(src.next().is_none());
    // The broken file is still reported when it is asked for.
    let mut src = open_source(d, &SourceOptions::default()).unwrap();
    assert!(src.nth(1).unwrap().is_err());
}
