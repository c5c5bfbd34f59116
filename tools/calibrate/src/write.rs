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
        self.table(&[name])
    }

    /// The table at `path` (`["bed", "mesh"]` is `[bed.mesh]`), made if missing.
    fn table(&mut self, path: &[&str]) -> Result<&mut Table, CalibrationError> {
        let file = self.file.display().to_string();
        let mut table = self.doc.as_table_mut();
        for (k, name) in path.iter().enumerate() {
            let item = table.entry(name).or_insert_with(|| Item::Table(Table::new()));
            table = item.as_table_mut().ok_or_else(|| CalibrationError::Config {
                file: file.clone(),
                message: format!("[{}] is not a section", path[..=k].join(".")),
            })?;
        }
        Ok(table)
    }

    /// Sets `[section] key = value`, keeping the comment after an existing value.
    fn set(&mut self, section: &str, key: &str, value: Value) -> Result<(), CalibrationError> {
        self.set_at(&[section], key, value)
    }

    /// Sets `key = value` in the table at `path`, keeping the comment after an existing value.
    fn set_at(&mut self, path: &[&str], key: &str, mut value: Value) -> Result<(), CalibrationError> {
        let table = self.table(path)?;
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

    /// Sets `[bed.mesh]`'s grid: `min` and `max` (m), `points` (m, one row per y, written one row a
    /// line), and `algorithm` when given; its other keys (the fade) are kept.
    pub fn set_bed_mesh(
        &mut self,
        min: &[f64; 2],
        max: &[f64; 2],
        points: &[Vec<f64>],
        algorithm: Option<&str>,
    ) -> Result<(), CalibrationError> {
        let path = ["bed", "mesh"];
        let new = self.doc.get("bed").and_then(|b| b.get("mesh")).is_none();
        self.set_at(&path, "min", array(min, DECIMALS))?;
        if new {
            // At the end of the file: right after `[bed]` it would come between that section's
            // commented-out keys and the operator, who might uncomment one into the mesh.
            let last = self.doc.as_table().iter().filter_map(|(_, i)| i.as_table()).filter_map(Table::position).max().unwrap_or(0);
            self.table(&path)?.set_position(Some(last + 1));
        }
        self.set_at(&path, "max", array(max, DECIMALS))?;
        let mut rows = Array::new();
        for row in points {
            let mut r = array(row, DECIMALS);
            r.decor_mut().set_prefix("\n    ");
            rows.push_formatted(r);
        }
        rows.set_trailing("\n");
        rows.set_trailing_comma(true);
        self.set_at(&path, "points", Value::Array(rows))?;
        if let Some(a) = algorithm {
            self.set_at(&path, "algorithm", Value::from(a))?;
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
    fn a_bed_mesh_goes_into_its_table_one_row_a_line_keeping_the_fade() {
        let text =
            "[bed]\nframe = { xyz = [0.5, 0.0, 0.2], rpy = [0.0, 0.0, 0.0] }\n\n[bed.mesh]\nfade_end = 0.008  # m\nmin = [0.0, 0.0]\n";
        let mut e = edit(text);
        e.set_bed_mesh(&[0.01, 0.02], &[0.19, 0.18], &[vec![0.0001, -0.0000004], vec![0.00025, 0.0]], Some("bicubic")).unwrap();
        let out = e.text();
        assert!(out.contains("fade_end = 0.008  # m\nmin = [0.01, 0.02]\n"), "{out}");
        assert!(out.contains("points = [\n    [0.0001, 0.0],\n    [0.00025, 0.0],\n]\n"), "{out}");
        let parsed: toml_edit::DocumentMut = out.parse().unwrap();
        assert_eq!(parsed["bed"]["mesh"]["algorithm"].as_str(), Some("bicubic"));
        let mut e = edit("robot = \"r.toml\"\n");
        e.set_bed_mesh(&[0.0, 0.0], &[0.1, 0.1], &[vec![0.0; 2], vec![0.0; 2]], None).unwrap();
        assert!(e.text().contains("[bed.mesh]\nmin = [0.0, 0.0]"), "{}", e.text());
    }

    #[test]
    fn a_missing_section_is_added() {
        let mut e = edit("robot = \"r.toml\"\n");
        e.set_number("extruder", "drive_wheel_radius", 5.61234567e-3, 9).unwrap();
        assert!(e.text().contains("[extruder]\ndrive_wheel_radius = 0.005612346"), "{}", e.text());
    }
}
