//! Slicer annotations: the `;` comments that name the feature, layer and height being printed.

use std::sync::Arc;

use super::interpreter::Interpreter;

impl Interpreter {
    /// Slicer tags in a `;` comment (the characters after the `;`).
    pub(super) fn read_tag_comment(&mut self, comment: &[char]) {
        if !comment.first().is_some_and(|c| c.is_ascii_uppercase()) {
            return;
        }
        let text: String = comment.iter().collect();
        let text = text.trim();
        if let Some(feature) = text.strip_prefix("TYPE:") {
            let feature = feature.trim();
            if self.tags.feature.as_deref() != Some(feature) {
                self.tags.feature = Some(Arc::from(feature));
            }
        } else if text == "LAYER_CHANGE" {
            self.tags.layer = Some(self.tags.layer.map_or(0, |l| l.saturating_add(1)));
            self.layer_marker_pending = true;
        } else if let Some(layer) = text.strip_prefix("LAYER:") {
            if let Ok(layer) = layer.trim().parse::<i32>() {
                self.tags.layer = Some(layer);
                self.layer_marker_pending = true;
            }
        } else if let Some(Ok(z)) = text.strip_prefix("Z:").map(|z| z.trim().parse::<f64>()) {
            self.tags.z_marker = Some(z * self.modal.unit).filter(|z| z.is_finite());
        }
    }
}
