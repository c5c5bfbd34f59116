//! 5-axis G-code: the rotary words `A`/`B`/`C` mapped onto the external axes
//! (`GcodeOptions::rotary`) and the tool-direction dialect (`GcodeOptions::tool_direction`).
//! Exact numbers for rotary-only moves (dwells of the turn over F in degrees per minute), moves of
//! XYZ and rotary axes together, `G91` increments, `G92` offsets, sign and offset, unmapped words,
//! tool directions (modal, antiparallel), errors with line and column; property tests that random
//! 5-axis programs give segments that pass `Segment::check` and carry the axes an independent model
//! of the program expects, and that random bytes never panic with the options on.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_6, PI};
use std::io::Cursor;

use nalgebra::{Unit, UnitQuaternion, Vector3};
use proptest::prelude::*;
use strand_core::{Segment, SegmentKind};
use strand_job::gcode::{GcodeError, GcodeOptions, GcodeSegment, MAX_ANGLE, Parser, RotaryAxis, Warning, segment_length};

// ------------------------------------------------------------------------------------------------
// Helpers.
// ------------------------------------------------------------------------------------------------

const MM: f64 = 1e-3;
const DEG: f64 = PI / 180.0;

struct Parsed {
    segments: Vec<GcodeSegment>,
    warnings: Vec<Warning>,
    notes: Vec<Warning>,
}

fn try_parse_with(text: &str, options: GcodeOptions) -> Result<Parsed, GcodeError> {
    let mut parser = Parser::new(Cursor::new(text.as_bytes().to_vec()), "test.ngc", options);
    let segments = parser.by_ref().collect::<Result<Vec<_>, _>>()?;
    Ok(Parsed { segments, warnings: parser.warnings().to_vec(), notes: parser.notes().to_vec() })
}

fn parse_with(text: &str, options: GcodeOptions) -> Parsed {
    let parsed = try_parse_with(text, options).unwrap_or_else(|e| panic!("{e}"));
    for s in &parsed.segments {
        s.segment.check().unwrap_or_else(|e| panic!("line {}: {e}: {:?}", s.line, s.segment));
    }
    parsed
}

fn segments_with(text: &str, options: GcodeOptions) -> Vec<Segment> {
    parse_with(text, options).segments.into_iter().map(|s| s.segment).collect()
}

fn error_with(text: &str, options: GcodeOptions) -> GcodeError {
    match try_parse_with(text, options) {
        Ok(p) => panic!("expected an error from {text:?}, got {} segments", p.segments.len()),
        Err(e) => e,
    }
}

/// C mapped onto the first external axis, +1, no offset.
fn c_axis() -> GcodeOptions {
    GcodeOptions::default().with_rotary(&["C"], &[], &[]).unwrap()
}

/// A (−1, +0.1 rad) and C (+1, −0.2 rad): a tilt-and-turn positioner.
fn a_and_c() -> GcodeOptions {
    GcodeOptions::default().with_rotary(&["A".to_string(), "C".to_string()], &[-1.0, 1.0], &[0.1, -0.2]).unwrap()
}

fn with_tool_direction() -> GcodeOptions {
    GcodeOptions { tool_direction: true, ..GcodeOptions::default() }
}

fn assert_close(actual: f64, expected: f64, tolerance: f64, what: &str) {
    assert!((actual - expected).abs() <= tolerance, "{what}: {actual} vs {expected} (tolerance {tolerance})");
}

fn assert_axes(segment: &Segment, expected: [f64; 2], what: &str) {
    let axes = segment.axes.unwrap_or_else(|| panic!("{what}: no axes on {segment:?}"));
    for k in 0..2 {
        assert_close(axes[k], expected[k], 1e-12, &format!("{what}: axis {k}"));
    }
}

fn assert_vec_close(actual: &Vector3<f64>, expected: &Vector3<f64>, what: &str) {
    assert!((actual - expected).norm() < 1e-12, "{what}: {actual:?} vs {expected:?}");
}

