//! Rotary words: how a program's `A`, `B` and `C` words map onto the cell's external axes (a
//! positioner under the part), and the checks of that mapping as a robot file's `[positioner]`
//! section gives it (`gcode_words`, `gcode_signs`, `gcode_offsets`). Reading the words in a program
//! is the interpreter's business (`interpreter::rotary`); this module holds only the mapping.

use std::f64::consts::PI;

use thiserror::Error;

/// How many external axes a segment carries (`strand_core::Segment::axes`).
pub const ROTARY_AXES: usize = strand_wire::MAX_EXTERNAL_AXES;

/// Largest accepted magnitude of a rotary word, of an axis's position after `G91` increments and
/// `G92` offsets, and of a mapping's offset, in the units of each (degrees for the words, rad for
/// the offset): far beyond any positioner, and far below overflow.
pub const MAX_ANGLE: f64 = 1e6;

/// One rotary word of the program mapped onto an external axis: the axis (rad) is
/// `sign · (word in degrees) · π/180 + offset`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotaryAxis {
    /// The word, `'A'`, `'B'` or `'C'` (upper case; the program may write it in either case).
    pub word: char,
    /// +1 or −1 (dimensionless): whether the axis turns with the word or against it.
    pub sign: f64,
    /// Where the axis is (rad) when the word is 0 (finite, at most ±[`MAX_ANGLE`]).
    pub offset: f64,
}

/// A rotary mapping that cannot be used: the configuration key at fault and why.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[error("{key}: {message}")]
pub struct RotaryConfigError {
    /// The `[positioner]` key at fault: `"gcode_words"`, `"gcode_signs"` or `"gcode_offsets"`.
    pub key: &'static str,
    /// What is wrong.
    pub message: String,
}

fn fault(key: &'static str, message: String) -> RotaryConfigError {
    RotaryConfigError { key, message }
}

impl RotaryAxis {
    /// The axis position (rad) for a word value of `degrees`.
    pub fn axis(&self, degrees: f64) -> f64 {
        self.sign * (degrees * PI / 180.0) + self.offset
    }

    /// A rotary word as a configuration writes it: one letter `A`, `B` or `C` (either case, blanks
    /// around it ignored), returned upper case.
    pub fn parse_word(text: &str) -> Result<char, RotaryConfigError> {
        let mut chars = text.trim().chars();
        match (chars.next(), chars.next()) {
            (Some(c), None) if matches!(c.to_ascii_uppercase(), 'A' | 'B' | 'C') => Ok(c.to_ascii_uppercase()),
            _ => Err(fault("gcode_words", format!("{text:?} is not a rotary word (A, B or C)"))),
        }
    }

    /// The mapping of a `[positioner]` section: `words[k]` drives external axis k with
    /// `signs[k]` and `offsets[k]` (rad). An empty `signs` means all +1 and an empty `offsets` all 0;
    /// otherwise each list has one entry per word. At most [`ROTARY_AXES`] words, none twice; signs
    /// are +1 or −1; offsets finite and at most ±[`MAX_ANGLE`] rad. The error names the key.
    pub fn from_config<S: AsRef<str>>(
        words: &[S],
        signs: &[f64],
        offsets: &[f64],
    ) -> Result<[Option<RotaryAxis>; ROTARY_AXES], RotaryConfigError> {
        if words.len() > ROTARY_AXES {
            let message = format!("{} words, at most {ROTARY_AXES} (one per external axis)", words.len());
            return Err(fault("gcode_words", message));
        }
        for (key, len) in [("gcode_signs", signs.len()), ("gcode_offsets", offsets.len())] {
            if len != 0 && len != words.len() {
                let message = format!("{len} entries for {} gcode_words: give one per word (or none for the default)", words.len());
                return Err(fault(key, message));
            }
        }
        let mut mapping = [None; ROTARY_AXES];
        for (k, word) in words.iter().enumerate() {
            let axis = RotaryAxis {
                word: RotaryAxis::parse_word(word.as_ref())?,
                sign: signs.get(k).copied().unwrap_or(1.0),
                offset: offsets.get(k).copied().unwrap_or(0.0),
            };
            mapping[k] = Some(axis);
        }
        check_mapping(&mapping)?;
        Ok(mapping)
    }
}

/// Checks a mapping however it was made (the [`GcodeOptions::rotary`](super::GcodeOptions::rotary)
/// fields are public): words `A`/`B`/`C`, none twice, signs ±1, offsets finite within ±[`MAX_ANGLE`].
pub fn check_mapping(mapping: &[Option<RotaryAxis>; ROTARY_AXES]) -> Result<(), RotaryConfigError> {
    for (k, axis) in mapping.iter().enumerate() {
        let Some(axis) = axis else { continue };
        if !matches!(axis.word, 'A' | 'B' | 'C') {
            return Err(fault("gcode_words", format!("{:?} is not a rotary word (A, B or C)", axis.word)));
        }
        if mapping[..k].iter().flatten().any(|a| a.word == axis.word) {
            return Err(fault("gcode_words", format!("{} given twice: one word drives one axis", axis.word)));
        }
        if axis.sign != 1.0 && axis.sign != -1.0 {
            return Err(fault("gcode_signs", format!("{} (for {}) is not +1 or -1", axis.sign, axis.word)));
        }
        if !(axis.offset.is_finite() && axis.offset.abs() <= MAX_ANGLE) {
            return Err(fault("gcode_offsets", format!("{} rad (for {}) is not finite within ±{MAX_ANGLE:e} rad", axis.offset, axis.word)));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_config_maps_words_in_order_with_defaults() {
        let m = RotaryAxis::from_config(&["b", " C "], &[], &[]).unwrap();
        assert_eq!(m[0], Some(RotaryAxis { word: 'B', sign: 1.0, offset: 0.0 }));
        assert_eq!(m[1], Some(RotaryAxis { word: 'C', sign: 1.0, offset: 0.0 }));
        let m = RotaryAxis::from_config(&["C".to_string()], &[-1.0], &[0.5]).unwrap();
        assert_eq!(m, [Some(RotaryAxis { word: 'C', sign: -1.0, offset: 0.5 }), None]);
        assert!((m[0].unwrap().axis(90.0) - (0.5 - PI / 2.0)).abs() < 1e-15);
        assert_eq!(RotaryAxis::from_config::<&str>(&[], &[], &[]).unwrap(), [None, None]);
    }

    #[test]
    fn bad_configs_name_the_key() {
        type Case<'a> = (&'a [&'a str], &'a [f64], &'a [f64], &'a str);
        let cases: [Case; 8] = [
            (&["A", "B", "C"], &[], &[], "gcode_words: 3 words, at most 2"),
            (&["D"], &[], &[], "gcode_words: \"D\" is not a rotary word"),
            (&["AB"], &[], &[], "gcode_words: \"AB\" is not a rotary word"),
            (&["C", "c"], &[], &[], "gcode_words: C given twice"),
            (&["C"], &[2.0], &[], "gcode_signs: 2 (for C) is not +1 or -1"),
            (&["C"], &[1.0, 1.0], &[], "gcode_signs: 2 entries for 1 gcode_words"),
            (&["A", "C"], &[], &[0.0], "gcode_offsets: 1 entries for 2 gcode_words"),
            (&["C"], &[], &[f64::NAN], "gcode_offsets: NaN rad (for C) is not finite"),
        ];
        for (words, signs, offsets, want) in cases {
            let e = RotaryAxis::from_config(words, signs, offsets).unwrap_err().to_string();
            assert!(e.starts_with(want), "{words:?} {signs:?} {offsets:?}: {e}");
        }
    }
}
