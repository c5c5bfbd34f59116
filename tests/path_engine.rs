//! The path engine on hand-made segment streams: limits, blending, underrun, dwell, override.

use nalgebra::{UnitQuaternion, Vector3};
use strand_core::{Extruder, ExtruderConfig};
use strand_core::{Motion, PathConfig, PathEngine, PathSample, PlanningMode, Segment, SegmentError, SegmentFlags, SegmentKind};
use strand_job::bed::BedConfig;
use strand_job::bed::BedTransform;

const DT: f64 = 1e-3;

fn line(seq: u64, end: [f64; 3], feed: f64) -> Segment {
    Segment { seq, kind: SegmentKind::Line, end: Vector3::from(end), feed, orientation: UnitQuaternion::identity(), ..Segment::default() }
}

fn engine(mode: PlanningMode) -> PathEngine {
    let config = PathConfig { mode, ..PathConfig::default() };
    PathEngine::new(&config, DT, Vector3::zeros(), UnitQuaternion::identity()).unwrap()
}

fn run(engine: &mut PathEngine, max_ticks: usize) -> Vec<PathSample> {
    let mut out = Vec::new();
    for _ in 0..max_ticks {
        let s = engine.step(1.0);
        out.push(s);
        if engine.is_at_rest() && s.speed == 0.0 && out.len() > 2 {
            break;
        }
    }
    out
}

fn check_limits(samples: &[PathSample], config: &PathConfig, jerk: bool) {
    for (i, s) in samples.iter().enumerate() {
        assert!(s.position.iter().all(|x| x.is_finite()), "tick {i}: position not finite");
        assert!(s.speed <= config.max_speed * (1.0 + 1e-9) + 1e-12, "tick {i}: speed {}", s.speed);
        assert!(s.speed >= 0.0, "tick {i}: negative speed {}", s.speed);
        assert!(s.path_acceleration.abs() <= config.max_acceleration * (1.0 + 1e-6) + 1e-9, "tick {i}: acc {}", s.path_acceleration);
        if jerk {
            assert!(s.path_jerk.abs() <= config.max_jerk * (1.0 + 1e-6) + 1e-9, "tick {i}: jerk {}", s.path_jerk);
        }
    }
}

#[test]
fn square_runs_to_its_end_within_limits_in_every_mode() {
    for mode in [PlanningMode::StopAndGo, PlanningMode::KnowledgeRules, PlanningMode::Lookahead] {
        let mut e = engine(mode);
        let pts = [[0.02, 0.0, 0.0], [0.02, 0.02, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.0]];
        for (i, p) in pts.iter().enumerate() {
            let mut s = line(i as u64 + 1, *p, 0.04);
            if i == 3 {
                s.flags = SegmentFlags::LAST;
            }
            e.push(&s).unwrap();
        }
        let samples = run(&mut e, 100_000);
        let last = samples.last().unwrap();
        assert_eq!(last.motion, Motion::Finished, "{mode:?}");
        assert!(last.position.norm() < 1e-9, "{mode:?}: ends at {:?}", last.position);
        check_limits(&samples, e.config(), mode == PlanningMode::Lookahead);
        println!("{mode:?}: {} ticks, max speed {:.4}", samples.len(), samples.iter().map(|s| s.speed).fold(0.0, f64::max));
    }
}

fn square(e: &mut PathEngine, first_seq: u64, last: bool) {
    let pts = [[0.02, 0.0, 0.0], [0.02, 0.02, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.0]];
    for (i, p) in pts.iter().enumerate() {
        let mut s = line(first_seq + i as u64, *p, 0.04);
        if last && i == 3 {
            s.flags = SegmentFlags::LAST;
        }
        e.push(&s).unwrap();
    }
}

#[test]
fn underrun_stops_at_the_end_of_what_arrived_and_resumes() {
    let mut e = engine(PlanningMode::Lookahead);
    e.push(&line(1, [0.02, 0.0, 0.0], 0.04)).unwrap();
    e.push(&line(2, [0.02, 0.02, 0.0], 0.04)).unwrap();
    let mut samples = Vec::new();
    for _ in 0..3000 {
        samples.push(e.step(1.0));
    }
    let last = *samples.last().unwrap();
    assert_eq!(last.motion, Motion::Starved);
    assert_eq!(e.stats().underruns, 1);
    assert!((last.position - Vector3::new(0.02, 0.02, 0.0)).norm() < 1e-12, "stopped at {:?}", last.position);
    e.push(&line(3, [0.0, 0.02, 0.0], 0.04)).unwrap();
    let mut end = line(4, [0.0, 0.0, 0.0], 0.04);
    end.flags = SegmentFlags::LAST;
    e.push(&end).unwrap();
    samples.extend(run(&mut e, 10_000));
    let last = samples.last().unwrap();
    assert_eq!(last.motion, Motion::Finished);
    assert!(last.position.norm() < 1e-12);
    assert_eq!(e.stats().underruns, 1, "finishing is not an underrun");
    check_limits(&samples, e.config(), true);
}