fn note<'a>(list: &'a [Warning], kind: &str) -> &'a Warning {
    list.iter().find(|w| w.kind == kind).unwrap_or_else(|| panic!("no {kind:?} in {list:#?}"))
}

/// The nozzle direction (tool z) of a segment.
fn nozzle(s: &Segment) -> Vector3<f64> {
    s.orientation * Vector3::z()
}

// ------------------------------------------------------------------------------------------------
// Rotary words.
// ------------------------------------------------------------------------------------------------

#[test]
fn a_c_only_turn_is_a_dwell_of_the_angle_over_f_in_degrees_per_minute() {
    let parsed = parse_with("G1 X10 F600\nG1 C90 F1800\nG4 P100\n", c_axis());
    let s: Vec<Segment> = parsed.segments.iter().map(|g| g.segment).collect();
    assert_eq!(s.len(), 3);
    assert_eq!((s[0].kind, s[0].axes), (SegmentKind::Line, None), "no axes before the first rotary word");
    assert_eq!(s[1].kind, SegmentKind::Dwell);
    assert_eq!(s[1].duration, 3.0, "90° at 1800°/min");
    assert_eq!(s[1].filament, 0.0);
    assert_eq!(s[1].end, Vector3::new(10.0 * MM, 0.0, 0.0));
    assert_axes(&s[1], [FRAC_PI_2, 0.0], "C90");
    assert_eq!(s[2].kind, SegmentKind::Dwell);
    assert_axes(&s[2], [FRAC_PI_2, 0.0], "a G4 after the turn carries the axes");
    assert_eq!(note(&parsed.notes, "rotary only").count, 1);
    // With E: a dwell that turns the table and pushes filament; relative E.
    let s = segments_with("M83\nG1 X10 F600\nG1 C-45 E2 F900\n", c_axis());
    assert_eq!((s[1].kind, s[1].duration, s[1].filament), (SegmentKind::Dwell, 3.0, 2.0 * MM));
    assert_axes(&s[1], [-45.0 * DEG, 0.0], "C-45");
    // Under G20 lengths are inches, F on a rotary-only move is still degrees per minute.
    let s = segments_with("G20\nG1 X1 F10\nG1 C30\n", c_axis());
    assert_eq!(s[0].feed, 10.0 * 0.0254 / 60.0);
    assert_close(s[1].duration, 180.0, 1e-12, "30° at 10°/min");
    // The feed percentage applies.
    let s = segments_with("M220 S50\nG1 C90 F1800\n", c_axis());
    assert_eq!(s[0].duration, 6.0);
    // Both axes turn: the larger turn sets the time.
    let s = segments_with("G1 A10 C-60 F600\n", a_and_c());
    assert_eq!(s[0].duration, 6.0);
}

#[test]
fn a_rapid_turn_runs_at_90_degrees_per_second_unless_a_g0_line_gave_f() {
    let s = segments_with("G0 C90\n", c_axis());
    assert_eq!((s[0].kind, s[0].duration), (SegmentKind::Dwell, 1.0));
    // The modal F of a G1 is not a rapid's.
    let s = segments_with("G1 X1 F600\nG0 C180\n", c_axis());
    assert_eq!(s[1].duration, 2.0);
    // An F on a G0 line is.
    let s = segments_with("G0 X1 F3600\nG1 X2 F600\nG0 C90\n", c_axis());
    assert_eq!(s[2].duration, 1.5);
}

