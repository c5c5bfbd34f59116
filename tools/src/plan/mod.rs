//! Offline planners behind `strand-plan` that turn a job or a part into a new job (G-code out), one
//! module per method.

pub mod strips;