#[test]
fn blends_stay_within_the_deviation_tolerance_and_keep_speed_on_curves() {
    // A circle of radius 5 mm in 0.4 mm chords, as slicers write rounded corners.
    let mut e = engine(PlanningMode::Lookahead);
    let n = 80;
    let r = 0.005;
    let mut pts = Vec::new();
    for k in 1..=n {
        let th = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
        pts.push([r * th.cos() - r, r * th.sin(), 0.0]);
    }
    for (i, p) in pts.iter().enumerate() {
        let mut s = line(i as u64 + 1, *p, 0.04);
        if i + 1 == pts.len() {
            s.flags = SegmentFlags::LAST;
        }
        e.push(&s).unwrap();
    }
    let samples = run(&mut e, 100_000);
    check_limits(&samples, e.config(), true);
    let tol = e.config().deviation_tolerance;
    for s in &samples {
        let radial = ((s.position.x + r).powi(2) + s.position.y.powi(2)).sqrt();
        // Chords sit inside the circle by at most r(1 − cos(π/n)); blends cut corners by ≤ tol.
        assert!(radial <= r + 1e-12 && radial >= r * (std::f64::consts::PI / n as f64).cos() - tol - 1e-12, "radius {radial}");
    }
    // Centripetal limit √(a_c·r) ≈ 0.12 m/s > feed, so the curve runs at the feed.
    let cruise = samples.iter().filter(|s| (s.speed - 0.04).abs() < 1e-9).count();
    assert!(cruise as f64 > 0.8 * samples.len() as f64, "only {cruise} of {} ticks at feed", samples.len());
    assert!(e.stats().blends >= (n - 2) as u64);
}

#[test]
fn arcs_run_as_true_arcs() {
    let mut e = engine(PlanningMode::Lookahead);
    // Full circle of radius 10 mm about (0.01, 0, 0), counter-clockwise about +z, then a helix turn.
    let mut arc = Segment {
        seq: 1,
        kind: SegmentKind::Arc,
        end: Vector3::zeros(),
        centre: Vector3::new(0.01, 0.0, 0.0),
        normal: Vector3::z(),
        sweep: 2.0 * std::f64::consts::PI,
        feed: 0.03,
        orientation: UnitQuaternion::identity(),
        ..Segment::default()
    };
    e.push(&arc).unwrap();
    arc.seq = 2;
    arc.end = Vector3::new(0.0, 0.0, 0.002);
    arc.flags = SegmentFlags::LAST;
    e.push(&arc).unwrap();
    let samples = run(&mut e, 100_000);
    check_limits(&samples, e.config(), true);
    for s in &samples {
        let radial = ((s.position.x - 0.01).powi(2) + s.position.y.powi(2)).sqrt();
        assert!((radial - 0.01).abs() < 1e-12, "off the circle by {}", radial - 0.01);
        // Velocity is tangent and has the path speed as its length.
        assert!(
            (s.velocity.norm() - s.speed * (1.0f64 + (0.002f64 / (2.0 * std::f64::consts::PI * 0.01)).powi(2)).sqrt().min(1.0 / 1.0)).abs()
                < 1e-9
                || s.seq == 2
        );
    }
    let last = samples.last().unwrap();
    assert!((last.position - Vector3::new(0.0, 0.0, 0.002)).norm() < 1e-12);
    let expected = 2.0 * std::f64::consts::PI * 0.01 + (std::f64::consts::TAU * 0.01f64).hypot(0.002);
    assert!((last.s - expected).abs() < 1e-12, "length {} vs {expected}", last.s);
}