#[test]
fn a_move_of_xyz_and_rotary_axes_is_one_line_or_arc_carrying_the_axes() {
    let s = segments_with("G1 X10 C90 F600\nG1 X20\nG2 X10 Y0 I-5 J0 C180\nG1 Y5 C0 E1\n", c_axis());
    assert_eq!(s.len(), 4);
    assert_eq!((s[0].kind, s[0].end, s[0].feed), (SegmentKind::Line, Vector3::new(10.0 * MM, 0.0, 0.0), 10.0 * MM));
    assert_axes(&s[0], [FRAC_PI_2, 0.0], "X10 C90");
    assert_axes(&s[1], [FRAC_PI_2, 0.0], "X20 keeps C");
    assert_eq!(s[2].kind, SegmentKind::Arc);
    assert_axes(&s[2], [PI, 0.0], "arc with C180");
    assert_close(segment_length(&s[1].end, &s[2]), 5.0 * MM * PI, 1e-15, "half circle");
    assert_eq!(s[3].kind, SegmentKind::Line);
    assert_axes(&s[3], [0.0, 0.0], "C0");
    // A rotary word that does not change the axis on a zero-length move: skipped as before.
    let parsed = parse_with("G1 X1 C10 F600\nG1 X1 C10\n", c_axis());
    assert_eq!(parsed.segments.len(), 1);
    assert_eq!(note(&parsed.notes, "zero-length").count, 1);
    // Axis words on a line with the modal motion.
    let s = segments_with("G1 F600\nC90\nX1 C0\n", c_axis());
    assert_eq!((s[0].kind, s[1].kind), (SegmentKind::Dwell, SegmentKind::Line));
    assert_axes(&s[0], [FRAC_PI_2, 0.0], "modal C90");
}

#[test]
fn g91_turns_by_increments_and_g90_returns_to_absolute() {
    let s = segments_with("G91\nG1 C30 F600\nG1 C30\nG1 X1 C-90\nG90\nG1 C10\n", c_axis());
    let expected = [30.0, 60.0, -30.0, 10.0];
    assert_eq!(s.len(), 4);
    for (segment, degrees) in s.iter().zip(expected) {
        assert_axes(segment, [degrees * DEG, 0.0], &format!("C at {degrees}°"));
    }
    assert_eq!(s[0].duration, 3.0, "30° at 600°/min");
}

#[test]
fn g92_sets_the_rotary_program_offset_like_xyz() {
    // G92 C0 at 90°: C90 is then 180° of the axis.
    let s = segments_with("G1 C90 F600\nG92 C0\nG1 C90\nG92.1\nG1 C45\n", c_axis());
    assert_axes(&s[1], [PI, 0.0], "C90 after G92 C0 at 90°");
    assert_axes(&s[2], [45.0 * DEG, 0.0], "G92.1 clears the offset");
    // G92 without words zeroes every axis, rotary ones included.
    let s = segments_with("G1 X1 C45 F600\nG92\nG1 X1 C10\n", c_axis());
    assert_axes(&s[1], [55.0 * DEG, 0.0], "C10 after G92 at 45°");
    assert_eq!(s[1].end, Vector3::new(2.0 * MM, 0.0, 0.0));
    // A G92 C alone leaves XYZ alone; in G91 the offset does not matter.
    let s = segments_with("G1 X5 C20 F600\nG92 C100\nG1 X6\nG91\nG1 C10\n", c_axis());
    assert_eq!(s[1].end, Vector3::new(6.0 * MM, 0.0, 0.0));
    assert_axes(&s[1], [20.0 * DEG, 0.0], "G92 does not move the axis");
    assert_axes(&s[2], [30.0 * DEG, 0.0], "G91 C10 from 20°");
    // G92 C without a number: left unchanged, with a note.
    let parsed = parse_with("G1 C20 F600\nG92 C\nG1 C30\n", c_axis());
    assert_axes(&parsed.segments[1].segment, [30.0 * DEG, 0.0], "bare G92 C");
    assert_eq!(note(&parsed.notes, "G92 C").line, 2);
    // G92 C before any move with C does not make segments carry axes.
    let s = segments_with("G92 C10\nG1 X1 F600\nG1 C20\n", c_axis());
    assert_eq!(s[0].axes, None);
    assert_axes(&s[1], [10.0 * DEG, 0.0], "C20 with the axis at 0 = C10");
    // Homing is not acted on, for rotary words either: the axis stays where it is.
    let parsed = parse_with("G1 C90 F600\nG28 C0\nG1 C90\n", c_axis());
    assert_eq!(parsed.segments.len(), 1);
    assert!(parsed.warnings.iter().any(|w| w.kind == "G28"));
}

