//! Slicer annotations: the `;` comments that name the feature, layer and height being printed, in
//! each major slicer's spelling. They change nothing in the path; they label it, so that offline
//! tools can pick features (skip the skirt) and layers (strip splitting, inclined planes).
//!
//! | slicer | feature | layer | top of layer | layer height |
//! |---|---|---|---|---|
//! | PrusaSlicer, SuperSlicer, Orca (non-Bambu printers) | `;TYPE:` | `;LAYER_CHANGE` | `;Z:` | `;HEIGHT:` |
//! | Orca (Bambu printers), Bambu Studio | `; FEATURE:` | `; CHANGE_LAYER` | `; Z_HEIGHT:` | `; LAYER_HEIGHT:` |
//! | Cura, ideaMaker | `;TYPE:` | `;LAYER:n` (0-based, negative for raft) | | |
//! | Simplify3D | `; feature ...` | `; layer n, Z = z` (1-based) | (same line) | `; tool H.. W..` |

use std::sync::Arc;

use super::super::lexer::is_blank;
use super::Interpreter;

impl Interpreter {
    /// Slicer tags in a `;` comment (the characters after the `;`).
    pub(in crate::gcode) fn read_tag_comment(&mut self, comment: &[char]) {
        let start = comment.iter().take_while(|c| is_blank(**c)).count();
        if !comment.get(start).is_some_and(|c| c.is_ascii_alphabetic()) {
            return;
        }
        let text: String = comment[start..].iter().collect();
        let text = text.trim_end();
        let unit = self.modal.unit;
        let length = |value: &str| value.trim().parse::<f64>().ok().map(|v| v * unit).filter(|v| v.is_finite());
        if let Some(feature) =
            text.strip_prefix("TYPE:").or_else(|| text.strip_prefix("FEATURE:")).or_else(|| text.strip_prefix("feature "))
        {
            self.set_feature(feature.trim());
        } else if text == "LAYER_CHANGE" || text == "CHANGE_LAYER" {
            let next = match self.tags.layer {
                Some(layer) if !self.moved_since_marker => layer,
                Some(layer) => layer.saturating_add(1),
                None => 0,
            };
            self.start_layer(next);
        } else if let Some(layer) = text.strip_prefix("LAYER:") {
            if let Ok(layer) = layer.trim().parse::<i32>() {
                self.start_layer(layer);
            }
        } else if let Some(rest) = text.strip_prefix("layer ") {
            self.simplify3d_layer(rest, unit);
        } else if let Some(z) = text.strip_prefix("Z:").or_else(|| text.strip_prefix("Z_HEIGHT:")) {
            if let Some(z) = length(z) {
                self.tags.z_marker = Some(z);
            }
        } else if let Some(height) = text.strip_prefix("HEIGHT:").or_else(|| text.strip_prefix("LAYER_HEIGHT:")) {
            if let Some(height) = length(height) {
                self.tags.height = Some(height);
            }
        } else if let Some(tool) = text.strip_prefix("tool ") {
            // Simplify3D: `; tool H0.200 W0.480`, the extrusion height and width.
            if let Some(height) = tool.split_whitespace().find_map(|w| w.strip_prefix('H')).and_then(length) {
                self.tags.height = Some(height);
            }
        }
    }

    fn set_feature(&mut self, feature: &str) {
        if self.tags.feature.as_deref() != Some(feature) {
            self.tags.feature = Some(Arc::from(feature));
        }
    }

    /// A layer marker: the next line or arc starts layer `layer`.
    fn start_layer(&mut self, layer: i32) {
        self.tags.layer = Some(layer);
        self.layer_marker_pending = true;
        self.moved_since_marker = false;
    }

    /// Simplify3D's `; layer 3, Z = 0.600` (layers counted from 1).
    fn simplify3d_layer(&mut self, rest: &str, unit: f64) {
        let (number, z) = rest.split_once(',').unwrap_or((rest, ""));
        let Ok(number) = number.trim().parse::<i32>() else { return };
        self.start_layer(number.saturating_sub(1));
        let z = z.trim().strip_prefix('Z').map(|z| z.trim_start().trim_start_matches('=').trim());
        if let Some(z) = z.and_then(|z| z.parse::<f64>().ok()).map(|z| z * unit).filter(|z| z.is_finite()) {
            self.tags.z_marker = Some(z);
        }
    }
}
