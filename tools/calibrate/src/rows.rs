//! Numeric CSV rows, the one text format of the calibration files: fields separated by commas,
//! blank lines and `#` comments (whole lines or after the numbers) skipped, every field a finite
//! number, and every error naming the file, the line and the column of the field at fault.

use std::path::Path;

use crate::error::CalibrationError;

/// One row of numbers and the line it came from.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Row {
    /// 1-based line in the file.
    pub line: usize,
    /// The numbers, in the order written.
    pub values: Vec<f64>,
    /// 1-based column where each field starts.
    pub columns: Vec<usize>,
}

/// Reads a file as text, the error naming it.
pub(crate) fn read(path: &Path) -> Result<String, CalibrationError> {
    let file = path.display().to_string();
    let bytes =
        std::fs::read(path).map_err(|e| CalibrationError::Input { file: file.clone(), line: 0, column: 0, message: e.to_string() })?;
    String::from_utf8(bytes).map_err(|e| {
        let valid = e.utf8_error().valid_up_to();
        let line = e.as_bytes()[..valid].iter().filter(|b| **b == b'\n').count() + 1;
        CalibrationError::Input { file, line, column: 0, message: "not UTF-8 text".into() }
    })
}

/// The rows of `text` (`file` names it in errors), each with a number of fields `allowed` accepts;
/// `expect` says what a row should hold, for the error.
pub(crate) fn parse(text: &str, file: &str, allowed: &dyn Fn(usize) -> bool, expect: &str) -> Result<Vec<Row>, CalibrationError> {
    let mut rows = Vec::new();
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let content = raw.split('#').next().unwrap_or("");
        if content.trim().is_empty() {
            continue;
        }
        let err = |column: usize, message: String| CalibrationError::Input { file: file.to_string(), line, column, message };
        let mut values = Vec::new();
        let mut columns = Vec::new();
        let mut start = 0usize;
        for field in content.split(',') {
            let lead = field.len() - field.trim_start().len();
            let column = content[..start + lead].chars().count() + 1;
            let word = field.trim();
            let value: f64 = word.parse().map_err(|_| {
                if word.is_empty() { err(column, "empty field".into()) } else { err(column, format!("{word:?} is not a number")) }
            })?;
            if !value.is_finite() {
                return Err(err(column, format!("{word:?} is not finite")));
            }
            values.push(value);
            columns.push(column);
            start += field.len() + 1;
        }
        if !allowed(values.len()) {
            return Err(err(0, format!("{} fields, expected {expect}", values.len())));
        }
        rows.push(Row { line, values, columns });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comments_blank_lines_and_columns() {
        let text = "# header\n\n 0.1, 0.2 ,0.3 # trailing\n1,2,3\n";
        let rows = parse(text, "f.csv", &|n| n == 3, "3").unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].line, 3);
        assert_eq!(rows[0].values, vec![0.1, 0.2, 0.3]);
        assert_eq!(rows[0].columns, vec![2, 7, 12]);
    }

    #[test]
    fn errors_name_line_and_column() {
        let e = parse("1,2,3\n1, x ,3\n", "f.csv", &|n| n == 3, "3").unwrap_err();
        assert_eq!(e, CalibrationError::Input { file: "f.csv".into(), line: 2, column: 4, message: "\"x\" is not a number".into() });
        let e = parse("1,2\n", "f.csv", &|n| n == 3, "3 joint angles").unwrap_err();
        assert!(e.to_string().starts_with("f.csv:1:0: 2 fields, expected 3 joint angles"), "{e}");
        let e = parse("1,,3\n", "f.csv", &|n| n == 3, "3").unwrap_err();
        assert!(e.to_string().starts_with("f.csv:1:3: empty field"), "{e}");
        let e = parse("1,inf,3\n", "f.csv", &|n| n == 3, "3").unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
    }
}