#[test]
fn sign_and_offset_map_each_word_onto_its_axis() {
    let s = segments_with("G1 A30 F600\nG1 C90\nG1 X1 A0 C0\n", a_and_c());
    assert_axes(&s[0], [-30.0 * DEG + 0.1, -0.2], "A30: −1 · 30° + 0.1, C at 0° = −0.2");
    assert_axes(&s[1], [-FRAC_PI_6 + 0.1, FRAC_PI_2 - 0.2], "C90");
    assert_axes(&s[2], [0.1, -0.2], "both at 0°");
    // An entry without a word stays 0; the word may drive the second axis alone.
    let options = GcodeOptions { rotary: [None, Some(RotaryAxis { word: 'B', sign: -1.0, offset: 0.0 })], ..GcodeOptions::default() };
    let s = segments_with("G1 B45 F600\n", options);
    assert_axes(&s[0], [0.0, -45.0 * DEG], "B on the second axis");
    // Words are read in either case.
    let s = segments_with("g1 c90 f600\n", c_axis());
    assert_axes(&s[0], [FRAC_PI_2, 0.0], "lower case");
}

#[test]
fn unmapped_rotary_words_keep_todays_error() {
    for (options, program, column, letter) in [
        (GcodeOptions::default(), "F60\nG1 X1 C5", 7, 'C'),
        (GcodeOptions::default(), "F60\nG1 X1 A5", 7, 'A'),
        (c_axis(), "F60\nG1 X1 A5", 7, 'A'),
        (c_axis(), "F60\nG1 X1 C5 B5", 10, 'B'),
        (a_and_c(), "F60\nG1 B5", 4, 'B'),
    ] {
        let e = error_with(program, options);
        assert_eq!((e.line, e.column, e.message.clone()), (2, column, format!("unsupported axis word {letter}")), "{program:?}");
    }
    // An M-code's words are its parameters, mapped or not.
    let parsed = parse_with("M117 C5\nM486 A1 C2\nG1 X1 F60\n", c_axis());
    assert_eq!(parsed.segments.len(), 1);
    assert_eq!(parsed.segments[0].segment.axes, None);
}

#[test]
fn rotary_errors_name_line_column_and_cause() {
    let cases: Vec<(&str, usize, usize, &str)> = vec![
        ("G1 C1000001 F60", 1, 4, "C1000001: an angle beyond ±1e6° (degrees)"),
        ("G1 F60\nG92 C-2000000", 2, 5, "C-2000000: an angle beyond"),
        ("G91\nG1 C900000 F60\nG1 C900000", 3, 4, "C900000: the axis would be at 1800000°, beyond ±1e6°"),
        ("G1 C90 F0.0001", 1, 8, "G1 turns the rotary axes alone by 90° at F0.0001 (degrees per minute on such a move)"),
        ("G1 X1 F0.0001\nG1 C90", 2, 1, "not in (0, 1e6) s"),
        ("G1 C F60", 1, 4, "C without a number"),
        ("G1 C\"x\" F60", 1, 4, "C needs a number, not a string"),
        ("G1 C90", 1, 1, "G1 with no feed rate"),
        ("C90", 1, 1, "axis words but no motion mode"),
        ("G92 C10 G1", 1, 9, "G1 and G92 on one line both use the axis words"),
    ];
    for (program, line, column, message) in cases {
        let e = error_with(program, c_axis());
        assert_eq!((e.line, e.column), (line, column), "{program:?}: {e}");
        assert!(e.message.contains(message), "{program:?}: {e}");
        assert_eq!(e.to_string(), format!("test.ngc:{line}:{column}: {}", e.message));
    }
    // 10⁶ degrees itself is accepted.
    let s = segments_with(&format!("G0 C{MAX_ANGLE}\n"), c_axis());
    assert_close(s[0].duration, MAX_ANGLE / 90.0, 1e-9, "10⁶° at 90°/s");
}

