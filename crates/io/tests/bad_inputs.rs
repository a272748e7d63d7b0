//! Bad inputs for image sequences: each gives an error (never a panic) whose
//! message names the file at fault.

mod common;

use std::path::Path;

use colslam_io::{SourceError, SourceOptions, open_source, probe_source};
use common::{chain, png};

fn open_err(path: &Path, opts: &SourceOptions) -> SourceError {
    match open_source(path, opts) {
        Ok(_) => panic!("{} opened without error", path.display()),
        Err(e) => e,
    }
}

fn write_tum(d: &Path, lines: &[&str]) {
    std::fs::write(d.join("rgb.txt"), lines.join("\n")).unwrap();
}

#[test]
fn missing_image_listed_in_rgb_txt() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    png(&d.join("rgb/1.png"), 1);
    write_tum(d, &["# comment", "1.0 rgb/1.png", "2.0 rgb/2.png"]);
    let e = open_err(d, &SourceOptions::default());
    assert!(matches!(e, SourceError::MissingListedImage { line: 3, .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("rgb/2.png") && msg.contains("rgb.txt") && msg.contains("line 3"), "{msg}");
    // Not selected (max_frames 1): no error, the listed image is never needed.
    let src = open_source(d, &SourceOptions { max_frames: Some(1), ..Default::default() }).unwrap();
    assert_eq!(src.count(), 1);
}

#[test]
fn missing_image_listed_in_data_csv() {
    let dir = tempfile::tempdir().unwrap();
    let cam = dir.path().join("mav0/cam0");
    png(&cam.join("data/100.png"), 1);
    std::fs::write(cam.join("data.csv"), "#timestamp [ns],filename\n100,100.png\n200,200.png\n").unwrap();
    let msg = open_err(dir.path(), &SourceOptions::default()).to_string();
    assert!(msg.contains("200.png") && msg.contains("data.csv"), "{msg}");
}

#[test]
fn corrupt_image_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    png(&d.join("rgb/1.png"), 1);
    let mut bytes = std::fs::read(d.join("rgb/1.png")).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(d.join("rgb/2.png"), &bytes).unwrap(); // truncated PNG
    std::fs::write(d.join("rgb/3.png"), b"this is not a png").unwrap();
    png(&d.join("rgb/4.png"), 4);
    write_tum(d, &["1.0 rgb/1.png", "2.0 rgb/2.png", "3.0 rgb/3.png", "4.0 rgb/4.png"]);
    let items: Vec<_> = open_source(d, &SourceOptions::default()).unwrap().collect();
    assert_eq!(items.len(), 4);
    assert!(items[0].is_ok());
    for (i, name) in [(1, "2.png"), (2, "3.png")] {
        // The file is named by the cause (the decoding error), printed in the chain.
        let msg = chain(items[i].as_ref().unwrap_err());
        assert!(msg.contains(name) && msg.contains("rgb.txt line"), "{msg}");
    }
    // A bad frame is consumed; the next good one still reads.
    assert_eq!(items[3].as_ref().unwrap().image.get(0, 0, 0), 4);

    // A corrupt first image in a plain folder: open works, the frame errs.
    let dir2 = tempfile::tempdir().unwrap();
    std::fs::write(dir2.path().join("a.png"), [0x89, b'P', b'N', b'G', 0, 1, 2]).unwrap();
    let mut src = open_source(dir2.path(), &SourceOptions::default()).unwrap();
    assert_eq!(src.image_size(), None);
    let msg = chain(&src.next().unwrap().unwrap_err());
    assert!(msg.contains("a.png"), "{msg}");
}

