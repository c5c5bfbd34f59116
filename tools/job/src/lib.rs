//! strand's offline job code, used by the tools and by `strand check-job`, never by a tick:
//!
//! - [`gcode`]: the streaming G-code reader (lexer → blocks → modal interpreter, with the firmware
//!   and RS274NGC dialects), G-code to core segments in bed coordinates;
//! - [`segfile`]: the JSON-Lines segment file (`strand-segments`), read and written bit for bit;
//! - [`bed`]: the bed transform for printing on inclined planes (004 Section III-D);
//! - [`load`]: a job (G-code or segment file) read and put on the bed, its wire form, and a planned
//!   base trajectory;
//! - [`timing`]: a job timed by the controller's own path engine, tick by tick (`strand-plan time`).

// Index loops read like the matrix formulas they implement; iterator chains would hide the indices.

pub mod bed;
pub mod gcode;
pub mod load;
pub mod segfile;
pub mod timing;

pub use bed::{BedConfig, BedTransform};
pub use load::{BaseTrajectory, JobError, LayeredSegments, load_segments, load_segments_with, to_wire, wire_job};
