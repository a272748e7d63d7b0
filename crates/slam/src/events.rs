//! Typed events for consumers such as the viewer. The pipeline sends them
//! over an unbounded channel, so the mapping loop never waits on a consumer;
//! a consumer that went away is simply no longer sent to.

use colslam_geometry::{Rigid3, Vec3};
use std::sync::mpsc::{Receiver, Sender, channel};

/// One event of a run.
#[derive(Debug, Clone)]
pub enum SlamEvent {
    /// A frame went through the keyframe test.
    FrameProcessed {
        /// Frame index (after skip).
        index: usize,
        /// Timestamp, seconds.
        timestamp: f64,
        /// Flow score against the last keyframe.
        flow_score: f64,
        /// Matches to the last keyframe.
        num_matches: usize,
        /// Of those, the matches the frame's geometric verification kept:
        /// the inliers of the two-view geometry against the keyframe (the
        /// number the debug log reports for the frame).
        num_inliers: usize,
        /// Flow lines `[x_frame, y_frame, x_keyframe, y_keyframe]` in pixels
        /// (OpenCV convention) of the verified matches: one per inlier (at
        /// most [`MAX_INLIER_LINES`]).
        flow_lines: Vec<[f32; 4]>,
        /// The same for the matches verification rejected, a subsample of at
        /// most [`MAX_OUTLIER_LINES`].
        outlier_lines: Vec<[f32; 4]>,
        /// Whether it became a keyframe.
        is_keyframe: bool,
    },
    /// A keyframe was registered.
    KeyframeAdded {
        /// Map (0 = first).
        map: usize,
        /// Image id in the map.
        image_id: u32,
        /// Frame index.
        frame_index: usize,
        /// Pose.
        cam_from_world: Rigid3,
        /// 3D points it observes.
        num_points: usize,
    },
    /// The map changed (after triangulation and bundle adjustment). Points
    /// and poses are sent as increments: upserted points and keyframe poses,
    /// and the ids of removed points; `full` marks a complete snapshot that
    /// replaces the consumer's copy (after global BA or a map reset).
    MapUpdated {
        /// Map index.
        map: usize,
        /// A complete snapshot rather than an increment.
        full: bool,
        /// Points added or moved.
        points: Vec<EventPoint>,
        /// Ids of points removed since the last update.
        removed_points: Vec<u64>,
        /// Keyframe poses added or changed: (image id, frame index, pose).
        poses: Vec<(u32, usize, Rigid3)>,
        /// Registered keyframes.
        keyframes: usize,
        /// 3D points.
        num_points: usize,
        /// Observations.
        observations: usize,
        /// Mean reprojection error, px.
        mean_reproj_error: f64,
    },
    /// A bundle adjustment finished.
    BundleAdjusted {
        /// Map index.
        map: usize,
        /// True for global BA.
        global: bool,
        /// Final cost.
        final_cost: f64,
        /// Iterations.
        iterations: usize,
    },
    /// Tracking was lost and a new map started.
    MapReset {
        /// Index of the new map.
        new_map: usize,
        /// Frame at which it happened.
        frame_index: usize,
        /// Why.
        reason: String,
    },
    /// The run finished.
    Finished,
}

/// Where the pipeline sends its events; a disconnected or absent receiver
/// costs nothing.
#[derive(Debug, Clone, Default)]
pub struct EventSink {
    tx: Option<Sender<SlamEvent>>,
}

impl EventSink {
    /// A sink that drops everything.
    pub fn none() -> Self {
        Self { tx: None }
    }

    /// A sink and the receiver of its events.
    pub fn channel() -> (Self, Receiver<SlamEvent>) {
        let (tx, rx) = channel();
        (Self { tx: Some(tx) }, rx)
    }

    /// True when somebody may be listening.
    pub fn is_active(&self) -> bool {
        self.tx.is_some()
    }

    /// Sends an event; never blocks. Stops sending once the receiver is gone.
    pub fn send(&mut self, event: SlamEvent) {
        if let Some(tx) = &self.tx
            && tx.send(event).is_err()
        {
            self.tx = None;
        }
    }
}

/// A 3D point as sent to consumers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EventPoint {
    /// Point id.
    pub id: u64,
    /// Position.
    pub xyz: Vec3,
    /// Colour.
    pub color: [u8; 3],
}

/// Flow lines of verified matches sent per frame event: all of them up to
/// the automatic keypoint cap, so a consumer can draw one per inlier.
pub const MAX_INLIER_LINES: usize = crate::options::AUTO_FEATURES_MAX;

/// Flow lines of rejected matches sent per frame event (a subsample).
pub const MAX_OUTLIER_LINES: usize = 300;

