//! Warnings and notes, kept once per kind with a count so that their memory is bounded.

use super::{MAX_REPORT_KINDS, OTHER_KIND, Warning};

#[derive(Default)]
pub(super) struct Reports {
    pub(super) entries: Vec<Warning>,
}

impl Reports {
    /// Counts one occurrence of `kind`; the first one keeps its line, column and message.
    pub(super) fn record(&mut self, kind: &str, line: usize, column: usize, message: impl FnOnce() -> String) {
        if self.count(kind) {
            return;
        }
        if self.entries.len() < MAX_REPORT_KINDS {
            self.entries.push(Warning { line, column, kind: kind.to_string(), message: message(), count: 1 });
        } else if !self.count(OTHER_KIND) {
            let message = format!("more kinds than are listed apart; the first: {kind}: {}", message());
            self.entries.push(Warning { line, column, kind: OTHER_KIND.to_string(), message, count: 1 });
        }
    }

    /// Counts one more of `kind` if it is listed.
    pub(super) fn count(&mut self, kind: &str) -> bool {
        let entry = self.entries.iter_mut().find(|e| e.kind == kind);
        entry.map(|e| e.count = e.count.saturating_add(1)).is_some()
    }
}
