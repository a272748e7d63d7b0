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
        /// Flow lines `[x_frame, y_frame, x_keyframe, y_keyframe]` in pixels
        /// (OpenCV convention), for drawing.
        flow_lines: Vec<[f32; 4]>,
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
