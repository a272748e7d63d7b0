use super::*;
use crate::frame::tests::frame_data;
use colslam_camera::Camera;
use colslam_geometry::{Vec2, Vec3};

/// A record of frame `index` with observations `(frame_kp, keyframe,
/// keyframe_kp)` at distinct pixels.
fn record(index: usize, obs: &[(u32, u32, u32)]) -> FrameRecord {
    let data = frame_data(index, Vec::new());
    let mut r = FrameRecord::new(&data);
    for &(kp, kf, kf_kp) in obs {
        let px = Vec2::new(100.0 + f64::from(kp) * 3.25, 80.0 + f64::from(kp) * 1.5);
        r.obs.push(RecordObs::new(kp, px, ImageId(kf), kf_kp));
    }
    r
}

fn spill_to(dir: &std::path::Path, budget: usize) -> Option<SpillConfig> {
    Some(SpillConfig { dir: dir.to_path_buf(), prefix: ".out.scratch-".into(), budget })
}

fn links(n: usize, to: Option<(u32, u32)>) -> Vec<Option<TrackElement>> {
    (0..n).map(|k| to.map(|(id, kp)| TrackElement::new(ImageId(id), kp + k as u32))).collect()
}

/// The same history applied to a store: records, matches to a new keyframe
/// while pending, a promotion, culls whose links chain, pooling and
/// compensation.
fn history(store: &mut RecordStore) -> Result<(), SlamError> {
    for i in 0..40usize {
        let kf = 1 + (i / 10) as u32;
        store.push(record(i, &[(0, kf, 2), (1, kf, 3), (2, kf + 1, 4), (3, 9, 1)]))?;
    }
    // Frame 5 saw keyframe 7 while pending; frame 39 became a keyframe.
    let data = frame_data(5, vec![Vec2::new(0.5, 0.25); 6]);
    let m = |q, t| colslam_features::Match { query: q, train: t, distance: 0.0 };
    store.add_matches(5, &data, ImageId(7), &[m(4, 1), m(5, 2)]);
    store.promote(39);
    // Keyframe 1 (frame 100) culled: its keypoints link to keyframe 2;
    // then keyframe 2 to keyframe 3, and keyframe 9 to nothing.
    store.cull(ImageId(1), 100, links(8, Some((2, 10))));
    store.push(record(100, &[(0, 2, 1), (1, 3, 1)]))?;
    store.add_matches(6, &data, ImageId(8), &[m(1, 7)]);
    store.cull(ImageId(2), 39, links(16, Some((3, 20))));
    store.cull(ImageId(9), 101, links(4, None));
    // A relocalised frame's second record, pooled at the end.
    store.push(record(3, &[(7, 3, 5)]))?;
    let velocities = (0..40).map(|i| (i, Vec3::new(0.1 * i as f64, -0.2, 0.05))).collect();
    let camera = Camera::pinhole(640, 480, 500.0, 500.0, 320.5, 240.5);
    store.compensate(Compensation { camera, velocities, readout: 0.03 });
    Ok(())
}

#[test]
fn spilled_records_read_back_as_the_records_kept_in_memory() -> Result<(), SlamError> {
    let dir = tempfile::tempdir().map_err(|e| SlamError::Io { path: "tmp".into(), source: e })?;
    let mut memory = RecordStore::new(None);
    history(&mut memory)?;
    let mut disk = RecordStore::new(spill_to(dir.path(), 0));
    history(&mut disk)?;
    assert!(disk.spilled() > 30, "spilled {}", disk.spilled());
    assert_eq!(memory.spilled(), 0);
    let (all_m, all_d) = (memory.all()?, disk.all()?);
    assert_eq!(all_m, all_d);
    assert_eq!(memory.pooled_all()?, disk.pooled_all()?);
    // The history did change the records.
    let r5 = &all_d[5];
    assert_eq!(r5.obs.iter().map(|o| o.keyframe.0).collect::<Vec<_>>(), vec![3, 3, 3, 7, 7]);
    assert!(all_d.iter().all(|r| r.obs.iter().all(|o| ![1, 2, 9].contains(&o.keyframe.0))), "culled keyframes left");
    assert!(!all_d[39].promoted, "frame 39's keyframe was culled: localised again");
    assert_eq!(all_d[6].obs.last().map(|o| o.keyframe.0), Some(8));
    assert!(all_d.iter().all(|r| r.compensated.len() == r.obs.len()));
    Ok(())
}

#[test]
fn the_file_goes_with_the_last_store_sharing_it() -> Result<(), SlamError> {
    let dir = tempfile::tempdir().map_err(|e| SlamError::Io { path: "tmp".into(), source: e })?;
    let mut store = RecordStore::new(spill_to(dir.path(), 0));
    history(&mut store)?;
    let path = store.file_path().map(std::path::Path::to_path_buf).unwrap_or_default();
    assert!(path.is_file(), "{}", path.display());
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    assert!(name.starts_with(&format!(".out.scratch-{}-", std::process::id())), "{name}");
    let bytes = std::fs::read(&path).map_err(|e| SlamError::Io { path: path.clone(), source: e })?;
    assert_eq!(&bytes[..8], RECORD_FILE_MAGIC);
    assert_eq!(bytes.len() as u64, 8 + store.disk_bytes());
    let copy = store.clone();
    drop(store);
    assert!(path.is_file(), "a clone still reads it");
    assert_eq!(copy.all()?.len(), 42);
    drop(copy);
    assert!(!path.exists(), "removed with the last store");
    let mut cleared = RecordStore::new(spill_to(dir.path(), 0));
    history(&mut cleared)?;
    let path = cleared.file_path().map(std::path::Path::to_path_buf).unwrap_or_default();
    cleared.clear();
    assert!(!path.exists(), "removed when the records are released");
    Ok(())
}

#[test]
fn records_under_the_budget_stay_in_memory() -> Result<(), SlamError> {
    let dir = tempfile::tempdir().map_err(|e| SlamError::Io { path: "tmp".into(), source: e })?;
    let mut store = RecordStore::new(spill_to(dir.path(), 1 << 20));
    history(&mut store)?;
    assert_eq!(store.spilled(), 0);
    assert!(store.file_path().is_none());
    assert_eq!(std::fs::read_dir(dir.path()).map(|d| d.count()).unwrap_or(1), 0, "no file");
    Ok(())
}

#[test]
fn a_cut_or_altered_record_is_an_error_not_a_panic() {
    let mut bytes = Vec::new();
    encode(&record(4, &[(0, 1, 2), (5, 3, 9)]), &mut bytes);
    assert_eq!(decode(&bytes).ok(), Some(record(4, &[(0, 1, 2), (5, 3, 9)])));
    for cut in 0..bytes.len() {
        assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
    }
    let mut long = bytes.clone();
    long.push(0);
    assert!(decode(&long).is_err());
    // An observation count beyond the bytes.
    let at = 8 + 8 + 4 + "000004.png".len() + 1;
    bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(decode(&bytes).is_err());
}
