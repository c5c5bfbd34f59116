//! The paper's Eqs. 2-4 (W ≤ R/2, N ≤ ⌊W/L⌋, N ≤ ⌊R/(2L)⌋), checked per strip and reported together,
//! so that a refused plan names every violated equation with its numbers.

use serde::Serialize;
use strand_cli::error::{Result, ToolError};

/// Relative slack on the floors of Eqs. 3 and 4.
const FLOOR_SLACK: f64 = 1e-9;

/// Eq. 2 for the widest strip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Eq2 {
    /// The widest strip (1-based).
    pub strip: usize,
    /// Its width W (m).
    pub width_m: f64,
    /// R/2 (m), which W may not exceed.
    pub half_reach_m: f64,
    /// W ≤ R/2.
    pub ok: bool,
}

/// Eq. 3 for one strip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Eq3 {
    /// The strip (1-based).
    pub strip: usize,
    /// Its width W (m).
    pub width_m: f64,
    /// ⌊W/L⌋.
    pub max_layers: u64,
    /// N ≤ ⌊W/L⌋.
    pub ok: bool,
}

/// Eq. 4.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Eq4 {
    /// ⌊R/(2L)⌋.
    pub max_layers: u64,
    /// N ≤ ⌊R/(2L)⌋.
    pub ok: bool,
}

/// The checks of Eqs. 2-4.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Checks {
    /// N: layers of the job.
    pub layers: usize,
    /// Eq. 2: the widest strip within half the reach.
    pub eq2: Eq2,
    /// Eq. 3, strip by strip: the layers a strip's width allows.
    pub eq3: Vec<Eq3>,
    /// Eq. 4: the layers the reach allows.
    pub eq4: Eq4,
}

fn floor_ratio(a: f64, b: f64) -> u64 {
    ((a / b) * (1.0 + FLOOR_SLACK)).floor().max(0.0) as u64
}

/// Evaluates Eqs. 2-4 for strips of nominal `widths`, N = `layers`, L = `overlap`, R = `reach`.
/// Err lists every violated equation with its numbers and strip (1-based).
pub fn check_equations(widths: &[f64], layers: usize, overlap: f64, reach: f64) -> Result<Checks> {
    let (widest, width) = widths.iter().copied().enumerate().fold((0, f64::NEG_INFINITY), |m, (k, w)| if w > m.1 { (k, w) } else { m });
    let half = reach / 2.0;
    let eq2 = Eq2 { strip: widest + 1, width_m: width, half_reach_m: half, ok: width <= half * (1.0 + FLOOR_SLACK) };
    let eq3: Vec<Eq3> = widths
        .iter()
        .enumerate()
        .map(|(k, &w)| {
            let max = floor_ratio(w, overlap);
            Eq3 { strip: k + 1, width_m: w, max_layers: max, ok: layers as u64 <= max }
        })
        .collect();
    let max4 = floor_ratio(reach, 2.0 * overlap);
    let eq4 = Eq4 { max_layers: max4, ok: layers as u64 <= max4 };
    let mut errors = Vec::new();
    if !eq2.ok {
        errors.push(format!(
            "Eq. 2 (W ≤ R/2) violated: strip {} is W = {} m wide, more than --reach {} m / 2 = {} m",
            eq2.strip, eq2.width_m, reach, half
        ));
    }
    for e in eq3.iter().filter(|e| !e.ok) {
        errors.push(format!(
            "Eq. 3 (N ≤ ⌊W/L⌋) violated: strip {} (W = {} m) with --overlap {} m allows ⌊{}/{}⌋ = {} layers, the job has N = {layers}",
            e.strip, e.width_m, overlap, e.width_m, overlap, e.max_layers
        ));
    }
    if !eq4.ok {
        errors.push(format!(
            "Eq. 4 (N ≤ ⌊R/(2L)⌋) violated: --reach {reach} m and --overlap {overlap} m allow ⌊{reach}/(2·{overlap})⌋ = {} layers, the job has N = {layers}",
            eq4.max_layers
        ));
    }
    let checks = Checks { layers, eq2, eq3, eq4 };
    if errors.is_empty() { Ok(checks) } else { Err(ToolError::Usage(errors.join("; "))) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq2_names_the_widest_strip_and_the_reach() {
        let e = check_equations(&[0.043, 0.06, 0.047], 4, 0.005, 0.1).unwrap_err().to_string();
        assert!(e.starts_with("Eq. 2 (W ≤ R/2) violated: strip 2 is W = 0.06 m wide"), "{e}");
        assert!(e.contains("--reach 0.1 m / 2 = 0.05 m"), "{e}");
        assert!(!e.contains("Eq. 3") && !e.contains("Eq. 4"), "{e}");
        // R = 0.12 m is exactly enough for 60 mm.
        let c = check_equations(&[0.043, 0.06, 0.047], 4, 0.005, 0.12).unwrap();
        assert_eq!((c.eq2.strip, c.eq2.half_reach_m, c.eq2.ok), (2, 0.06, true));
    }

    #[test]
    fn eq3_names_each_strip_too_narrow_for_the_layers() {
        // ⌊43/15⌋ = 2, ⌊60/15⌋ = 4, ⌊47/15⌋ = 3 against N = 4; ⌊120/30⌋ = 4 keeps Eq. 4.
        let e = check_equations(&[0.043, 0.06, 0.047], 4, 0.015, 0.12).unwrap_err().to_string();
        assert!(e.contains("Eq. 3 (N ≤ ⌊W/L⌋) violated: strip 1 (W = 0.043 m) with --overlap 0.015 m allows ⌊0.043/0.015⌋ = 2 layers, the job has N = 4"), "{e}");
        assert!(e.contains("strip 3 (W = 0.047 m) with --overlap 0.015 m allows ⌊0.047/0.015⌋ = 3 layers"), "{e}");
        assert!(!e.contains("strip 2 (") && !e.contains("Eq. 2") && !e.contains("Eq. 4"), "{e}");
        // A quotient that is an integer in decimal is not floored below it: 0.043/0.01075 = 4.
        let c = check_equations(&[0.043], 4, 0.01075, 0.1).unwrap();
        assert_eq!(c.eq3[0].max_layers, 4);
        assert!(check_equations(&[0.043], 5, 0.01075, 0.1).is_err());
    }

    #[test]
    fn eq4_bounds_the_layers_by_reach_and_overlap() {
        // R = 0.1, L = 0.015: ⌊0.1/0.03⌋ = 3 < 4. Eq. 4 follows from Eqs. 2 and 3, so one of them
        // fails too: here Eq. 2 (60 mm > 50 mm), while ⌊0.06/0.015⌋ = 4 keeps Eq. 3.
        let e = check_equations(&[0.06], 4, 0.015, 0.1).unwrap_err().to_string();
        assert!(
            e.contains(
                "Eq. 4 (N ≤ ⌊R/(2L)⌋) violated: --reach 0.1 m and --overlap 0.015 m allow ⌊0.1/(2·0.015)⌋ = 3 layers, the job has N = 4"
            ),
            "{e}"
        );
        assert!(e.contains("Eq. 2") && !e.contains("Eq. 3"), "{e}");
        let c = check_equations(&[0.05], 4, 0.0125, 0.1).unwrap();
        assert_eq!(c.eq4.max_layers, 4);
    }
}
