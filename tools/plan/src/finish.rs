//! 002's finishing layer (Section 6.2, Eqs. 20-21, `strand-plan finish`): one layer laid over the
//! curved top of a part, z = z₀·exp(−y²/β²), with the nozzle kept normal to the surface so the
//! strands run across the stair steps of the flat layers below instead of following them.
//!
//! The layer is a raster of paths along y (up, over and down the profile), stepped across x, each
//! path a chain of short lines whose ends lie on the surface offset outwards by the layer
//! thickness. The tool tilts in the y–z plane by Eq. 21, α = π − atan(dz/dy): α is the angle of the
//! nozzle from +z (π: straight down), leaning with the slope. 002 states the orientation as ZYX
//! Euler angles (0, α, 0) in its robot's base frame; here the profile runs along y, so the same
//! tilt is a turn about x. The roll about the nozzle is the G-code default's
//! ([`strand_job::segfile::tool_pointing`]), so a finishing layer follows flat layers without a spin.

use std::path::PathBuf;

use nalgebra::Vector3;
use strand_core::{Segment, SegmentFlags, SegmentKind};
use strand_job::segfile::{tool_pointing, write_path};

use super::surface::{Bump, Surface};
use strand_cli::error::{Result, ToolError};

/// The profile of Eq. 20 and the raster laid over it (SI units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Finish {
    /// Height z₀ of the profile (m; 002: 3 mm).
    pub z0: f64,
    /// Width β of the profile (m; 002: 18 mm).
    pub beta: f64,
    /// The layer covers y from −half_length to +half_length (m).
    pub half_length: f64,
    /// Width of the part along x (m); paths run from x = 0 to this.
    pub width: f64,
    /// Distance between neighbouring paths along x (m): the strand width.
    pub spacing: f64,
    /// Length of the chords that make up a path (m).
    pub step: f64,
    /// Layer thickness (m): the nozzle runs this far from the surface along its normal.
    pub layer_height: f64,
    /// Filament diameter (m).
    pub filament: f64,
    /// Print speed (m/s).
    pub feed: f64,
    /// Height of the profile's foot above the bed (m).
    pub z_base: f64,
}

impl Default for Finish {
    /// The values `strand-plan` uses when no flag is given.
    fn default() -> Self {
        Finish {
            z0: 3e-3,
            beta: 18e-3,
            half_length: 45e-3,
            width: 20e-3,
            spacing: 0.45e-3,
            step: 0.5e-3,
            layer_height: 0.2e-3,
            filament: 1.75e-3,
            feed: 0.01,
            z_base: 0.0,
        }
    }
}

impl Finish {
    /// Checks the parameters; the message names the flag.
    pub fn validate(&self) -> Result<()> {
        super::positive("beta", self.beta)?;
        super::positive("half-length", self.half_length)?;
        super::positive("width", self.width)?;
        super::positive("spacing", self.spacing)?;
        super::positive("step", self.step)?;
        super::positive("layer-height", self.layer_height)?;
        super::positive("filament", self.filament)?;
        super::positive("feed", self.feed)?;
        if !(self.z0.is_finite() && self.z_base.is_finite()) {
            return Err(ToolError::Usage("--z0 and --z-base must be finite".to_string()));
        }
        if self.spacing < self.layer_height {
            return Err(ToolError::Usage(format!(
                "--spacing {} m is below --layer-height {} m: no strand is that narrow",
                self.spacing, self.layer_height
            )));
        }
        Ok(())
    }

    /// The profile as the `surface` planner's bump (a ridge along x).
    pub fn profile(&self) -> Bump {
        Bump { length: self.width, width: 2.0 * self.half_length, height: self.z0, beta: self.beta }
    }

    /// Eq. 20: the profile height at y (m), on its foot.
    pub fn z(&self, y: f64) -> f64 {
        self.z_base + self.profile().z(y)
    }

    /// dz/dy of Eq. 20.
    pub fn slope(&self, y: f64) -> f64 {
        self.profile().slope(y)
    }

    /// Eq. 21: the nozzle's angle from +z at y (rad; π straight down).
    pub fn alpha(&self, y: f64) -> f64 {
        std::f64::consts::PI - self.slope(y).atan()
    }

    /// The surface's outward unit normal at y (in the y–z plane).
    pub fn normal(&self, y: f64) -> Vector3<f64> {
        self.profile().normal(0.0, y)
    }

