//! Printing on an inclined plane (004 Section III-D, `strand-plan tilt`): a G-code job laid on a bed
//! tilted by α about its x axis (Eqs. 7-9) with the nozzle kept normal to the bed (Eq. 10), written
//! as a segment file so the orientation travels with every segment.
//!
//! The geometry is the controller's own [`BedTransform`] — the same map the service applies for a
//! `[bed] tilt` — so a job tilted here and a job tilted by the config are the same motion. The file
//! is for a cell whose `[bed] tilt` is 0 (the tilt is in the file; the config's bed offset still
//! places it), e.g. to inspect, edit or stream a tilted job with a fixed-bed config.

use std::path::PathBuf;

use strand_cli::error::{Result, ToolError};
use strand_core::{Segment, SegmentFlags};
use strand_job::bed::BedConfig;
use strand_job::bed::BedTransform;
use strand_job::gcode::{GcodeOptions, parse_file};
use strand_job::segfile::write_path;

/// Eq. 7: the bed's angle from the bolts' height difference h over their distance d (rad).
pub(crate) fn angle_from_bolts(h: f64, d: f64) -> f64 {
    (h / d).atan()
}

/// `strand-plan tilt`.
#[derive(Clone, Debug)]
pub struct TiltOptions {
    /// The G-code job, in the bed's own frame.
    pub job: PathBuf,
    /// Tilt α of the bed about its x axis (degrees, 0 ≤ α < 90; 004 printed at 10, 45, 60, 80).
    pub angle_deg: Option<f64>,
    /// Eq. 7: the adjustable bolt's height h (m) …
    pub bolt_height: Option<f64>,
    /// … over the distance d between the bolts (m): α = atan(h / d).
    pub bolt_distance: Option<f64>,
    /// The segment file to write.
    pub output: PathBuf,
}

/// The job's segments on the tilted bed (the bed origin stays at the origin).
pub(crate) fn tilt_job(job: &std::path::Path, alpha: f64) -> Result<(Vec<Segment>, Vec<String>)> {
    let bed = BedTransform::new(&BedConfig { tilt: alpha, offset: [0.0; 3], frame: None, mesh: None })
        .map_err(|e| ToolError::Usage(e.message.replace("[bed] tilt", "--angle")))?;
    let mut parser = parse_file(job, GcodeOptions { first_seq: 1, ..GcodeOptions::for_path(job) })?;
    let mut out = Vec::new();
    for g in parser.by_ref() {
        out.push(bed.segment(&g?.segment));
    }
    if out.is_empty() {
        return Err(ToolError::Plan(format!("{}: no motion in the program", job.display())));
    }
    let n = out.len();
    out[n - 1].flags = out[n - 1].flags.with(SegmentFlags::LAST);
    Ok((out, parser.warnings().iter().map(|w| format!("{}: {w}", job.display())).collect()))
}

/// Runs `strand-plan tilt`.
pub fn run(args: &TiltOptions) -> Result<()> {
    let alpha = match (args.angle_deg, args.bolt_height, args.bolt_distance) {
        (Some(a), _, _) => a.to_radians(),
        (None, Some(h), Some(d)) if h.is_finite() && d.is_finite() && d > 0.0 && h >= 0.0 => angle_from_bolts(h, d),
        (None, Some(h), Some(d)) => return Err(ToolError::Plan(format!("--bolt-height {h} / --bolt-distance {d}: need h ≥ 0 and d > 0"))),
        _ => return Err(ToolError::Plan("give --angle or --bolt-height with --bolt-distance".to_string())),
    };
    if !(alpha.is_finite() && (0.0..std::f64::consts::FRAC_PI_2).contains(&alpha)) {
        return Err(ToolError::Plan(format!("--angle {:.3}°: must be at least 0° and below 90°", alpha.to_degrees())));
    }
    let (segments, warnings) = tilt_job(&args.job, alpha)?;
    for w in &warnings {
        eprintln!("strand-plan tilt: warning: {w}");
    }
    let note = format!(
        "strand-plan tilt: {} on a bed tilted {:.4}° about x (004 Eqs. 7-10); stream with [bed] tilt = 0",
        args.job.display(),
        alpha.to_degrees()
    );
    write_path(&args.output, &segments, &note).map_err(strand_job::JobError::from)?;
    println!("{}: {} segments, bed tilted {:.3}° about x", args.output.display(), segments.len(), alpha.to_degrees());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn box35() -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/gcode/slic3r/box35.gcode"))
    }

    #[test]
    fn the_job_lies_on_the_tilted_plane_with_the_nozzle_normal_to_it() {
        let (flat, _) = tilt_job(&box35(), 0.0).unwrap();
        for deg in [10.0f64, 45.0, 60.0, 80.0] {
            let a = deg.to_radians();
            let (tilted, _) = tilt_job(&box35(), a).unwrap();
            assert_eq!(tilted.len(), flat.len());
            let normal = Vector3::new(0.0, -a.sin(), a.cos());
            for (t, f) in tilted.iter().zip(&flat) {
                // Eq. 9: p_s = R(x, α)·p_b — height above the bed and distances are kept.
                assert!((t.end.dot(&normal) - f.end.z).abs() < 1e-12);
                assert!((t.end.x - f.end.x).abs() < 1e-15);
                assert!((t.end.norm() - f.end.norm()).abs() < 1e-12);
                // Eq. 10: the nozzle (tool z) points into the bed, along −normal.
                assert!((t.orientation * Vector3::z() + normal).norm() < 1e-12, "{deg}°");
                assert_eq!(
                    (t.kind, t.flags.0 & !SegmentFlags::LAST.0, t.feed, t.filament),
                    (f.kind, f.flags.0 & !SegmentFlags::LAST.0, f.feed, f.filament)
                );
            }
        }
        assert!(tilted_last_only(&flat));
    }

    fn tilted_last_only(s: &[Segment]) -> bool {
        s.iter().filter(|x| x.flags.contains(SegmentFlags::LAST)).count() == 1 && s.last().unwrap().flags.contains(SegmentFlags::LAST)
    }

    #[test]
    fn eq_7_gives_the_angle_from_the_bolts() {
        assert!((angle_from_bolts(0.1, 0.1) - std::f64::consts::FRAC_PI_4).abs() < 1e-15);
        assert!((angle_from_bolts(0.0, 0.2)).abs() < 1e-15);
        assert!(tilt_job(&box35(), std::f64::consts::FRAC_PI_2).unwrap_err().to_string().contains("--angle"));
    }
}
