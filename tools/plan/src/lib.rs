//! The offline planners of `strand-plan` (DESIGN.md, "Offline planning"), one module per method:
//! they turn a job or a surface into a job for strand-feed — G-code, or a segment file where the
//! tool orientation matters — and never run on the tick path. [`time`] times a program through the
//! controller's own path engine. `strand-plan`'s main only parses the command line.

use strand_cli::error::{Result, ToolError};

pub mod base;
pub mod filter;
pub mod finish;
pub mod strips;
pub mod surface;
pub mod tilt;
pub mod time;
pub mod truss;

/// Filament per metre of deposited bead (m/m): Slic3r's bead cross-section, a rectangle with round
/// ends, A = h·(w − h) + π(h/2)², over the filament's section π(d/2)². `line_width` w, `layer_height`
/// h and `filament_diameter` d in m.
pub(crate) fn filament_per_metre(line_width: f64, layer_height: f64, filament_diameter: f64) -> f64 {
    let (w, h, d) = (line_width, layer_height, filament_diameter);
    let pi = std::f64::consts::PI;
    (h * (w - h) + pi * (h / 2.0).powi(2)) / (pi * (d / 2.0).powi(2))
}

/// `v` if it is finite and positive, else an error naming the flag: `--{flag} = {v}: must be positive`.
pub fn positive(flag: &str, v: f64) -> Result<f64> {
    if v.is_finite() && v > 0.0 { Ok(v) } else { Err(ToolError::Usage(format!("--{flag} = {v}: must be positive"))) }
}