    /// Filament per metre of strand (m/m), [`super::filament_per_metre`] with the spacing as the
    /// strand width.
    pub(crate) fn filament_per_m(&self) -> f64 {
        super::filament_per_metre(self.spacing, self.layer_height, self.filament)
    }

    /// The layer: a travel to the first point, then the raster, the last segment LAST.
    pub fn segments(&self) -> Vec<Segment> {
        let paths = (self.width / self.spacing + 1e-9).floor() as usize + 1;
        let chords = (2.0 * self.half_length / self.step).ceil().max(1.0) as usize;
        let e_per_m = self.filament_per_m();
        let mut out = Vec::with_capacity(paths * (chords + 1) + 1);
        let point = |x: f64, y: f64| Vector3::new(x, y, self.z(y)) + self.normal(y) * self.layer_height;
        let tool = |y: f64| tool_pointing(&-self.normal(y));
        let mut last = Vector3::zeros();
        for k in 0..paths {
            let x = k as f64 * self.spacing;
            // Boustrophedon: even paths run towards +y, odd ones back.
            let ys: Vec<f64> = (0..=chords)
                .map(|j| -self.half_length + 2.0 * self.half_length * j as f64 / chords as f64)
                .map(|y| if k % 2 == 0 { y } else { -y })
                .collect();
            let start = point(x, ys[0]);
            let first = k == 0;
            out.push(Segment {
                kind: SegmentKind::Line,
                end: start,
                orientation: tool(ys[0]),
                feed: self.feed,
                filament: if first { 0.0 } else { (start - last).norm() * e_per_m },
                flags: if first { SegmentFlags::TRAVEL } else { SegmentFlags::EXTRUDE },
                ..Segment::default()
            });
            last = start;
            for &y in &ys[1..] {
                let p = point(x, y);
                out.push(Segment {
                    kind: SegmentKind::Line,
                    end: p,
                    orientation: tool(y),
                    feed: self.feed,
                    filament: (p - last).norm() * e_per_m,
                    flags: SegmentFlags::EXTRUDE,
                    ..Segment::default()
                });
                last = p;
            }
        }
        out[1].flags = out[1].flags.with(SegmentFlags::LAYER_START);
        for (k, s) in out.iter_mut().enumerate() {
            s.seq = k as u64 + 1;
        }
        let n = out.len();
        out[n - 1].flags = out[n - 1].flags.with(SegmentFlags::LAST);
        out
    }
}

/// `strand-plan finish`.
#[derive(Clone, Debug)]
pub struct FinishOptions {
    /// The profile and the raster.
    pub finish: Finish,
    /// The segment file to write.
    pub output: PathBuf,
    /// Print a JSON summary.
    pub json: bool,
}