#[test]
fn invalid_rotary_options_are_the_first_error() {
    let bad = [
        (RotaryAxis { word: 'D', sign: 1.0, offset: 0.0 }, "gcode_words: 'D' is not a rotary word (A, B or C)"),
        (RotaryAxis { word: 'C', sign: 0.5, offset: 0.0 }, "gcode_signs: 0.5 (for C) is not +1 or -1"),
        (RotaryAxis { word: 'C', sign: 1.0, offset: f64::INFINITY }, "gcode_offsets: inf rad (for C) is not finite within ±1e6 rad"),
    ];
    for (axis, message) in bad {
        let options = GcodeOptions { rotary: [Some(axis), None], ..GcodeOptions::default() };
        let e = error_with("G1 X1 F60\n", options);
        assert_eq!((e.line, e.column), (0, 0));
        assert_eq!(e.message, format!("invalid options: rotary words: {message}"));
    }
    let twice = RotaryAxis { word: 'C', sign: 1.0, offset: 0.0 };
    let e = error_with("", GcodeOptions { rotary: [Some(twice), Some(twice)], ..GcodeOptions::default() });
    assert!(e.message.ends_with("gcode_words: C given twice: one word drives one axis"), "{e}");
    // The config keys by name.
    let e = GcodeOptions::default().with_rotary(&["C", "X"], &[], &[]).unwrap_err();
    assert_eq!((e.key, e.to_string().as_str()), ("gcode_words", "gcode_words: \"X\" is not a rotary word (A, B or C)"));
    let e = GcodeOptions::default().with_rotary(&["C"], &[-2.0], &[]).unwrap_err();
    assert_eq!(e.key, "gcode_signs");
    let e = GcodeOptions::default().with_rotary(&["C"], &[1.0], &[1.0, 2.0]).unwrap_err();
    assert_eq!(e.key, "gcode_offsets");
}

#[test]
fn every_dwell_the_parser_makes_passes_segment_check() {
    // Durations the path engine would refuse (≥ 10⁶ s, or 0 while moving filament) are errors at
    // the word that asked for them, rotary or not.
    for (program, line, column, message) in [
        ("G4 S1000000", 1, 1, "G4 dwell time: 1000000 s is not in [0, 1e6) s"),
        ("G1 X1 F0.001\nG1 E1000", 2, 4, "extruder-only move: 60000000 s is not in (0, 1e6) s"),
        ("M203 E0.000001\nG1 C1 E10 F600", 2, 11, "rotary move with filament (after M203 E)"),
    ] {
        let e = error_with(program, c_axis());
        assert_eq!((e.line, e.column), (line, column), "{program:?}: {e}");
        assert!(e.message.contains(message), "{program:?}: {e}");
    }
    let s = segments_with("G4 S999999\nG0 C-180 E1\n", c_axis());
    assert!(s.iter().all(|s| s.check().is_ok()));
}

// ------------------------------------------------------------------------------------------------
// Tool direction.
// ------------------------------------------------------------------------------------------------

#[test]
fn i_j_k_on_a_line_point_the_nozzle_against_them_by_the_shortest_turn() {
    let default = GcodeOptions::default().orientation;
    let s = segments_with("G1 X10 I0 J0 K1 F600\nG1 X20 I2 J0 K0\nG1 X30\nG0 X40 I0 J-3 K4\n", with_tool_direction());
    assert_eq!(s[0].orientation, default, "straight up: the default nozzle-down orientation");
    assert_vec_close(&nozzle(&s[1]), &Vector3::new(-1.0, 0.0, 0.0), "I2: nozzle along −x");
    assert_close(s[1].orientation.angle_to(&default), FRAC_PI_2, 1e-12, "the shortest turn from nozzle-down to sideways");
    // The turn is about the axis normal to both nozzle directions: the tool's roll is kept.
    let turn = s[1].orientation * default.inverse();
    let axis = turn.axis().unwrap();
    assert_close(axis.dot(&Vector3::y()).abs(), 1.0, 1e-12, "turned about y");
    assert_eq!(s[2].orientation, s[1].orientation, "modal");
    assert_vec_close(&nozzle(&s[3]), &Vector3::new(0.0, 0.6, -0.8), "J-3 K4, normalised, negated");
    assert_close(s[3].orientation.angle_to(&default), (0.8f64).acos(), 1e-12, "shortest turn from nozzle-down");
    // Any length: K5 is K1.
    let s = segments_with("G1 X1 I0 J0 K5 F600\n", with_tool_direction());
    assert_eq!(s[0].orientation, default);
}