/// A frame's matches to its reference keyframe as consumers draw them,
/// split by the frame's geometric verification.
#[derive(Debug, Default)]
pub(crate) struct FrameFlow {
    num_matches: usize,
    num_inliers: usize,
    inlier_lines: Vec<[f32; 4]>,
    outlier_lines: Vec<[f32; 4]>,
}

/// Turns the pipeline's progress into events: what was sent of the current
/// map (so map updates are increments) and the diagnostics that only
/// consumers need. Costs nothing without a consumer.
#[derive(Debug, Default)]
pub(crate) struct Emitter {
    sink: EventSink,
    /// Keyframes whose points moved in a local BA (the newest ones).
    local_ba_images: usize,
    /// Point ids of the current map sent so far.
    sent_points: std::collections::HashSet<colslam_scene::Point3DId>,
    /// Ground truth for diagnostics: when set, the keyframes' ATE is logged
    /// (debug level) after every keyframe.
    debug_gt: Option<colslam_eval::trajectory::Trajectory>,
}

/// Lines `[x_frame, y_frame, x_keyframe, y_keyframe]` of `matches`, every
/// `step`-th one, at most `max`.
fn flow_lines<'a>(
    matches: impl Iterator<Item = &'a colslam_features::Match>,
    frame: &crate::frame::FrameData,
    reference: &crate::frame::FrameData,
    step: usize,
    max: usize,
) -> Vec<[f32; 4]> {
    matches
        .step_by(step.max(1))
        .filter_map(|m| {
            let a = frame.features.keypoints.get(m.query as usize)?;
            let b = reference.features.keypoints.get(m.train as usize)?;
            Some([a.x, a.y, b.x, b.y])
        })
        .take(max)
        .collect()
}

impl Emitter {
    pub(crate) fn new(sink: EventSink, local_ba_images: usize) -> Self {
        Self { sink, local_ba_images, ..Self::default() }
    }

    /// True when a consumer listens (diagnostics only it needs are computed then).
    pub(crate) fn is_active(&self) -> bool {
        self.sink.is_active()
    }

    pub(crate) fn set_debug_ground_truth(&mut self, gt: colslam_eval::trajectory::Trajectory) {
        self.debug_gt = Some(gt);
    }

    pub(crate) fn send(&mut self, event: SlamEvent) {
        self.sink.send(event);
    }

    /// A new map is tracked: nothing of it was sent yet.
    pub(crate) fn new_map(&mut self) {
        self.sent_points.clear();
    }

    /// The flow of `frame`'s `matches` (query = frame) to `reference`, split
    /// by `inliers` (one flag per match); `None` without a consumer.
    pub(crate) fn flow(
        &self,
        frame: &crate::frame::FrameData,
        reference: &crate::frame::FrameData,
        matches: &[colslam_features::Match],
        inliers: &[bool],
    ) -> Option<FrameFlow> {
        if !self.is_active() {
            return None;
        }
        let flagged = || matches.iter().zip(inliers.iter().chain(std::iter::repeat(&false)));
        let num_inliers = inliers.iter().filter(|&&i| i).count();
        let outliers = matches.len() - num_inliers.min(matches.len());
        let inlier_lines = flow_lines(flagged().filter(|p| *p.1).map(|p| p.0), frame, reference, 1, MAX_INLIER_LINES);
        let step = outliers.div_ceil(MAX_OUTLIER_LINES);
        let outlier_lines =
            flow_lines(flagged().filter(|p| !*p.1).map(|p| p.0), frame, reference, step, MAX_OUTLIER_LINES);
        Some(FrameFlow { num_matches: matches.len(), num_inliers, inlier_lines, outlier_lines })
    }

    /// A frame went through the keyframe test; `flow` from [`Emitter::flow`].
    pub(crate) fn frame(
        &mut self,
        data: &crate::frame::FrameData,
        flow: Option<FrameFlow>,
        flow_score: f64,
        is_keyframe: bool,
    ) {
        // `flow` is `None` without a consumer (see `flow`).
        let Some(flow) = flow else { return };
        self.sink.send(SlamEvent::FrameProcessed {
            index: data.index(),
            timestamp: data.id.timestamp,
            flow_score,
            num_matches: flow.num_matches,
            num_inliers: flow.num_inliers,
            flow_lines: flow.inlier_lines,
            outlier_lines: flow.outlier_lines,
            is_keyframe,
        });
    }

    /// A keyframe of `map` was registered.
    pub(crate) fn keyframe(&mut self, map: &crate::mapper::Mapper, image_id: colslam_scene::ImageId) {
        if !self.sink.is_active() {
            return;
        }
        let Some(img) = map.reconstruction().image(image_id) else { return };
        let frame_index = map.keyframes().iter().find(|k| k.image_id == image_id).map_or(0, |k| k.data.index());
        self.sink.send(SlamEvent::KeyframeAdded {
            map: map.index(),
            image_id: image_id.0,
            frame_index,
            cam_from_world: img.cam_from_world,
            num_points: img.num_points3d(),
        });
    }

