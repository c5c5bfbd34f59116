//! The path engine: segment queue, lookahead, knowledge-based blending and jerk-limited time scaling
//! along the path. Deterministic and allocation-free after construction.

pub mod bed;
pub mod config;
pub mod engine;
pub mod geometry;
pub mod profile;
pub mod segment;

pub use bed::BedTransform;
pub use config::{InvalidPathConfig, PathConfig, PlanningMode};
pub use engine::{Motion, PathEngine, PathSample, PathStats, SegmentError};
pub use segment::{MAX_ARC_SWEEP, Segment, SegmentFlags, SegmentKind};
