//! 000's free-form 1D truss (Section 2.2) as G-code: a base layer, the cross beams, a top layer,
//! printed as one continuous extrusion, of any length.
//!
//! 000 gives the length (100 cm, "any length"), the order (base layer, then the vertical cross
//! beams, then the top layer, continuous extrusion throughout), the nozzle (1.2 mm), the filament
//! (2.85 mm PLA), the speed (3.33 mm/s with 3.77 mm³/s: a round 1.2 mm strand) and a height under
//! 10 mm; its figures with the cross-section are not in the text. Our reading, documented in the
//! file header it writes: two chords along x, `width` apart, joined by beams across (a Warren
//! pattern with posts every `pitch`), each layer `layer_height` thick:
//!
//! - layer 1: both chords and the two end posts, as one loop;
//! - layer 2: the cross beams, post – diagonal – post … from x = 0 to the far end;
//! - layer 3: the chords again, starting where layer 2 ended.

use std::fmt::Write;
use strand_cli::error::{Result, ToolError};

/// Truss dimensions and process (SI units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truss {
    /// Length along x (m).
    pub length: f64,
    /// Distance between the chords (m).
    pub width: f64,
    /// Post spacing (m); the length is split into whole panels of about this size.
    pub pitch: f64,
    /// Layer height (m).
    pub layer_height: f64,
    /// Strand diameter: the nozzle's (m).
    pub strand: f64,
    /// Filament diameter (m).
    pub filament: f64,
    /// Print speed (m/s).
    pub speed: f64,
}

impl Default for Truss {
    /// 000's process on a 100 cm truss: 1.2 mm nozzle, 2.85 mm filament, 3.33 mm/s.
    fn default() -> Self {
        Truss { length: 1.0, width: 0.04, pitch: 0.04, layer_height: 1.0e-3, strand: 1.2e-3, filament: 2.85e-3, speed: 3.33e-3 }
    }
}

impl Truss {
    /// Checks the dimensions; the message names the parameter.
    pub fn validate(&self) -> Result<()> {
        crate::positive("length", self.length)?;
        crate::positive("width", self.width)?;
        crate::positive("pitch", self.pitch)?;
        crate::positive("layer-height", self.layer_height)?;
        crate::positive("strand", self.strand)?;
        crate::positive("filament", self.filament)?;
        crate::positive("speed", self.speed)?;
        if self.pitch > self.length {
            return Err(ToolError::Usage(format!("--pitch = {} m is longer than --length = {} m", self.pitch, self.length)));
        }
        Ok(())
    }

    /// Panels between posts.
    pub(crate) fn panels(&self) -> usize {
        ((self.length / self.pitch).round() as usize).max(1)
    }

    /// The three layers' polylines (m, bed coordinates), in print order; each starts where the last
    /// ended, so the extrusion never stops.
    pub fn layers(&self) -> [Vec<[f64; 3]>; 3] {
        let (l, w) = (self.length, self.width);
        let h = self.layer_height;
        let n = self.panels();
        let p = l / n as f64;
        let base = vec![[0.0, 0.0, h], [l, 0.0, h], [l, w, h], [0.0, w, h], [0.0, 0.0, h]];
        let mut beams = vec![[0.0, 0.0, 2.0 * h], [0.0, w, 2.0 * h]];
        for k in 1..=n {
            // A diagonal down to the near chord, then the post back across: parallel diagonals.
            let x = k as f64 * p;
            beams.push([x, 0.0, 2.0 * h]);
            beams.push([x, w, 2.0 * h]);
        }
        let end = *beams.last().expect("posts");
        let other = if end[1] == 0.0 { w } else { 0.0 };
        let top = vec![[l, end[1], 3.0 * h], [0.0, end[1], 3.0 * h], [0.0, other, 3.0 * h], [l, other, 3.0 * h]];
        [base, beams, top]
    }

    /// Total extruded path length (m).
    pub fn path_length(&self) -> f64 {
        let layers = self.layers();
        let mut total = 0.0;
        let mut last: Option<[f64; 3]> = None;
        for layer in &layers {
            for q in layer {
                if let Some(a) = last {
                    total += ((q[0] - a[0]).powi(2) + (q[1] - a[1]).powi(2) + (q[2] - a[2]).powi(2)).sqrt();
                }
                last = Some(*q);
            }
        }
        total
    }

    /// Writes [`Truss::gcode`] to `output` (with a line on stderr: panels, strand length) or, with
    /// None, to standard output.
    pub fn write(&self, output: Option<&std::path::Path>) -> Result<()> {
        let text = self.gcode();
        match output {
            Some(p) => {
                std::fs::write(p, text).map_err(ToolError::file(p))?;
                eprintln!("strand-plan truss: {} ({} panels, {:.3} m of strand)", p.display(), self.panels(), self.path_length());
            }
            None => print!("{text}"),
        }
        Ok(())
    }