#[test]
fn feed_override_and_speed_scale_slow_the_tool_along_the_path_within_limits() {
    let mut e = engine(PlanningMode::Lookahead);
    let mut s = line(1, [0.2, 0.0, 0.0], 0.1);
    s.flags = SegmentFlags::LAST;
    e.push(&s).unwrap();
    let mut samples = Vec::new();
    for _ in 0..300 {
        samples.push(e.step(1.0));
    }
    assert!((samples.last().unwrap().speed - 0.1).abs() < 1e-12);
    e.set_feed_override(0.5);
    for _ in 0..200 {
        samples.push(e.step(1.0));
    }
    assert!((samples.last().unwrap().speed - 0.05).abs() < 1e-12, "override: {}", samples.last().unwrap().speed);
    e.set_feed_override(1.0);
    for _ in 0..100 {
        samples.push(e.step(1.0));
    }
    // The CLIK reports it can follow only 60 %: the path slows (never leaves the line).
    for _ in 0..5 {
        samples.push(e.step(0.6));
    }
    for _ in 0..200 {
        samples.push(e.step(1.0));
    }
    let slowest = samples[600..].iter().map(|s| s.speed).fold(f64::INFINITY, f64::min);
    assert!(slowest < 0.061, "speed scale did not slow the path: {slowest}");
    samples.extend(run(&mut e, 100_000));
    check_limits(&samples, e.config(), true);
    for s in &samples {
        assert!(s.position.y.abs() < 1e-15 && s.position.z.abs() < 1e-15);
    }
    assert_eq!(samples.last().unwrap().motion, Motion::Finished);
    assert!((samples.last().unwrap().position.x - 0.2).abs() < 1e-12);
}

#[test]
fn bad_segments_are_refused_by_field_and_nothing_accepted_is_lost() {
    let mut e = engine(PlanningMode::Lookahead);
    e.push(&line(1, [0.01, 0.0, 0.0], 0.04)).unwrap();
    let mut bad = line(2, [f64::NAN, 0.0, 0.0], 0.04);
    assert!(matches!(e.push(&bad), Err(SegmentError::Invalid { field: "end", .. })));
    bad = line(2, [0.02, 0.0, 0.0], f64::INFINITY);
    assert!(matches!(e.push(&bad), Err(SegmentError::Invalid { field: "feed", .. })));
    bad = line(2, [0.02, 0.0, 0.0], 0.0);
    assert!(matches!(e.push(&bad), Err(SegmentError::Invalid { field: "feed", .. })), "F0 is refused");
    bad = line(1, [0.02, 0.0, 0.0], 0.04);
    assert!(matches!(e.push(&bad), Err(SegmentError::Invalid { field: "seq", .. })));
    let mut arc = Segment {
        seq: 2,
        kind: SegmentKind::Arc,
        end: Vector3::new(0.03, 0.0, 0.0),
        centre: Vector3::new(0.02, 0.0, 0.0),
        normal: Vector3::z(),
        sweep: 1.0,
        feed: 0.04,
        ..Segment::default()
    };
    assert!(matches!(e.push(&arc), Err(SegmentError::Invalid { field: "end", .. })), "end inconsistent with the sweep");
    arc.sweep = f64::NAN;
    assert!(matches!(e.push(&arc), Err(SegmentError::Invalid { field: "sweep", .. })));
    assert_eq!(e.stats().rejected, 6);
    // A zero-length move is skipped with a note.
    e.push(&line(3, [0.01, 0.0, 0.0], 0.04)).unwrap();
    assert_eq!(e.stats().skipped_zero_length, 1);
    assert_eq!(e.stats().last_skipped, Some(3));
    let mut last = line(4, [0.02, 0.0, 0.0], 0.04);
    last.flags = SegmentFlags::LAST;
    e.push(&last).unwrap();
    let samples = run(&mut e, 10_000);
    assert_eq!(samples.last().unwrap().motion, Motion::Finished);
    assert!((samples.last().unwrap().position.x - 0.02).abs() < 1e-12);
    assert!(samples.iter().all(|s| s.position.iter().all(|x| x.is_finite())));
}

