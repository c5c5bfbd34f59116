//! The error of a configuration value outside its range: every section's `validate` returns one,
//! naming the section and, in its message, the key, the value and the allowed range.

/// A configuration value outside its range.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct InvalidSetting {
    /// The config section (`controller`, `base`, `clik`, ...).
    pub section: &'static str,
    /// The key, its value and the rule it breaks (e.g. `[base] alpha = 2: must lie in (0, 1]`).
    pub message: String,
}

impl InvalidSetting {
    /// `message` names the key, its value and the rule.
    pub fn new(section: &'static str, message: String) -> Self {
        InvalidSetting { section, message }
    }
}
