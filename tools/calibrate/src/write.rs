//! A config file edited in place: values set or replaced by key, everything else — comments, blank
//! lines, key order, the formatting of untouched values — kept as the operator wrote it (toml_edit's
//! format-preserving document). A replaced value keeps the comment that trailed it.

use std::path::{Path, PathBuf};

use toml_edit::{Array, DocumentMut, InlineTable, Item, Table, Value};

use crate::error::CalibrationError;

/// Decimal places kept for lengths in m (1 µm) and angles in rad (1 µrad) written by a calibration.
pub const DECIMALS: i32 = 6;

/// A config file being edited.
#[derive(Clone, Debug)]
pub struct ConfigEdit {
    file: PathBuf,
    doc: DocumentMut,
}

/// `v` rounded to `decimals` places (so the file says 0.102345, not 0.10234512345678).
pub fn rounded(v: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    let r = (v * scale).round() / scale;
    if r == 0.0 { 0.0 } else { r }
}

fn array(values: &[f64], decimals: i32) -> Value {
    let mut a: Array = values.iter().map(|v| rounded(*v, decimals)).collect();
    a.fmt();
    Value::Array(a)
}

impl ConfigEdit {
    /// Reads and parses `path`.
    pub fn open(path: &Path) -> Result<Self, CalibrationError> {
        let file = path.to_path_buf();
        let err = |message: String| CalibrationError::Config { file: path.display().to_string(), message };
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let doc: DocumentMut = text.parse().map_err(|e: toml_edit::TomlError| err(e.to_string().trim_end().to_string()))?;
        Ok(ConfigEdit { file, doc })
    }

    /// The file being edited.
    pub fn file(&self) -> &Path {
        &self.file
    }

    /// A top-level string value (`robot = "robots/iiwa7.toml"`), if there is one.
    pub fn top_string(&self, key: &str) -> Option<String> {
        self.doc.get(key).and_then(Item::as_str).map(str::to_string)
    }

    /// True if the file has the section `[name]`.
    pub fn has_section(&self, name: &str) -> bool {
        self.doc.get(name).is_some_and(Item::is_table_like)
    }

    fn section(&mut self, name: &str) -> Result<&mut Table, CalibrationError> {
        let file = self.file.display().to_string();
        let item = self.doc.entry(name).or_insert_with(|| Item::Table(Table::new()));
        item.as_table_mut().ok_or_else(|| CalibrationError::Config { file, message: format!("{name} is not a [section]") })
    }

    /// Sets `[section] key = value`, keeping the comment after an existing value.
    fn set(&mut self, section: &str, key: &str, mut value: Value) -> Result<(), CalibrationError> {
        let table = self.section(section)?;
        if let Some(old) = table.get(key).and_then(Item::as_value) {
            *value.decor_mut() = old.decor().clone();
        } else {
            value.decor_mut().set_prefix(" ");
        }
        table.insert(key, Item::Value(value));
        Ok(())
    }

    /// Sets `[section] key = [v, …]` (rounded to `decimals` places).
    pub fn set_array(&mut self, section: &str, key: &str, values: &[f64], decimals: i32) -> Result<(), CalibrationError> {
        self.set(section, key, array(values, decimals))
    }

    /// Sets `[section] key = v` (rounded to `decimals` places).
    pub fn set_number(&mut self, section: &str, key: &str, v: f64, decimals: i32) -> Result<(), CalibrationError> {
        self.set(section, key, Value::from(rounded(v, decimals)))
    }

    /// Sets `[section] key = { xyz = [...], rpy = [...] }` and removes the keys it `replaces`, whose
    /// old lines are kept as a comment above it (so the file still says what it was).
    pub fn set_pose(
        &mut self,
        section: &str,
        key: &str,
        xyz: &[f64; 3],
        rpy: &[f64; 3],
        replaces: &[&str],
    ) -> Result<(), CalibrationError> {
        let mut pose = InlineTable::new();
        pose.insert("xyz", array(xyz, DECIMALS));
        pose.insert("rpy", array(rpy, DECIMALS));
        pose.fmt();
        let table = self.section(section)?;
        let mut was = Vec::new();
        for r in replaces {
            if let Some(item) = table.remove(r) {
                // The value alone, without the comment that trailed it.
                let text = match item.as_value() {
                    Some(v) => {
                        let mut v = v.clone();
                        v.decor_mut().clear();
                        v.to_string()
                    }
                    None => item.to_string(),
                };
                was.push(format!("{r} = {}", text.trim()));
            }
        }
        self.set(section, key, Value::InlineTable(pose))?;
        if !was.is_empty() {
            let table = self.section(section)?;
            if let Some(mut k) = table.key_mut(key) {
                let prefix = format!("# replaced by `strand calibrate`: {}\n", was.join(", "));
                k.leaf_decor_mut().set_prefix(prefix);
            }
        }
        Ok(())
    }

    /// The edited text.
    pub fn text(&self) -> String {
        self.doc.to_string()
    }

    /// Writes the edited text back to the file.
    pub fn save(&self) -> Result<(), CalibrationError> {
        std::fs::write(&self.file, self.text())
            .map_err(|e| CalibrationError::Config { file: self.file.display().to_string(), message: format!("cannot write: {e}") })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edit(text: &str) -> ConfigEdit {
        ConfigEdit { file: PathBuf::from("t.toml"), doc: text.parse().unwrap() }
    }

    #[test]
    fn a_replaced_value_keeps_its_comment_and_the_rest_is_untouched() {
        let text = "# head\nurdf = \"a.urdf\"\n\n# the tool\n[tool]\nxyz = [0.10, 0.0, 0.0]  # m, flange\nrpy = [0.0, 1.5707963267948966, 0.0]\n\n[limits]\n# kept\nacceleration = [1.0]\n";
        let mut e = edit(text);
        e.set_array("tool", "xyz", &[0.1023456789, -0.0000001, 0.0], DECIMALS).unwrap();
        let out = e.text();
        assert_eq!(out, text.replace("xyz = [0.10, 0.0, 0.0]  # m, flange", "xyz = [0.102346, 0.0, 0.0]  # m, flange"));
    }

    #[test]
    fn a_pose_replaces_the_old_keys_and_says_so() {
        let text = "[bed]\ntilt = 0.0                 # rad\noffset = [0.45, 0.0, 0.2]  # m\n\n[check]\nx = 1\n";
        let mut e = edit(text);
        e.set_pose("bed", "frame", &[0.5, 0.01, 0.2], &[0.001, -0.002, 0.3], &["tilt", "offset"]).unwrap();
        let out = e.text();
        assert!(out.contains("# replaced by `strand calibrate`: tilt = 0.0, offset = [0.45, 0.0, 0.2]\n"), "{out}");
        assert!(out.contains("frame = { xyz = [0.5, 0.01, 0.2], rpy = [0.001, -0.002, 0.3] }"), "{out}");
        assert!(!out.contains("\ntilt"), "{out}");
        assert!(out.contains("[check]\nx = 1\n"), "{out}");
    }

    #[test]
    fn a_missing_section_is_added() {
        let mut e = edit("robot = \"r.toml\"\n");
        e.set_number("extruder", "drive_wheel_radius", 5.61234567e-3, 9).unwrap();
        assert!(e.text().contains("[extruder]\ndrive_wheel_radius = 0.005612346"), "{}", e.text());
    }
}
