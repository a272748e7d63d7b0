//! COLMAP's incremental structure-from-motion parts, in Rust: the
//! correspondence graph of 2D-2D matches between images, the incremental
//! triangulator (create, continue, merge and complete tracks, retriangulate)
//! and the observation manager (filters, register/deregister), as the
//! sequential SLAM pipeline drives them (paper sections 3.3-3.6).

pub mod bundle;
pub mod correspondence_graph;
pub mod error;
pub mod triangulator;

pub use correspondence_graph::{Correspondence, CorrespondenceGraph};
pub use error::SfmError;
pub use triangulator::{TriangulationReport, TriangulatorOptions};
