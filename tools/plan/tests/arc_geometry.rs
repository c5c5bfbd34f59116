//! One arc geometry for every use (ARCH): the G-code reader's segment length, the path engine's
//! run length and the strip planner's flattened points all come from `strand_core::arc_geometry`.
//! Pinned on a helix whose start lies off the centre's plane (where the three used to disagree: the
//! reader and the planner measured the rise from the centre, not from the start) and on a slight
//! spiral (G-code tolerates a radius mismatch).

use std::f64::consts::PI;

use nalgebra::{UnitQuaternion, Vector3};
use strand_core::{Geometry, PathConfig, PathEngine, Segment, SegmentFlags, SegmentKind, arc_geometry, distance_to_arc};
use strand_job::gcode::segment_length;
use strand_plan::strips::flatten_arc;

fn arc(end: Vector3<f64>, sweep: f64) -> Segment {
    Segment {
        seq: 1,
        kind: SegmentKind::Arc,
        end,
        centre: Vector3::zeros(),
        normal: Vector3::z(),
        sweep,
        feed: 0.02,
        flags: SegmentFlags::LAST,
        ..Default::default()
    }
}

/// ∫ |p'(θ)| dθ by Simpson's rule on the spiral from (r0, z0) to (r1, z1).
fn numeric_length(r0: f64, r1: f64, z0: f64, z1: f64, sweep: f64) -> f64 {
    let n = 200_000;
    let (k, h) = ((r1 - r0) / sweep, (z1 - z0) / sweep);
    let speed = |t: f64| {
        let r = r0 + k * t;
        (r * r + k * k + h * h).sqrt()
    };
    let dt = sweep / n as f64;
    let mut sum = speed(0.0) + speed(sweep);
    for i in 1..n {
        sum += speed(i as f64 * dt) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * dt / 3.0
}

/// The length the path engine runs: its path position at Finished.
fn engine_length(start: Vector3<f64>, s: &Segment) -> f64 {
    let config = PathConfig::default();
    let mut engine = PathEngine::new(&config, 0.001, start, UnitQuaternion::identity()).unwrap();
    engine.push(s).unwrap();
    for _ in 0..200_000 {
        let sample = engine.step(1.0);
        if sample.motion == strand_core::Motion::Finished {
            assert!((sample.position - s.end).norm() < 1e-9, "finished at the arc's end");
            return sample.s;
        }
    }
    panic!("the arc did not finish");
}

#[test]
fn a_helix_off_the_centre_plane_has_one_length_and_one_curve() {
    let (r, turns, z0, z1) = (0.01, 1.5, 0.002, 0.007);
    let sweep = 2.0 * PI * turns;
    let start = Vector3::new(r, 0.0, z0);
    let end = Vector3::new(r * sweep.cos(), r * sweep.sin(), z1);
    let s = arc(end, sweep);
    let exact = ((r * sweep).powi(2) + (z1 - z0).powi(2)).sqrt();
    let geometry = arc_geometry(&start, &s).unwrap();
    assert!((geometry.length(0.0) - exact).abs() < 1e-15, "core: {} against {exact}", geometry.length(0.0));
    assert_eq!(segment_length(&start, &s), geometry.length(0.0), "the G-code reader measures the core's arc");
    let run = engine_length(start, &s);
    assert!((run - exact).abs() < 1e-12, "the engine runs {run} m of {exact} m");

    let points = flatten_arc(&start, &s, 10e-6).unwrap();
    assert_eq!(*points.last().unwrap(), end);
    let mut previous = start;
    let mut chords = 0.0;
    for (i, p) in points.iter().enumerate() {
        assert!(distance_to_arc(p, &geometry, exact) < 1e-12, "point {i} lies on the arc");
        // The rise is linear in θ from the start's height, not from the centre's.
        let f = (i + 1) as f64 / points.len() as f64;
        assert!((p.z - (z0 + (z1 - z0) * f)).abs() < 1e-12, "point {i} at z {} m", p.z);
        chords += (p - previous).norm();
        previous = *p;
    }
    // A 10 µm sagitta on a 10 mm radius: chords of 0.089 rad, each θ²/24 = 3.3e-4 shorter.
    assert!(chords <= exact && exact - chords < 4e-4 * exact, "chords {chords} m against {exact} m");
}

#[test]
fn a_spiral_is_measured_exactly() {
    // A 1 % radius mismatch over three quarters of a turn, rising 1 mm.
    let (r0, r1, sweep, rise) = (0.01, 0.0101, 1.5 * PI, 0.001);
    let start = Vector3::new(r0, 0.0, 0.0);
    let end = Vector3::new(r1 * sweep.cos(), r1 * sweep.sin(), rise);
    let s = arc(end, sweep);
    let expected = numeric_length(r0, r1, 0.0, rise, sweep);
    let length = segment_length(&start, &s);
    assert!((length - expected).abs() < 1e-12 * expected, "spiral {length} m against {expected} m");
    let Some(Geometry::Arc { radius, radius_rate, .. }) = arc_geometry(&start, &s) else { panic!("an arc") };
    assert!((radius - r0).abs() < 1e-15 && (radius + radius_rate * sweep - r1).abs() < 1e-15);
    let run = engine_length(start, &s);
    assert!((run - length).abs() < 1e-12, "the engine runs {run} m of {length} m");
}
