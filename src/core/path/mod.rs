//! The path engine: segment queue, lookahead, knowledge-based blending and jerk-limited time scaling
//! along the path. Deterministic and allocation-free after construction.

pub mod segment;

pub use segment::{Segment, SegmentFlags, SegmentKind};