#[test]
fn a_dwell_holds_for_its_duration_and_moves_its_filament() {
    let mut e = engine(PlanningMode::Lookahead);
    e.push(&line(1, [0.01, 0.0, 0.0], 0.04)).unwrap();
    let dwell = Segment {
        seq: 2,
        kind: SegmentKind::Dwell,
        end: Vector3::new(0.01, 0.0, 0.0),
        duration: 0.25,
        filament: -1e-3,
        ..Segment::default()
    };
    e.push(&dwell).unwrap();
    let mut last = line(3, [0.02, 0.0, 0.0], 0.04);
    last.flags = SegmentFlags::LAST;
    e.push(&last).unwrap();
    let samples = run(&mut e, 10_000);
    let dwelling: Vec<_> = samples.iter().filter(|s| s.motion == Motion::Dwelling).collect();
    assert!((dwelling.len() as i64 - 250).abs() <= 1, "{} dwelling ticks", dwelling.len());
    // Whole ticks inside the dwell move its rate; the ticks it begins or ends in, their share: in
    // all exactly its filament (a retraction and its prime cancel to the micrometre).
    assert!(dwelling.iter().all(|s| s.speed == 0.0 && s.dwell_filament_rate <= 0.0 && s.dwell_filament_rate >= -1e-3 / 0.25 - 1e-15));
    assert!(dwelling.iter().filter(|s| (s.dwell_filament_rate + 1e-3 / 0.25).abs() < 1e-12).count() >= 248);
    let moved: f64 = samples.iter().map(|s| s.dwell_filament_rate * DT).sum();
    assert!((moved + 1e-3).abs() < 1e-12, "the dwell moved {moved} m of filament");
    assert_eq!(samples.last().unwrap().motion, Motion::Finished);
}

#[test]
fn a_burst_of_ten_thousand_tiny_segments_is_absorbed_over_several_ticks() {
    let config = PathConfig { queue_capacity: 16_384, plan_budget: 2048, ..PathConfig::default() };
    let mut e = PathEngine::new(&config, DT, Vector3::zeros(), UnitQuaternion::identity()).unwrap();
    for k in 0..10_000u64 {
        // 0.1 mm chords of a gentle wave, the size of slicer output on fine curves.
        let t = (k + 1) as f64 * 1e-4;
        e.push(&line(k + 1, [t, 1e-3 * (t * 300.0).sin(), 0.0], 0.04)).unwrap();
    }
    let mut ticks_to_absorb = 0;
    let mut work_before = 0;
    let mut samples = Vec::new();
    while e.free_space() < 16_384 {
        samples.push(e.step(1.0));
        let work = e.stats().plan_work - work_before;
        work_before = e.stats().plan_work;
        // Each tick stays within the budget plus one segment's pass, which is atomic and bounded by
        // the pieces within one braking distance w(max_speed) of the change (2 pieces per segment).
        let horizon = 0.25f64.powi(2) / (2.0 * 3.0) + 0.25 * 3.0 / 100.0;
        let pieces_in_horizon = (2.0 * horizon / 1e-4) as u64 + 4;
        assert!(work <= config.plan_budget as u64 + pieces_in_horizon, "tick {ticks_to_absorb}: {work} junction updates");
        ticks_to_absorb += 1;
    }
    assert!(ticks_to_absorb >= 3, "absorbed in {ticks_to_absorb} ticks");
    samples.extend((0..2000).map(|_| e.step(1.0)));
    check_limits(&samples, e.config(), true);
    let cruising = samples.iter().filter(|s| s.speed > 0.039).count();
    println!(
        "{ticks_to_absorb} ticks to absorb; {cruising} of {} ticks at feed; last {:?}",
        samples.len(),
        samples.last().map(|s| (s.s, s.speed))
    );
    // The tool keeps cruising at the feed while the burst is taken in; it only stops at the end.
    assert!(cruising as f64 > 0.7 * samples.len() as f64, "it keeps cruising through the burst");
    assert!(samples.iter().all(|s| s.motion == Motion::Moving), "no stop while the burst is absorbed");
}

#[test]
fn same_input_gives_bit_identical_samples() {
    let go = || {
        let mut e = engine(PlanningMode::Lookahead);
        square(&mut e, 1, false);
        let mut out: Vec<PathSample> = (0..700).map(|k| e.step(if k == 300 { 0.8 } else { 1.0 })).collect();
        square(&mut e, 10, true);
        out.extend(run(&mut e, 10_000));
        out
    };
    let (a, b) = (go(), go());
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(format!("{x:?}"), format!("{y:?}"));
        assert_eq!(x.position.map(f64::to_bits), y.position.map(f64::to_bits));
    }
}