    /// Sends the map's changes since the last update (or everything).
    pub(crate) fn map(&mut self, map: &crate::mapper::Mapper, full: bool) {
        if !self.sink.is_active() {
            return;
        }
        let rec = map.reconstruction();
        let current: std::collections::HashSet<colslam_scene::Point3DId> = rec.point3d_ids().into_iter().collect();
        let removed: Vec<u64> =
            if full { Vec::new() } else { self.sent_points.difference(&current).map(|p| p.0).collect() };
        // Points of the newest keyframes moved in local BA; new points are
        // those not sent yet.
        let recent: std::collections::HashSet<colslam_scene::ImageId> =
            map.keyframes().iter().rev().take(self.local_ba_images).map(|k| k.image_id).collect();
        let points: Vec<EventPoint> = rec
            .points3d()
            .filter(|(id, p)| {
                full || !self.sent_points.contains(id) || p.track.iter().any(|e| recent.contains(&e.image_id))
            })
            .map(|(id, p)| EventPoint { id: id.0, xyz: p.xyz, color: p.color })
            .collect();
        self.sent_points = current;
        let poses = map
            .keyframes()
            .iter()
            .filter(|k| full || recent.contains(&k.image_id))
            .filter_map(|k| rec.image(k.image_id).map(|img| (k.image_id.0, k.data.index(), img.cam_from_world)))
            .collect();
        self.sink.send(SlamEvent::MapUpdated {
            map: map.index(),
            full,
            points,
            removed_points: removed,
            poses,
            keyframes: rec.num_registered_images(),
            num_points: rec.num_points3d(),
            observations: rec.num_observations(),
            mean_reproj_error: rec.mean_reprojection_error(),
        });
    }

    /// Logs the keyframes' ATE against the debug ground truth.
    pub(crate) fn log_keyframe_ate(&self, map: &crate::mapper::Mapper) {
        let Some(gt) = &self.debug_gt else { return };
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let rec = map.reconstruction();
        let mut kfs: Vec<(f64, Rigid3)> = map
            .keyframes()
            .iter()
            .filter_map(|k| {
                rec.image(k.image_id).filter(|i| i.registered).map(|i| (k.data.id.timestamp, i.cam_from_world))
            })
            .collect();
        kfs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let est = colslam_eval::trajectory::Trajectory::from_cam_from_world(
            kfs.iter().map(|k| k.0).collect(),
            &kfs.iter().map(|k| k.1).collect::<Vec<_>>(),
        );
        match colslam_eval::evaluate(gt, &est, &colslam_eval::EvalOptions::default()) {
            Ok(r) => tracing::debug!(
                "map {}: {} keyframes, ATE {:.4} m (max {:.4} m), scale {:.4}",
                map.index(),
                r.matched,
                r.ate_rmse,
                r.ate_max,
                r.scale
            ),
            Err(e) => tracing::debug!("map {}: keyframe ATE not available: {e}", map.index()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::tests::frame_data;
    use colslam_features::Match;

    #[test]
    fn a_frame_event_draws_every_verified_match_and_a_subsample_of_the_rest() {
        let n = 1000;
        let frame = frame_data(1, vec![colslam_geometry::Vec2::zeros(); n]);
        let reference = frame_data(0, vec![colslam_geometry::Vec2::zeros(); n]);
        let matches: Vec<Match> = (0..n as u32).map(|i| Match { query: i, train: i, distance: 0.0 }).collect();
        let inliers: Vec<bool> = (0..n).map(|i| i % 3 != 0).collect();
        let silent = Emitter::new(EventSink::none(), 7);
        assert!(silent.flow(&frame, &reference, &matches, &inliers).is_none(), "nothing computed without a consumer");
        let (sink, events) = EventSink::channel();
        let mut e = Emitter::new(sink, 7);
        let flow = e.flow(&frame, &reference, &matches, &inliers);
        e.frame(&frame, flow, 0.1, false);
        match events.try_recv() {
            Ok(SlamEvent::FrameProcessed { num_matches, num_inliers, flow_lines, outlier_lines, .. }) => {
                assert_eq!((num_matches, num_inliers, flow_lines.len()), (1000, 666, 666), "one line per inlier");
                assert!((1..=MAX_OUTLIER_LINES).contains(&outlier_lines.len()), "{}", outlier_lines.len());
            }
            other => panic!("a frame event: {other:?}"),
        }
    }
}
