//! A model folder is written as a whole: a reader finds one complete model,
//! never a mix of two writes or formats, whatever happens to the writer
//! (killed at any step, another writer at the same time, an old model of
//! another format in the folder), and nothing of the writer is left behind.

mod common;

use colslam_image::{OutputError, fault};
use colslam_scene::{ModelFormat, Reconstruction, SceneError, read_model, write_model};
use common::{synthetic_model, to_json};
use std::path::Path;

/// Names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

fn same(a: &Reconstruction, b: &Reconstruction) -> bool {
    to_json(a, true) == to_json(b, true)
}

#[test]
fn a_model_of_another_format_replaces_the_old_one() {
    // Regression: a text model written over a binary one left the .bin
    // files, and readers (which prefer binary) read the old model.
    let dir = tempfile::tempdir().unwrap();
    let (old, new) = (synthetic_model(1), synthetic_model(2));
    write_model(&old, dir.path(), ModelFormat::Binary).unwrap();
    write_model(&new, dir.path(), ModelFormat::Text).unwrap();
    assert!(same(&read_model(dir.path()).unwrap(), &new), "the new model is read");
    assert!(names(dir.path()).iter().all(|n| n.ends_with(".txt")), "{:?}", names(dir.path()));
}

#[test]
fn a_folder_of_other_files_is_not_replaced() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("notes.md"), "mine").unwrap();
    let err = write_model(&synthetic_model(1), dir.path(), ModelFormat::Binary).unwrap_err();
    assert!(matches!(&err, SceneError::Output(OutputError::Foreign { entry, .. }) if entry == "notes.md"), "{err}");
    assert_eq!(names(dir.path()), ["notes.md"]);
}

#[test]
fn a_model_write_killed_at_any_step_leaves_one_whole_model() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("model");
    let (a, b) = (synthetic_model(3), synthetic_model(4));
    write_model(&a, &dir, ModelFormat::Binary).unwrap();
    fault::kill_at(Some(usize::MAX));
    write_model(&b, &dir, ModelFormat::Text).unwrap();
    let steps = fault::steps();
    fault::kill_at(None);
    assert!(steps >= 18, "{steps} steps: the lock, the staging folder, 5 files, the swap");
    for k in 0..steps {
        // Alternate which model and format is the previous one.
        let (prev, next, format) = if k % 2 == 0 { (&a, &b, ModelFormat::Text) } else { (&b, &a, ModelFormat::Binary) };
        let other = if format == ModelFormat::Text { ModelFormat::Binary } else { ModelFormat::Text };
        write_model(prev, &dir, other).unwrap();
        fault::kill_at(Some(k));
        assert!(write_model(next, &dir, format).is_err(), "step {k}: the kill stops the write");
        fault::kill_at(None);
        let read = read_model(&dir).unwrap_or_else(|e| panic!("step {k}: no whole model: {e}"));
        assert!(same(&read, prev) || same(&read, next), "step {k}: a model of neither write");
        let files = names(&dir);
        let one_format = files.iter().all(|n| n.ends_with(".bin")) || files.iter().all(|n| n.ends_with(".txt"));
        assert!(one_format && files.len() == 5, "step {k}: {files:?}");
        // The next write cleans whatever the killed one left.
        write_model(next, &dir, format).unwrap();
        assert!(same(&read_model(&dir).unwrap(), next));
        assert_eq!(names(root.path()), ["model"], "step {k}: leftovers beside the model");
        assert_eq!(names(&dir).len(), 5, "step {k}: leftovers in the model");
    }
}

#[test]
fn twenty_writers_of_one_folder_at_once_write_or_are_refused() {
    // Regression: threads of one process shared a temporary name and failed
    // with "No such file or directory", or mixed their models.
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("model");
    let models: Vec<Reconstruction> = (0..20).map(|i| synthetic_model(10 + i)).collect();
    let results: Vec<Result<(), SceneError>> = std::thread::scope(|s| {
        let handles: Vec<_> = models
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let dir = &dir;
                let format = if i % 2 == 0 { ModelFormat::Binary } else { ModelFormat::Text };
                s.spawn(move || write_model(m, dir, format))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for r in &results {
        match r {
            Ok(()) | Err(SceneError::Output(OutputError::Locked { .. })) => {}
            Err(e) => panic!("neither written nor refused by the lock: {e}"),
        }
    }
    let written: Vec<&Reconstruction> =
        results.iter().zip(&models).filter(|(r, _)| r.is_ok()).map(|(_, m)| m).collect();
    assert!(!written.is_empty());
    let read = read_model(&dir).unwrap();
    assert!(written.iter().any(|m| same(&read, m)), "the folder holds one writer's whole model");
    assert_eq!(names(&dir).len(), 5, "{:?}", names(&dir));
    assert_eq!(names(root.path()), ["model"], "no lock or staging folder left");
}
