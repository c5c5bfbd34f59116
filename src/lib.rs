//! strand: a real-time streaming motion controller for robot-arm additive manufacturing.
//!
//! The deterministic core is its own crate, `strand-core` (`src/core`), inside this I/O shell; see
//! DESIGN.md. Every crate names the core's items by one path, `strand_core::…` (this crate does not
//! re-export it). Units are SI inside (m, rad, s); quaternions are (w, x, y, z).

pub mod calibrate;
pub mod check;
pub mod config;
pub mod ctl;
pub mod io;
pub mod log;
