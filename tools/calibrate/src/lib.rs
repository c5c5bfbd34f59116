//! strand-calibrate: a cell's first day, from touched points to config values, each answer with its
//! residual (`strand calibrate tool | frame | mesh | base | extruder`).
//!
//! - [`tool`]: the tool centre point from ≥ 4 orientations touching one fixed point (the 4-point
//!   TCP method), and the nozzle axis from touches along it;
//! - [`frame`]: the bed (or a work piece) frame from 3 or more touched points;
//! - [`mesh`]: the bed's surface from probed heights, fitted to a grid (`[bed.mesh]`);
//! - [`handeye`]: the hand–eye problem AX = XB (Park–Martin) for a tracked marker body;
//! - [`extruder`]: the drive wheel radius rescaled from a commanded and a measured length;
//! - [`snapshots`] and [`pairs`]: the CSV files the solvers read (joint snapshots; joints and
//!   tracker poses), with errors naming file, line and column;
//! - [`write`]: the config file edited in place, its comments kept.
//!
//! Every solver refuses an input that cannot determine its answer (touches from one orientation,
//! collinear bed points, rotations about one axis) with the reason, rather than return a number
//! the input does not support. Units: m, rad (mm and degrees only in residuals, where they say so).

pub mod error;
pub mod extruder;
pub mod frame;
pub mod handeye;
mod linalg;
pub mod mesh;
pub mod pairs;
mod rows;
pub mod snapshots;
pub mod tool;
pub mod write;

pub use error::CalibrationError;
