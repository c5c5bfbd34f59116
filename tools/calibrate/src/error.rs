//! The one error type of the calibration library: what in the input is wrong or why the input
//! cannot determine the answer, in words an operator can act on.

use thiserror::Error;

/// Why a calibration could not give an answer.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum CalibrationError {
    /// A file could not be read, or a line of it is not what it should be.
    #[error("{file}:{line}:{column}: {message}")]
    Input {
        /// The file (as given).
        file: String,
        /// 1-based line (0: the file as a whole).
        line: usize,
        /// 1-based column of the field at fault (0: the line as a whole).
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// Fewer measurements than the solve needs.
    #[error("{what}: {got} given, at least {needed} needed")]
    TooFew {
        /// What was counted ("snapshots", "points", "pairs").
        what: &'static str,
        /// How many the solve needs (count).
        needed: usize,
        /// How many were given (count).
        got: usize,
    },
    /// The measurements cannot determine the answer (the geometry is degenerate).
    #[error("cannot solve: {reason}")]
    Degenerate {
        /// Why, and what to touch differently.
        reason: String,
    },
    /// A value given is out of its range (a length ≤ 0, a ratio far from 1).
    #[error("{what}: {reason}")]
    BadValue {
        /// The value's name.
        what: &'static str,
        /// Why it is refused.
        reason: String,
    },
    /// The config file could not be read, parsed or written.
    #[error("{file}: {message}")]
    Config {
        /// The file.
        file: String,
        /// What failed.
        message: String,
    },
}

impl CalibrationError {
    pub(crate) fn degenerate(reason: impl Into<String>) -> Self {
        CalibrationError::Degenerate { reason: reason.into() }
    }
}