#[test]
fn malformed_list_lines_name_file_line_and_content() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    png(&d.join("rgb/1.png"), 1);
    for (lines, bad_line, content) in [
        (vec!["# c", "1.0 rgb/1.png", "", "abc rgb/1.png"], 4, "abc rgb/1.png"),
        (vec!["1.0 rgb/1.png", "2.0"], 2, "2.0"),
        (vec!["1.0 rgb/1.png extra"], 1, "1.0 rgb/1.png extra"),
        (vec!["nan rgb/1.png"], 1, "nan rgb/1.png"),
    ] {
        write_tum(d, &lines);
        let e = open_err(d, &SourceOptions::default());
        let msg = e.to_string();
        assert!(matches!(e, SourceError::MalformedLine { .. }), "{msg}");
        assert!(msg.contains(&format!("rgb.txt:{bad_line}")) && msg.contains(content), "{msg}");
    }

    let cam = d.join("euroc/cam0");
    std::fs::create_dir_all(cam.join("data")).unwrap();
    std::fs::write(cam.join("data.csv"), "#timestamp [ns],filename\n12x,1.png\n").unwrap();
    let msg = open_err(&d.join("euroc"), &SourceOptions::default()).to_string();
    assert!(msg.contains("data.csv:2") && msg.contains("12x"), "{msg}");
    std::fs::write(cam.join("data.csv"), "100;1.png\n").unwrap();
    let msg = open_err(&d.join("euroc"), &SourceOptions::default()).to_string();
    assert!(msg.contains("data.csv:1") && msg.contains("100;1.png"), "{msg}");

    let k = d.join("kitti");
    png(&k.join("image_0/000000.png"), 1);
    std::fs::write(k.join("times.txt"), "0.0\nzero point one\n").unwrap();
    let msg = open_err(&k, &SourceOptions::default()).to_string();
    assert!(msg.contains("times.txt:2") && msg.contains("zero point one"), "{msg}");
}

#[test]
fn existing_paths_of_the_wrong_kind_are_not_called_missing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    png(&d.join("rgb/1.png"), 1);
    std::fs::create_dir_all(d.join("rgb/2.png")).unwrap();
    write_tum(d, &["1.0 rgb/1.png", "2.0 rgb/2.png", "3.0 rgb/3.png"]);
    let e = open_err(d, &SourceOptions::default());
    let msg = e.to_string();
    assert!(matches!(e, SourceError::UnusableListedImage { line: 2, .. }), "{msg}");
    assert!(msg.contains("2.png") && msg.contains("is a folder") && !msg.contains("does not exist"), "{msg}");
    std::fs::remove_dir(d.join("rgb/2.png")).unwrap();
    png(&d.join("rgb/2.png"), 2);
    let msg = open_err(d, &SourceOptions::default()).to_string();
    assert!(msg.contains("3.png") && msg.contains("line 3") && msg.contains("does not exist"), "{msg}");

    // A video path that is a folder.
    let folder = d.join("clip.mp4");
    std::fs::create_dir(&folder).unwrap();
    let e = colslam_io::VideoSource::open(&folder, &SourceOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, SourceError::NotAFile { what: "a folder", .. }), "{msg}");
    assert!(!msg.contains("no such file"), "{msg}");
}

#[test]
fn repeated_or_decreasing_timestamps_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    png(&d.join("rgb/1.png"), 1);
    png(&d.join("rgb/2.png"), 2);
    for (lines, bad_line, how) in [
        (vec!["# c", "1.0 rgb/1.png", "1.0 rgb/2.png"], 3, "repeats the one on line 2"),
        (vec!["2.0 rgb/1.png", "", "1.5 rgb/2.png"], 3, "is earlier than the one on line 1"),
    ] {
        write_tum(d, &lines);
        let e = open_err(d, &SourceOptions::default());
        let msg = e.to_string();
        assert!(matches!(e, SourceError::MalformedLine { .. }), "{msg}");
        assert!(msg.contains(&format!("rgb.txt:{bad_line}")) && msg.contains(how), "{msg}");
    }

    let cam = d.join("euroc/cam0");
    png(&cam.join("data/1.png"), 1);
    png(&cam.join("data/2.png"), 2);
    std::fs::write(cam.join("data.csv"), "#timestamp [ns],filename\n200,1.png\n100,2.png\n").unwrap();
    let msg = open_err(&d.join("euroc"), &SourceOptions::default()).to_string();
    assert!(msg.contains("data.csv:3") && msg.contains("is earlier than the one on line 2"), "{msg}");

    let k = d.join("kitti");
    png(&k.join("image_0/000000.png"), 1);
    png(&k.join("image_0/000001.png"), 2);
    std::fs::write(k.join("times.txt"), "0.1\n0.1\n").unwrap();
    let msg = open_err(&k, &SourceOptions::default()).to_string();
    assert!(msg.contains("times.txt:2") && msg.contains("repeats"), "{msg}");
}

