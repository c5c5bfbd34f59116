//! Offline planners behind `strand-plan` that turn a part description into a segment stream (DESIGN.md,
//! "Offline planning"): they run on a workstation, never in the real-time loop.

pub mod surface;
