//! STEP faces as printable surfaces: strand-plan's door to a user's CAD. [`read_step`] reads a model
//! (ISO 10303-21, an AP203/AP214 B-rep, through truck-stepio), turns every face of every shell into a
//! [`StepFace`] — its surface S(u, v) with the face's outward normal, its trimming loops mapped into
//! (u, v), its area and bounding box in metres — and [`StepFace::contains`] answers 003's `isInside`:
//! whether a parameter pair lies on the trimmed face, holes excluded.
//!
//! Why a crate of its own: truck and its STEP reader are about a hundred crates that nothing else in
//! strand needs, and the reader's failure modes (entities it silently drops, panics on bad knot
//! vectors) are fenced in here, so the planner sees either faces it can trust or an error that names
//! the entity.
//!
//! Units: the file's length unit is read from its `GLOBAL_UNIT_ASSIGNED_CONTEXT` (millimetres when it
//! names none, the CAD default) and everything public is in metres; (u, v) stay in the surface's own
//! parameters (lengths in file units for planes, radians for angles, knot values for splines).

use std::path::Path;

mod face;
pub mod models;
mod read;

pub use face::{FaceSummary, StepFace, SurfaceType};
pub use read::{Model, parse_step};

/// Why a STEP model or one of its faces cannot be used. Every message names the file; those about one
/// entity give its `#id` and STEP type.
#[derive(Debug, thiserror::Error)]
pub enum CadError {
    /// The file cannot be read.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// Not STEP text, or cut off.
    #[error("{file}: not a readable STEP file: {reason}")]
    Parse {
        /// The file.
        file: String,
        /// The parser's first complaint.
        reason: String,
    },
    /// One entity cannot be used.
    #[error("{file}: entity #{id} ({entity}): {reason}")]
    Entity {
        /// The file.
        file: String,
        /// The entity's instance number in the file.
        id: u64,
        /// Its STEP type, e.g. `ADVANCED_FACE` or `B_SPLINE_SURFACE_WITH_KNOTS`.
        entity: String,
        /// What is wrong.
        reason: String,
    },
    /// The model as a whole (no faces, no such face).
    #[error("{file}: {reason}")]
    Model {
        /// The file.
        file: String,
        /// What is wrong.
        reason: String,
    },
}

/// Reads a STEP file: every face of every shell, in the file's order.
pub fn read_step(path: &Path) -> Result<Model, CadError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| CadError::Io { file: file.clone(), source })?;
    // STEP is ISO 8859-1 text with escapes; anything outside ASCII can only be in strings.
    let text = String::from_utf8_lossy(&bytes);
    parse_step(&text, &file)
}