#[test]
fn empty_and_missing_paths() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty_seq");
    std::fs::create_dir(&empty).unwrap();
    let msg = open_err(&empty, &SourceOptions::default()).to_string();
    assert!(msg.contains("no images in") && msg.contains("empty_seq"), "{msg}");
    // A folder with only a video hints at passing the video.
    std::fs::write(empty.join("clip.mp4"), b"x").unwrap();
    std::fs::create_dir(empty.join("clip_frames")).unwrap();
    png(&empty.join("clip_frames/0.png"), 0);
    let msg = open_err(&empty, &SourceOptions::default()).to_string();
    assert!(msg.contains("clip.mp4") && msg.contains("clip_frames"), "{msg}");

    let missing = dir.path().join("does_not_exist");
    let e = open_err(&missing, &SourceOptions::default());
    assert!(matches!(e, SourceError::NotFound { .. }));
    assert!(e.to_string().contains("does_not_exist"));
    assert!(probe_source(&missing, &SourceOptions::default()).is_err());

    // An rgb.txt with no entries.
    let tum = dir.path().join("tum");
    std::fs::create_dir(&tum).unwrap();
    std::fs::write(tum.join("rgb.txt"), "# only comments\n").unwrap();
    let msg = open_err(&tum, &SourceOptions::default()).to_string();
    assert!(msg.contains("rgb.txt") && msg.contains("names no images"), "{msg}");

    // A single image and a text file are not sequences.
    let img = dir.path().join("one.png");
    png(&img, 1);
    let msg = open_err(&img, &SourceOptions::default()).to_string();
    assert!(msg.contains("one.png") && msg.contains("single image"), "{msg}");
    let txt = dir.path().join("groundtruth.txt");
    std::fs::write(&txt, "1 2 3").unwrap();
    let msg = open_err(&txt, &SourceOptions::default()).to_string();
    assert!(msg.contains("groundtruth.txt"), "{msg}");
}

#[test]
fn invalid_options_and_start_past_end() {
    let dir = tempfile::tempdir().unwrap();
    png(&dir.path().join("a.png"), 1);
    png(&dir.path().join("b.png"), 2);
    let e = open_err(dir.path(), &SourceOptions { skip: 0, ..Default::default() });
    assert!(matches!(e, SourceError::InvalidOptions(_)));
    assert!(e.to_string().contains("skip"), "{e}");
    let e = open_err(dir.path(), &SourceOptions { max_frames: Some(0), ..Default::default() });
    assert!(matches!(e, SourceError::InvalidOptions(_)));
    let msg = open_err(dir.path(), &SourceOptions { start: 5, ..Default::default() }).to_string();
    assert!(msg.contains("start 5") && msg.contains("2 frames"), "{msg}");
}

#[test]
fn size_change_mid_sequence_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    png(&dir.path().join("0.png"), 1);
    colslam_image::Image::new(5, 5, 3).write_png(&dir.path().join("1.png")).unwrap();
    let items: Vec<_> = open_source(dir.path(), &SourceOptions::default()).unwrap().collect();
    assert!(items[0].is_ok());
    let msg = items[1].as_ref().unwrap_err().to_string();
    assert!(msg.contains("1.png") && msg.contains("5x5") && msg.contains("8x6"), "{msg}");
}
