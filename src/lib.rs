//! strand: a real-time streaming motion controller for robot-arm additive manufacturing.
//!
//! The deterministic core (`core`) sits inside an I/O shell; see DESIGN.md. Units are SI inside
//! (m, rad, s); quaternions are (w, x, y, z).

// Index loops read like the matrix formulas they implement; iterator chains would hide the indices.
#![allow(clippy::needless_range_loop)]

pub mod check;
pub mod config;
pub mod core;
pub mod gcode;
pub mod io;
pub mod job;
pub mod log;
pub mod plan;
pub mod segfile;