#[test]
fn extrusion_follows_the_path_speed_and_retracts_on_an_underrun() {
    let mut e = engine(PlanningMode::Lookahead);
    let mut s = line(1, [0.02, 0.0, 0.0], 0.04);
    s.filament = 0.8e-3;
    s.flags = SegmentFlags::EXTRUDE;
    e.push(&s).unwrap();
    let config = ExtruderConfig { pressure_advance: 0.05, ..ExtruderConfig::default() };
    let mut x = Extruder::new(&config, DT).unwrap();
    let mut retracting = 0;
    // The advance is K times the central difference of Ė over two ticks: Ë a tick ago, to within
    // what the jerk changes in half a tick.
    let flow = 0.8e-3 / 0.02;
    let tolerance = 0.05 * flow * PathConfig::default().max_jerk * DT;
    let mut before: Option<PathSample> = None;
    for _ in 0..1500 {
        let sample = e.step(1.0);
        let c = x.step(&sample);
        assert!((c.path_rate - flow * sample.speed).abs() < 1e-15, "Ė = ΔE/L·ṡ");
        if sample.motion == Motion::Moving
            && let Some(b) = before
        {
            let expected = flow * sample.speed + 0.05 * flow * b.path_acceleration;
            assert!((c.filament_rate - expected).abs() < tolerance, "pressure advance: {} against {expected}", c.filament_rate);
        }
        before = Some(sample);
        assert!((c.motor_speed - c.filament_rate / config.drive_wheel_radius).abs() < 1e-12, "ω = Ė/r_w");
        retracting += usize::from(sample.motion == Motion::Starved && c.filament_rate < 0.0);
    }
    // 1 mm at 35 mm/s: 29 ticks (28.6 rounded up).
    assert_eq!(retracting, 29, "retraction ticks");
    assert!((x.position() - (0.8e-3 - 1e-3)).abs() < 1e-12, "net filament {}", x.position());
    // Resume: the prime puts the filament back.
    let mut t = line(2, [0.03, 0.0, 0.0], 0.04);
    t.flags = SegmentFlags::TRAVEL.with(SegmentFlags::LAST);
    e.push(&t).unwrap();
    for _ in 0..1000 {
        let sample = e.step(1.0);
        let c = x.step(&sample);
        if sample.seq == 2 && sample.motion == Motion::Moving && !c.retracted && c.filament_rate > 0.0 {
            assert!(c.filament_rate <= config.retract_speed + 1e-12, "only the prime moves filament on a travel");
        }
    }
    assert!((x.position() - 0.8e-3).abs() < 1e-12, "travel extrudes nothing; prime restores: {}", x.position());
}

#[test]
fn a_programs_pressure_advance_replaces_the_configs_from_its_segment_on_clamped_to_the_maximum() {
    // Three extruding lines: the first with the config's K (0.05 s), the second with the program's
    // 0.1 s, the third asking 0.5 s, above max_pressure_advance (0.2 s).
    let config = ExtruderConfig { pressure_advance: 0.05, max_pressure_advance: 0.2, retract_length: 0.0, ..ExtruderConfig::default() };
    advances_seen(&config, [0.05, 0.1, 0.2]);
    // max_pressure_advance = 0 ignores the program: the config's K throughout (not none at all).
    advances_seen(&ExtruderConfig { max_pressure_advance: 0.0, ..config }, [0.05; 3]);
}

/// Runs the three lines of the test above through the extruder and checks the advance each applied.
fn advances_seen(config: &ExtruderConfig, advances: [f64; 3]) {
    let mut e = engine(PlanningMode::StopAndGo);
    let flow = 0.8e-3 / 0.02;
    for (k, (x, advance)) in [(0.02, None), (0.04, Some(0.1)), (0.06, Some(0.5))].into_iter().enumerate() {
        let mut s = line(k as u64 + 1, [x, 0.0, 0.0], 0.04);
        s.filament = 0.8e-3;
        s.flags = if k == 2 { SegmentFlags::EXTRUDE.with(SegmentFlags::LAST) } else { SegmentFlags::EXTRUDE };
        s.pressure_advance = advance;
        e.push(&s).unwrap();
    }
    let mut x = Extruder::new(config, DT).unwrap();
    let mut seen = [0usize; 3];
    // Stop-and-go plans trapezoids: the acceleration steps. Judged where it held over the two
    // ticks the difference spans.
    let mut before: [Option<PathSample>; 2] = [None, None];
    for _ in 0..5000 {
        let sample = e.step(1.0);
        let c = x.step(&sample);
        if sample.motion == Motion::Finished {
            break;
        }
        let [older, previous] = before;
        before = [previous, Some(sample)];
        let (Some(a), Some(b)) = (older, previous) else { continue };
        let steady = a.path_acceleration == b.path_acceleration && b.path_acceleration == sample.path_acceleration;
        if !steady || a.seq != sample.seq || b.motion != Motion::Moving || sample.motion != Motion::Moving || b.path_acceleration == 0.0 {
            continue;
        }
        let k = advances[sample.seq as usize - 1];
        let expected = flow * sample.speed + k * flow * b.path_acceleration;
        let tolerance = k * flow * PathConfig::default().max_jerk * DT;
        assert!(
            (c.filament_rate - expected).abs() < tolerance,
            "seq {}: K = {k} s: {} against {expected} (tolerance {tolerance}), a {} then {}",
            sample.seq,
            c.filament_rate,
            b.path_acceleration,
            sample.path_acceleration
        );
        seen[sample.seq as usize - 1] += 1;
    }
    assert!(seen.iter().all(|&n| n > 10), "every segment accelerated and braked: {seen:?}");
}