#[test]
fn a_nozzle_pointing_straight_up_turns_half_a_turn_about_the_tool_x_axis() {
    let default = GcodeOptions::default().orientation;
    let s = segments_with("G1 X1 I0 J0 K-1 F600\n", with_tool_direction());
    assert_vec_close(&nozzle(&s[0]), &Vector3::z(), "nozzle up");
    let expected = UnitQuaternion::from_axis_angle(&Unit::new_normalize(default * Vector3::x()), PI) * default;
    assert!(s[0].orientation.angle_to(&expected) < 1e-12, "{:?} vs {expected:?}", s[0].orientation);
    // From another base orientation (nozzle up, +z), the same rule: π about its own x axis.
    let options = GcodeOptions { orientation: UnitQuaternion::identity(), ..with_tool_direction() };
    let s = segments_with("G1 X1 I0 J0 K1 F600\n", options.clone());
    assert!(s[0].orientation.angle_to(&UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI)) < 1e-12);
    assert_vec_close(&nozzle(&s[0]), &-Vector3::z(), "nozzle reversed");
    // Within 1e-9 rad of straight against the base, the same half turn (the shortest turn's axis is
    // noise there); beyond it, the shortest turn.
    let s = segments_with("G1 X1 I0.000000000001 J0 K1 F600\nG1 X2 I0 J-0.001 K1\n", options);
    assert!(s[0].orientation.angle_to(&UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI)) < 1e-9);
    let turned = s[1].orientation * Vector3::x();
    assert_vec_close(&turned, &Vector3::x(), "the shortest turn is about x: x stays");
    assert!((nozzle(&s[1]) - Vector3::new(0.0, 0.001, -1.0).normalize()).norm() < 1e-12);
}

#[test]
fn arcs_read_i_j_k_as_centres_and_keep_the_tool_direction() {
    let s = segments_with("G1 X10 I1 J0 K0 F600\nG2 X0 Y0 I-5 J0\nG4 P10\n", with_tool_direction());
    assert_eq!(s[1].kind, SegmentKind::Arc);
    assert_vec_close(&s[1].centre, &Vector3::new(5.0 * MM, 0.0, 0.0), "I-5 is the centre offset");
    assert_eq!(s[1].orientation, s[0].orientation, "modal through the arc");
    assert_eq!(s[2].orientation, s[0].orientation, "and the dwell");
}

#[test]
fn a_direction_without_a_move_waits_for_the_next_line() {
    let default = GcodeOptions::default().orientation;
    let parsed = parse_with("G1 X1 F600\nG1 I1 J0 K0\nG4 P10\nG1 X2\n", with_tool_direction());
    let s: Vec<Segment> = parsed.segments.iter().map(|g| g.segment).collect();
    assert_eq!(s.len(), 3);
    assert_eq!(s[1].kind, SegmentKind::Dwell);
    assert_eq!(s[1].orientation, default, "a dwell keeps the orientation the tool has");
    assert_vec_close(&nozzle(&s[2]), &-Vector3::x(), "the next line turns the tool");
    assert_eq!(note(&parsed.notes, "tool direction without a move").line, 2);
    // A rotary-only move with a direction: the dwell keeps the tool as it is.
    let options = GcodeOptions { tool_direction: true, ..c_axis() };
    let s = segments_with("G1 X1 F600\nG1 C90 I1 J0 K0\nG1 X2\n", options);
    assert_eq!((s[1].kind, s[1].orientation), (SegmentKind::Dwell, default));
    assert_vec_close(&nozzle(&s[2]), &-Vector3::x(), "then the line");
}