    /// The program: mm, absolute positions, relative E (M83), layer comments PrusaSlicer-style.
    pub fn gcode(&self) -> String {
        let e_per_m = (self.strand * self.strand) / (self.filament * self.filament); // round strand
        let feed = self.speed * 60e3; // mm/min
        let mut g = String::new();
        let _ = writeln!(g, "; strand-plan truss: 000's free-form 1D truss (Section 2.2), one continuous extrusion");
        let _ = writeln!(
            g,
            "; length {:.1} mm, width {:.1} mm, {} panels, layer {:.2} mm, strand {:.2} mm, filament {:.2} mm, {:.2} mm/s, path {:.1} mm",
            self.length * 1e3,
            self.width * 1e3,
            self.panels(),
            self.layer_height * 1e3,
            self.strand * 1e3,
            self.filament * 1e3,
            self.speed * 1e3,
            self.path_length() * 1e3
        );
        let _ = writeln!(g, "G21 ; mm\nG90 ; absolute positions\nM83 ; relative extrusion");
        let mut at: Option<[f64; 3]> = None;
        for (k, layer) in self.layers().iter().enumerate() {
            let _ = writeln!(g, ";LAYER_CHANGE\n;Z:{:.3}", layer[0][2] * 1e3);
            let _ = writeln!(g, ";TYPE:{}", ["Base layer", "Cross beams", "Top layer"][k]);
            for q in layer {
                match at {
                    None => {
                        let _ = writeln!(g, "G0 X{:.3} Y{:.3} Z{:.3} F3000", q[0] * 1e3, q[1] * 1e3, q[2] * 1e3);
                        let _ = writeln!(g, "G1 F{feed:.1}");
                    }
                    Some(a) => {
                        let d = ((q[0] - a[0]).powi(2) + (q[1] - a[1]).powi(2) + (q[2] - a[2]).powi(2)).sqrt();
                        if d > 1e-9 {
                            let _ = writeln!(g, "G1 X{:.3} Y{:.3} Z{:.3} E{:.5}", q[0] * 1e3, q[1] * 1e3, q[2] * 1e3, d * e_per_m * 1e3);
                        }
                    }
                }
                at = Some(*q);
            }
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_truss_is_one_continuous_path_over_three_layers() {
        let t = Truss { length: 0.2, ..Truss::default() };
        let [base, beams, top] = t.layers();
        assert_eq!(t.panels(), 5);
        assert_eq!(base.last(), Some(&[0.0, 0.0, 1e-3]));
        // Continuous: each layer starts above where the last ended.
        assert_eq!((beams[0][0], beams[0][1]), (0.0, 0.0));
        assert_eq!((top[0][0], top[0][1]), (beams.last().unwrap()[0], beams.last().unwrap()[1]));
        // 6 posts and 5 diagonals.
        let diag = (0.04f64.powi(2) + 0.04f64.powi(2)).sqrt();
        let beams_len = 6.0 * 0.04 + 5.0 * diag;
        let expected = (0.4 + 0.08) + 1e-3 + beams_len + 1e-3 + (0.2 + 0.04 + 0.2);
        assert!((t.path_length() - expected).abs() < 1e-9, "{} vs {expected}", t.path_length());
    }

    #[test]
    fn the_program_parses_with_the_paper_flow() {
        let t = Truss { length: 0.2, ..Truss::default() };
        let text = t.gcode();
        let dir = std::env::temp_dir().join(format!("strand-truss-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("truss.gcode");
        std::fs::write(&p, &text).unwrap();
        let parsed: Vec<_> =
            strand_job::gcode::parse_file(&p, strand_job::gcode::GcodeOptions::for_path(&p)).unwrap().map(|r| r.unwrap()).collect();
        let extruding: Vec<_> = parsed.iter().filter(|g| g.segment.filament > 0.0).collect();
        let length: f64 = extruding.iter().map(|g| g.segment.feed).fold(0.0, f64::max);
        assert!((length - 3.33e-3).abs() < 1e-9, "feed {length} m/s");
        let filament: f64 = extruding.iter().map(|g| g.segment.filament).sum();
        // 000: 3.77 mm³/s at 3.33 mm/s: a round 1.2 mm strand.
        let area = std::f64::consts::PI / 4.0 * 2.85e-3f64.powi(2);
        let strand = filament * area / t.path_length();
        assert!((strand - std::f64::consts::PI / 4.0 * 1.2e-3f64.powi(2)).abs() < 1e-9, "{strand}");
        assert!((strand * 3.33e-3 * 1e9 - 3.77).abs() < 0.01);
        let layers: Vec<_> = parsed.iter().filter_map(|g| g.tags.layer).collect();
        assert_eq!(layers.iter().max(), Some(&2));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
