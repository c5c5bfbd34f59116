//! strand: a real-time streaming motion controller for robot-arm additive manufacturing.
//!
//! The deterministic core (`core`) sits inside an I/O shell; see DESIGN.md. Units are SI inside
//! (m, rad, s); quaternions are (w, x, y, z).

// Index loops read like the matrix formulas they implement; iterator chains would hide the indices.

/// The deterministic core, its own crate (`src/core`, `strand-core`): see its façade.
pub use strand_core as core;

pub mod check;
pub mod config;
pub mod ctl;
pub mod io;
pub mod log;