#[test]
fn tool_direction_errors_and_the_default_dialect() {
    for (program, line, column, message) in [
        ("G1 X1 I0 J0 K0 F60", 1, 7, "tool direction I0 J0 K0 is not a direction"),
        ("F60\nG1 X1\nX2 J0", 3, 4, "tool direction I0 J0 K0 is not a direction"),
        ("G1 X1 I F60", 1, 7, "I without a number"),
    ] {
        let e = error_with(program, with_tool_direction());
        assert_eq!((e.line, e.column), (line, column), "{program:?}: {e}");
        assert!(e.message.contains(message), "{program:?}: {e}");
    }
    // Off (the default), I J K on a line are words not acted on, as before.
    let parsed = parse_with("G1 X1 I1 J2 K3 F60\n", GcodeOptions::default());
    assert_eq!(parsed.segments[0].segment.orientation, GcodeOptions::default().orientation);
    assert!(parsed.warnings.iter().any(|w| w.kind == "word I"), "{:?}", parsed.warnings);
}

// ------------------------------------------------------------------------------------------------
// Properties.
// ------------------------------------------------------------------------------------------------

/// One line of a random 5-axis program.
#[derive(Clone, Debug)]
enum Line {
    /// G0 (true) or G1 with optional X Y Z A B C E F words (mm, degrees, mm/min or degrees/min).
    Move {
        rapid: bool,
        words: Vec<(char, f64)>,
    },
    Absolute(bool),
    /// G92 with optional A and C.
    SetPosition(Vec<(char, f64)>),
}

fn line_strategy() -> impl Strategy<Value = Line> {
    let word = prop_oneof![
        (proptest::sample::select(vec!['X', 'Y', 'Z']), -100.0f64..100.0),
        (proptest::sample::select(vec!['A', 'C']), -720.0f64..720.0),
        (Just('B'), -10.0f64..10.0),
        (Just('E'), -5.0f64..5.0),
        (Just('F'), 60.0f64..6000.0),
    ];
    prop_oneof![
        8 => (any::<bool>(), proptest::collection::vec(word, 0..6)).prop_map(|(rapid, words)| Line::Move { rapid, words }),
        1 => any::<bool>().prop_map(Line::Absolute),
        1 => proptest::collection::vec((proptest::sample::select(vec!['A', 'C']), -360.0f64..360.0), 0..3).prop_map(Line::SetPosition),
    ]
}

/// Writes the program (rounded to 3 decimals, as written) and the values as the parser reads them.
fn render(lines: &[Line]) -> (String, Vec<Line>) {
    let round = |v: f64| format!("{v:.3}").parse::<f64>().unwrap();
    let words = |words: &[(char, f64)]| -> (String, Vec<(char, f64)>) {
        let mut seen = String::new();
        let mut text = String::new();
        let mut read = Vec::new();
        for (letter, value) in words {
            if seen.contains(*letter) {
                continue;
            }
            seen.push(*letter);
            text.push_str(&format!(" {letter}{value:.3}"));
            read.push((*letter, round(*value)));
        }
        (text, read)
    };
    let mut text = String::from("F1000\n");
    let mut read = Vec::new();
    for line in lines {
        match line {
            Line::Move { rapid, words: w } => {
                let (t, r) = words(w);
                text.push_str(&format!("{}{t}\n", if *rapid { "G0" } else { "G1" }));
                read.push(Line::Move { rapid: *rapid, words: r });
            }
            Line::Absolute(absolute) => {
                text.push_str(if *absolute { "G90\n" } else { "G91\n" });
                read.push(line.clone());
            }
            Line::SetPosition(w) => {
                let (t, r) = words(w);
                // Without words G92 also zeroes XYZ and E: that is tested above; keep it to A and C.
                if r.is_empty() {
                    text.push_str("G90\n");
                    read.push(Line::Absolute(true));
                } else {
                    text.push_str(&format!("G92{t}\n"));
                    read.push(Line::SetPosition(r));
                }
            }
        }
    }
    (text, read)
}

