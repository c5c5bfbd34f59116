//! The deterministic controller core: no I/O, no clock, no threads, no allocation after start-up.
//! Everything that may influence a tick arrives as an argument, so the same inputs give the same
//! outputs to the bit, and a logged run replays exactly.

pub mod base;
pub mod controller;
pub mod extrude;
pub mod following;
pub mod kin;
pub mod path;