#[test]
fn an_inclined_bed_maps_points_and_keeps_the_nozzle_normal_to_it() {
    let alpha = 45f64.to_radians();
    let bed = BedTransform::new(&BedConfig { tilt: alpha, offset: [0.5, 0.0, 0.1], frame: None, mesh: None }).unwrap();
    let p = bed.point(&Vector3::new(0.0, 0.01, 0.0));
    assert!((p - Vector3::new(0.5, 0.01 * alpha.cos(), 0.1 + 0.01 * alpha.sin())).norm() < 1e-15);
    let nozzle = bed.tool_orientation() * Vector3::z();
    assert!((nozzle + bed.normal()).norm() < 1e-15, "tool z = −bed normal: {nozzle:?}");
    // A flat-bed segment's default orientation (nozzle down) is rotated with the bed.
    let s = Segment {
        orientation: UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
        ..line(1, [0.0, 0.01, 0.0], 0.04)
    };
    let mapped = bed.segment(&s);
    assert!((mapped.orientation * Vector3::z() + bed.normal()).norm() < 1e-15);
    assert!(BedTransform::new(&BedConfig { tilt: 2.0, offset: [0.0; 3], frame: None, mesh: None }).is_err());
}

/// Slic3r 1.3's cyl20 perimeter (short chords of an 8 mm circle, blended into large arcs) ending in
/// a travel that nearly reverses and another near-reversal (tests/data/gcode/slic3r13/
/// default_cyl20.gcode, lines 1185-1222), then three sub-0.2 mm moves that turn back and a travel.
/// The corners between them get blends of a few µm radius, capped at a few mm/s. The engine used to
/// reach them too fast: a chained brake aimed at a boundary's speed the braking bound did not
/// cover, the position plan then failed, and the forced brake (velocity interface, blind to
/// positions) entered the blend over its centripetal cap (52 m/s² of 3 here, 3.7 in the file).
#[test]
fn short_segments_into_a_near_reversal_keep_the_centripetal_limit_without_forced_brakes() {
    const MM: f64 = 1e-3;
    let (extrude, travel) = (4733.28 * MM / 60.0, 7800.0 * MM / 60.0);
    #[rustfmt::skip]
    let points: [(f64, f64, f64); 40] = [
        (94.161, 94.161, extrude), (94.738, 93.639, extrude), (95.363, 93.175, extrude), (96.030, 92.775, extrude),
        (96.733, 92.443, extrude), (97.466, 92.181, extrude), (98.221, 91.992, extrude), (98.990, 91.877, extrude),
        (99.772, 91.839, extrude), (100.544, 91.877, extrude), (101.314, 91.992, extrude), (102.069, 92.181, extrude),
        (102.801, 92.443, extrude), (103.505, 92.775, extrude), (104.172, 93.175, extrude), (104.797, 93.639, extrude),
        (105.373, 94.161, extrude), (105.896, 94.738, extrude), (106.359, 95.363, extrude), (106.759, 96.030, extrude),
        (107.092, 96.733, extrude), (107.354, 97.466, extrude), (107.543, 98.221, extrude), (107.657, 98.990, extrude),
        (107.696, 99.767, extrude), (107.657, 100.544, extrude), (107.543, 101.314, extrude), (107.354, 102.069, extrude),
        (107.092, 102.801, extrude), (106.759, 103.505, extrude), (106.359, 104.172, extrude), (105.896, 104.797, extrude),
        (105.373, 105.373, extrude), (107.897, 102.237, travel), (94.288, 105.883, extrude), (97.865, 107.968, travel),
        (98.012, 108.101, extrude), (97.950, 108.010, extrude), (97.951, 108.012, extrude), (90.0, 100.0, travel),
    ];
    let config = PathConfig::default();
    let start = Vector3::new(105.839 * MM, 105.839 * MM, 0.2 * MM);
    let mut e = PathEngine::new(&config, DT, start, UnitQuaternion::identity()).unwrap();
    for (i, &(x, y, feed)) in points.iter().enumerate() {
        let mut s = line(i as u64 + 1, [x * MM, y * MM, 0.2 * MM], feed);
        if i + 1 == points.len() {
            s.flags = SegmentFlags::LAST;
        }
        e.push(&s).unwrap();
    }
    let samples = run(&mut e, 200_000);
    assert_eq!(samples.last().unwrap().motion, Motion::Finished);
    check_limits(&samples, &config, true);
    for (i, s) in samples.iter().enumerate() {
        if s.speed > 1e-9 {
            // As strand-plan time measures it: the acceleration normal to the velocity.
            let t = s.velocity / s.speed;
            let normal = (s.acceleration - t * s.acceleration.dot(&t)).norm();
            assert!(
                normal <= config.centripetal_acceleration * (1.0 + 1e-6),
                "tick {i} (line {}): centripetal {normal} m/s² at {} m/s",
                s.source_line,
                s.speed
            );
        }
    }
    assert!(e.stats().forced_brakes <= 1, "{} forced brakes", e.stats().forced_brakes);
}