/// The model: A drives axis 0 with sign −1 and offset 0.3 rad, C axis 1 with +1 and 0. Returns, per
/// program line (1-based, the `F1000` first), the axes segments from that line must carry, and the
/// line of the first `B` (unmapped: an error), if any.
fn expected_axes(lines: &[Line]) -> (Vec<Option<[f64; 2]>>, Option<usize>) {
    let mut absolute = true;
    let mut machine = [0.0f64; 2];
    let mut offset = [0.0f64; 2];
    let mut used = false;
    let mut out = vec![None];
    let index = |letter: char| if letter == 'A' { 0 } else { 1 };
    for (k, line) in lines.iter().enumerate() {
        match line {
            Line::Move { words, .. } => {
                for (letter, value) in words.iter().filter(|(l, _)| matches!(l, 'A' | 'C')) {
                    let i = index(*letter);
                    machine[i] = if absolute { value + offset[i] } else { machine[i] + value };
                    used = true;
                }
                if words.iter().any(|(l, _)| *l == 'B') {
                    // The move runs, then the unused B is the error.
                    out.push(used.then(|| [-machine[0] * DEG + 0.3, machine[1] * DEG]));
                    return (out, Some(k + 2));
                }
            }
            Line::Absolute(a) => absolute = *a,
            Line::SetPosition(words) => {
                for (letter, value) in words {
                    let i = index(*letter);
                    offset[i] = machine[i] - value;
                }
            }
        }
        out.push(used.then(|| [-machine[0] * DEG + 0.3, machine[1] * DEG]));
    }
    (out, None)
}

fn rotary_everything() -> GcodeOptions {
    GcodeOptions { tool_direction: true, ..GcodeOptions::default().with_rotary(&["A", "C"], &[-1.0, 1.0], &[0.3, 0.0]).unwrap() }
}

/// Runs any bytes with the 5-axis options on: no panic, and every segment passes `Segment::check`.
fn run_to_end(bytes: Vec<u8>) {
    let parser = Parser::new(Cursor::new(bytes), "fuzz", rotary_everything());
    for g in parser.flatten().map(|s| s.segment) {
        g.check().unwrap_or_else(|e| panic!("{e}: {g:?}"));
        assert!(segment_length(&Vector3::zeros(), &g).is_finite());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn random_five_axis_programs_carry_the_expected_axes(lines in proptest::collection::vec(line_strategy(), 0..40)) {
        let (text, read) = render(&lines);
        let (expected, b_line) = expected_axes(&read);
        let options = GcodeOptions::default().with_rotary(&["A", "C"], &[-1.0, 1.0], &[0.3, 0.0]).unwrap();
        let mut parser = Parser::new(Cursor::new(text.clone().into_bytes()), "p.ngc", options);
        let mut error = None;
        for item in parser.by_ref() {
            match item {
                Ok(g) => {
                    prop_assert!(g.segment.check().is_ok(), "line {}: {:?}: {:?}\n{text}", g.line, g.segment.check(), g.segment);
                    let want = expected[g.line - 1];
                    match (g.segment.axes, want) {
                        (None, None) => {}
                        (Some(got), Some(want)) => {
                            for k in 0..2 {
                                prop_assert!((got[k] - want[k]).abs() < 1e-9, "line {}: axes {got:?} vs {want:?}\n{text}", g.line);
                            }
                        }
                        (got, want) => prop_assert!(false, "line {}: axes {got:?} vs {want:?}\n{text}", g.line),
                    }
                }
                Err(e) => error = Some(e),
            }
        }
        match (b_line, error) {
            (None, None) => {}
            (Some(line), Some(e)) => {
                prop_assert_eq!(e.line, line, "{}\n{}", e, text);
                prop_assert_eq!(e.message, "unsupported axis word B".to_string());
            }
            (b_line, error) => prop_assert!(false, "B on line {b_line:?}, error {error:?}\n{text}"),
        }
    }

    #[test]
    fn random_bytes_with_rotary_options_never_panic(
        lines in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..60), 0..20)
    ) {
        run_to_end(lines.join(&b'\n'));
    }

    #[test]
    fn random_five_axis_like_lines_never_panic(
        words in proptest::collection::vec(
            (proptest::sample::select(b"GMXYZABCEIJKRPFSTN;( )*%#".to_vec()), -3.0e3f64..3.0e3, 0u8..4),
            0..80,
        )
    ) {
        run_to_end(strand_testkit::gcode_from_words(&words));
    }
}