/// Runs `strand-plan finish`.
pub fn run(args: &FinishOptions) -> Result<()> {
    let f = &args.finish;
    f.validate()?;
    let segments = f.segments();
    let note = format!(
        "strand-plan finish: 002 Eqs. 20-21 finishing layer, z0 {} m, beta {} m, y ±{} m, width {} m, spacing {} m, layer {} m, feed {} m/s",
        f.z0, f.beta, f.half_length, f.width, f.spacing, f.layer_height, f.feed
    );
    write_path(&args.output, &segments, &note).map_err(strand_job::JobError::from)?;
    let tilt_max = (0..=2000).map(|k| f.slope(-f.half_length + f.half_length * k as f64 / 1000.0).atan().abs()).fold(0.0, f64::max);
    let length: f64 = segments.windows(2).map(|w| (w[1].end - w[0].end).norm()).sum();
    let filament: f64 = segments.iter().map(|s| s.filament).sum();
    if args.json {
        let v = serde_json::json!({
            "segments": segments.len(),
            "paths": (f.width / f.spacing + 1e-9).floor() as usize + 1,
            "path_length_m": length,
            "filament_m": filament,
            "max_tilt_rad": tilt_max,
            "alpha_range_rad": [std::f64::consts::PI - tilt_max, std::f64::consts::PI + tilt_max],
        });
        println!("{v}");
    } else {
        println!(
            "{}: {} segments, {:.3} m of path, {:.4} m of filament; tool tilt up to {:.2}° (α from {:.2}° to {:.2}°)",
            args.output.display(),
            segments.len(),
            length,
            filament,
            tilt_max.to_degrees(),
            180.0 - tilt_max.to_degrees(),
            180.0 + tilt_max.to_degrees()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The profile's y whose offset point is `p`: p − h·n(y) lies on the surface at y.
    fn surface_y(f: &Finish, p: &Vector3<f64>) -> f64 {
        let (mut lo, mut hi) = (p.y - 1e-3, p.y + 1e-3);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            let q = p - f.normal(mid) * f.layer_height;
            if q.y < mid { hi = mid } else { lo = mid }
        }
        0.5 * (lo + hi)
    }

    fn paper() -> Finish {
        Finish::default()
    }

    #[test]
    fn the_tool_follows_eq_21() {
        let f = paper();
        assert_eq!((f.z0, f.beta), (3e-3, 18e-3));
        // At the crest the nozzle points straight down; the steepest slope is at y = β/√2:
        // dz/dy = −√2·z₀/β·e^(−1/2) = −0.142961, α = π + 0.141998 rad (8.136°).
        assert!((f.alpha(0.0) - std::f64::consts::PI).abs() < 1e-15);
        let y = f.beta / 2f64.sqrt();
        assert!((f.slope(y) + 0.142_960_647).abs() < 1e-9, "{}", f.slope(y));
        assert!((f.alpha(y) - (std::f64::consts::PI + 0.141_998_488)).abs() < 1e-9, "{}", f.alpha(y));
        assert!((0..100).all(|k| f.slope(y + (k as f64 - 50.0) * 1e-4).abs() <= f.slope(y).abs() + 1e-12));
        for s in f.segments() {
            let y = surface_y(&f, &s.end);
            let nozzle = s.orientation * Vector3::z();
            // The nozzle's angle from +z is α (Eq. 21), leaning towards the side the surface faces.
            let from_z = nozzle.z.clamp(-1.0, 1.0).acos();
            let tilt = std::f64::consts::PI - from_z;
            assert!((tilt - f.slope(y).atan().abs()).abs() < 1e-9, "y {y}: {from_z} vs α {}", f.alpha(y));
            assert!((nozzle + f.normal(y)).norm() < 1e-9, "nozzle into the surface at y {y}");
            assert!(nozzle.x.abs() < 1e-12, "the tilt stays in the y–z plane");
            // The roll is the G-code default's: a tilt about x leaves the tool's x axis where the
            // nozzle-down default has it.
            let default_x = tool_pointing(&-Vector3::z()) * Vector3::x();
            assert!(((s.orientation * Vector3::x()) - default_x).norm() < 1e-9);
        }
    }

    #[test]
    fn the_raster_lies_one_layer_above_the_surface() {
        let f = paper();
        let segments = f.segments();
        let paths = 45; // 20 mm / 0.45 mm → 44 gaps, 45 paths
        assert_eq!(segments.len(), paths * 181, "a lead-in and 180 chords per path");
        assert_eq!(segments[0].flags, SegmentFlags::TRAVEL);
        assert!(segments[1].flags.contains(SegmentFlags::LAYER_START));
        assert!(segments.last().unwrap().flags.contains(SegmentFlags::LAST));
        for s in &segments {
            let q = s.end - f.normal(surface_y(&f, &s.end)) * f.layer_height;
            assert!((q.z - f.z(q.y)).abs() < 1e-9, "{:?}", s.end);
            assert!(s.end.x >= -1e-12 && s.end.x <= f.width + 1e-12);
        }
        // Chords: 0.5 mm along y, a little longer on the slopes, a little shorter where the offset
        // surface is concave.
        for w in segments[1..181].windows(2) {
            let l = (w[1].end - w[0].end).norm();
            assert!(l > 0.5e-3 * 0.99 && l < 0.5e-3 * 1.03, "{l}");
        }
        // Filament: Slic3r's flow for 0.45 × 0.2 mm (0.08142 mm²) over 1.75 mm filament is 0.03385 m per m.
        assert!((f.filament_per_m() - 0.033_849).abs() < 1e-6, "{}", f.filament_per_m());
        let len: f64 = segments[1..].iter().zip(&segments).map(|(b, a)| (b.end - a.end).norm()).sum();
        let fil: f64 = segments.iter().map(|s| s.filament).sum();
        assert!((fil - len * f.filament_per_m()).abs() < 1e-12);
    }

    #[test]
    fn bad_parameters_name_the_flag() {
        let mut f = paper();
        f.spacing = 0.1e-3;
        assert!(f.validate().unwrap_err().to_string().contains("--spacing"));
        let mut f = paper();
        f.beta = 0.0;
        assert!(f.validate().unwrap_err().to_string().contains("--beta"));
    }
}