/// The three planning modes as the config files spell them (`mode = "rules-004"` was documented
/// in every config but refused: serde spelled the variant `rules004`).
#[test]
fn every_documented_planning_mode_loads() {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/default.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let documented = text.lines().find(|l| l.starts_with("mode = ")).expect("the [path] mode line");
    for (name, mode) in [
        ("stop-and-go", strand_core::PlanningMode::StopAndGo),
        ("rules-004", strand_core::PlanningMode::KnowledgeRules),
        ("lookahead", strand_core::PlanningMode::Lookahead),
    ] {
        assert!(documented.contains(&format!("\"{name}\"")), "{documented}");
        let cfg = strand::config::Config::load_with(&file, &[format!("path.mode={name}")]).unwrap();
        assert_eq!(cfg.path.mode, mode);
        assert_eq!(mode.name(), name);
    }
}

/// A re-plan from a state on the current trajectory never makes the move slower. rsruckig 3.0.1
/// can answer such a state with a valid profile far slower than the rest of the trajectory it
/// lies on (the orca square's first travel: a speed-scale dip while accelerating, then the cap's
/// recovery re-planned where the ramp meets the speed limit to the bit, and the move took 1.17 s
/// instead of 0.66 s; which start postures hit it depended on micro-radians). Here: a dip of the
/// CLIK's scale at each tick of the run-up, at eight depths a few 1e-5 apart. What a dip costs
/// depends on when it comes (the cap recovers in 25 % steps), but not on the fifth digit of its
/// depth: the durations at one tick may differ by a few ticks, never by a jump.
#[test]
fn a_replan_on_the_current_trajectory_never_slows_the_move() {
    let (mut worst_spread, mut worst) = (0usize, String::new());
    for dip_at in 20..160 {
        let mut ticks_by_depth = Vec::new();
        for k in 0..8 {
            let depth = 0.2 + k as f64 * 1.3e-5;
            let mut e = engine(PlanningMode::Lookahead);
            let mut s = line(1, [0.15, 0.0, 0.0], 0.5);
            s.flags = SegmentFlags::LAST;
            e.push(&s).unwrap();
            let mut ticks = 0usize;
            loop {
                let scale = if (dip_at..dip_at + 6).contains(&ticks) { depth } else { 1.0 };
                let sample = e.step(scale);
                ticks += 1;
                if sample.motion == Motion::Finished || ticks > 20_000 {
                    break;
                }
            }
            ticks_by_depth.push(ticks);
        }
        let spread = ticks_by_depth.iter().max().unwrap() - ticks_by_depth.iter().min().unwrap();
        if spread > worst_spread {
            worst_spread = spread;
            worst = format!("dip at tick {dip_at}: {ticks_by_depth:?} ticks");
        }
    }
    assert!(worst_spread <= 5, "{worst}");
}
