//! The path engine: segment queue, lookahead, knowledge-based blending and jerk-limited time scaling
//! along the path. Deterministic and allocation-free after construction.

mod bed_mesh;
mod config;
mod engine;
mod geometry;
mod profile;
mod segment;

pub use bed_mesh::{BedMesh, BedMeshConfig, MESH_COUNT, MeshAlgorithm};
pub use config::{InvalidPathConfig, PathConfig, PlanningMode};
pub(crate) use engine::rest_sample;
pub use engine::{AxisLimits, Motion, PathEngine, PathSample, PathStats, SegmentError};
pub use geometry::{Geometry, PathPoint, arc_geometry};
pub use geometry::{distance_to_arc, distance_to_segment};
pub use segment::{
    HeatRequest, HeatWait, Heater, InvalidSegment, MAX_ARC_SWEEP, MAX_TEMPERATURE, OPEN_BAND, Segment, SegmentFlags, SegmentKind,
};
