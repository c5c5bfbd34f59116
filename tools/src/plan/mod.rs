//! The offline planners of `strand-plan` (DESIGN.md, "Offline planning"), one module per method:
//! they turn a job or a surface into a job for strand-feed — G-code, or a segment file where the
//! tool orientation matters — and never run on the tick path.

pub mod base;
pub mod filter;
pub mod finish;
pub mod strips;
pub mod surface;
pub mod tilt;
