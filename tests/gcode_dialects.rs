//! G-code dialects: what printer firmwares (Marlin, RepRapFirmware, Klipper) and slicers (Cura,
//! PrusaSlicer, OrcaSlicer, Bambu Studio, Simplify3D) write beyond RS274/NGC, with numbers: bare axis
//! flags, firmware retraction, feed and flow overrides, velocity limits honoured and other limits
//! recorded, single-tool T codes, free-text and extended commands, slicer tags, dwell units per
//! dialect, positions out of range; the hand-made Orca, Simplify3D and Cura samples parse end to end;
//! no panic and a located error on random slicer-like input.

use std::io::Cursor;
use std::path::PathBuf;

use proptest::prelude::*;
use strand_core::{Segment, SegmentFlags, SegmentKind};
use strand_job::gcode::{Dialect, FirmwareRetraction, GcodeError, GcodeOptions, GcodeSegment, Parser, ProgramLimits, Warning, parse_file};

const MM: f64 = 1e-3;

struct Parsed {
    segments: Vec<GcodeSegment>,
    warnings: Vec<Warning>,
    notes: Vec<Warning>,
    limits: ProgramLimits,
}

fn try_parse_with(text: &str, options: GcodeOptions) -> Result<Parsed, GcodeError> {
    let mut parser = Parser::new(Cursor::new(text.as_bytes().to_vec()), "test.gcode", options);
    let segments = parser.by_ref().collect::<Result<Vec<_>, _>>()?;
    Ok(Parsed { segments, warnings: parser.warnings().to_vec(), notes: parser.notes().to_vec(), limits: *parser.program_limits() })
}

fn parse_with(text: &str, options: GcodeOptions) -> Parsed {
    try_parse_with(text, options).unwrap_or_else(|e| panic!("{e}"))
}

fn parse(text: &str) -> Parsed {
    parse_with(text, GcodeOptions::default())
}

fn segments(text: &str) -> Vec<Segment> {
    parse(text).segments.into_iter().map(|s| s.segment).collect()
}

fn error_with(text: &str, options: GcodeOptions) -> GcodeError {
    match try_parse_with(text, options) {
        Ok(_) => panic!("{text:?} parsed without error"),
        Err(e) => e,
    }
}

fn error(text: &str) -> GcodeError {
    error_with(text, GcodeOptions::default())
}

fn rs274() -> GcodeOptions {
    GcodeOptions { dialect: Dialect::Rs274ngc, ..GcodeOptions::default() }
}

fn find<'a>(list: &'a [Warning], kind: &str) -> &'a Warning {
    list.iter().find(|w| w.kind == kind).unwrap_or_else(|| panic!("no {kind:?} in {list:#?}"))
}

fn has(list: &[Warning], kind: &str) -> bool {
    list.iter().any(|w| w.kind == kind)
}

fn close(actual: f64, expected: f64, what: &str) {
    assert!((actual - expected).abs() <= 1e-12 * expected.abs().max(1.0), "{what}: {actual} vs {expected}");
}

fn corpus(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/gcode").join(name)
}

// ------------------------------------------------------------------------------------------------
// Bare axis flags.
// ------------------------------------------------------------------------------------------------

#[test]
fn bare_axis_flags_are_accepted_on_codes_that_take_them() {
    // Cura's default end code, Marlin's homing and motors-off with axis flags.
    let parsed = parse("G1 X10 E1 F600\nM84 X Y E ;Disable all steppers but Z\nG28 X Y\nM18 E\nG29 A\nM84 X Y E\n");
    assert_eq!(parsed.segments.len(), 1, "flags are parameters, not moves");
    let m84 = find(&parsed.warnings, "M84");
    assert_eq!((m84.line, m84.column, m84.count), (2, 1, 2));
    assert_eq!(find(&parsed.warnings, "G28").line, 3);
    assert_eq!(find(&parsed.warnings, "M18").line, 4);
    assert!(!parsed.warnings.iter().any(|w| w.kind.starts_with("word")), "{:#?}", parsed.warnings);
    // On a motion, dwell or leftover word a letter without a number stays an error.
    for (program, column, message) in [
        ("G1 X F600", 4, "X without a number"),
        ("G1 X1 Y F600", 7, "Y without a number"),
        ("G0 X1 E", 7, "E without a number"),
        ("G2 X1 Y1 I J1 F60", 10, "I without a number"),
        ("G4 P", 4, "P without a number"),
        ("G1 X1 F", 7, "F without a number"),
        ("G1 X1 S F60", 7, "S without a number"),
        ("G90 M", 5, "M without a number"),
    ] {
        let err = error(program);
        assert_eq!((err.line, err.column), (1, column), "{program}: {err}");
        assert!(err.message.contains(message), "{program}: {err}");
    }
}

#[test]
fn a_bare_axis_on_g92_is_left_unchanged_as_marlin_does() {
    // Absolute E: after `G92 E` (no number) E stays at 5, so E6 pushes 1 mm.
    let parsed = parse("G1 X1 E5 F600\nG92 E\nG1 X2 E6\nG92 E0\nG1 X3 E1\n");
    let filament: Vec<f64> = parsed.segments.iter().map(|s| s.segment.filament).collect();
    close(filament[1], 1.0 * MM, "E unchanged by a bare G92 E");
    close(filament[2], 1.0 * MM, "G92 E0 then E1");
    let note = find(&parsed.notes, "G92 E");
    assert_eq!((note.line, note.column), (2, 5));
    assert!(note.message.contains("left unchanged"), "{}", note.message);
}

// ------------------------------------------------------------------------------------------------
// Firmware retraction.
// ------------------------------------------------------------------------------------------------

#[test]
fn g10_and_g11_retract_and_recover_once() {
    // Marlin's defaults: 3 mm at 45 mm/s, recovered at 8 mm/s.
    let parsed = parse("G1 X1 E1 F600\nG10\nG10\nG1 X5 F6000\nG11\nG11\nG1 X6 E1\n");
    let s: Vec<Segment> = parsed.segments.iter().map(|s| s.segment).collect();
    assert_eq!(s.len(), 5, "move, retraction, travel, recovery, move: {s:#?}");
    let (retract, prime) = (s[1], s[3]);
    assert_eq!((retract.kind, prime.kind), (SegmentKind::Dwell, SegmentKind::Dwell));
    close(retract.filament, -3.0 * MM, "retracted filament");
    close(retract.duration, 3.0 / 45.0, "retraction time");
    close(prime.filament, 3.0 * MM, "recovered filament");
    close(prime.duration, 3.0 / 8.0, "recovery time");
    assert_eq!(retract.end, s[0].end, "the arm stands still");
    assert!(!retract.flags.contains(SegmentFlags::EXTRUDE) && !retract.flags.contains(SegmentFlags::TRAVEL));
    assert_eq!((parsed.segments[1].line, parsed.segments[3].line), (2, 5));
    assert_eq!(find(&parsed.notes, "G10 while retracted").line, 3);
    assert_eq!(find(&parsed.notes, "G11 while not retracted").line, 6);
    assert!(find(&parsed.notes, "G10").message.contains("3 mm of filament at 45 mm/s"));
}

#[test]
fn retraction_settings_come_from_the_options_m207_and_set_retraction() {
    let options = GcodeOptions {
        firmware_retraction: FirmwareRetraction { length: 0.8 * MM, speed: 40.0 * MM, extra_prime: 0.1 * MM, prime_speed: 30.0 * MM },
        ..GcodeOptions::default()
    };
    let s: Vec<Segment> = parse_with("G10\nG11\n", options).segments.into_iter().map(|s| s.segment).collect();
    close(s[0].filament, -0.8 * MM, "options' length");
    close(s[0].duration, 0.8 / 40.0, "options' speed");
    close(s[1].filament, 0.9 * MM, "length + extra");
    close(s[1].duration, 0.9 / 30.0, "options' recovery speed");
    // M207 S<mm> F<mm/min> R<extra mm> T<mm/min>; its F is not the modal feed.
    let parsed = parse("M207 S1 F1200 R0.5 T600 Z0.2\nG10\nG11\n");
    assert!(try_parse_with("M207 S1 F1200\nG1 X1\n", GcodeOptions::default()).is_err(), "M207's F is not a feed");
    let s: Vec<Segment> = parsed.segments.iter().map(|s| s.segment).take(2).collect();
    close(s[0].filament, -MM, "M207 S");
    close(s[0].duration, 1.0 / 20.0, "M207 F1200 = 20 mm/s");
    close(s[1].filament, 1.5 * MM, "M207 S + R");
    close(s[1].duration, 1.5 / 10.0, "M207 T600 = 10 mm/s");
    assert!(has(&parsed.warnings, "M207 Z"), "Z hop not acted on");
    // Klipper's SET_RETRACTION (mm, mm/s).
    let s = segments("SET_RETRACTION RETRACT_LENGTH=0.5 RETRACT_SPEED=25 UNRETRACT_EXTRA_LENGTH=0 UNRETRACT_SPEED=20\nG10\nG11\n");
    close(s[0].filament, -0.5 * MM, "RETRACT_LENGTH");
    close(s[0].duration, 0.02, "RETRACT_SPEED");
    close(s[1].duration, 0.025, "UNRETRACT_SPEED");
}

#[test]
fn g10_with_l_or_p_and_g10_in_rs274ngc_set_offsets_and_do_not_retract() {
    let parsed = parse("G10 L2 P1 X0 Y0\nG10 P0 S200 R150\n");
    assert!(parsed.segments.is_empty());
    assert_eq!(find(&parsed.warnings, "G10").count, 2);
    let parsed = parse_with("G10 L20 P1 X0\nG11\n", rs274());
    assert!(parsed.segments.is_empty());
    assert!(has(&parsed.warnings, "G10") && has(&parsed.warnings, "G11"));
}

#[test]
fn firmware_retraction_is_not_scaled_by_feed_or_flow_overrides() {
    let s = segments("M220 S50\nM221 S90\nG10\nG11\n");
    close(s[0].filament, -3.0 * MM, "length");
    close(s[0].duration, 3.0 / 45.0, "speed");
}

// ------------------------------------------------------------------------------------------------
// Feed and flow overrides.
// ------------------------------------------------------------------------------------------------

#[test]
fn m220_scales_later_feeds_and_m221_later_filament() {
    let parsed = parse("G1 X1 F6000\nM220 S50\nG1 X2\nG0 X3 F12000\nM220 B\nM220 S200\nG1 X4\nM220 R\nG1 X5\nM220\n");
    let feeds: Vec<f64> = parsed.segments.iter().map(|s| s.segment.feed).collect();
    let expected = [0.1, 0.05, 0.1, 0.4, 0.1];
    for (feed, expected) in feeds.iter().zip(expected) {
        close(*feed, expected, "feed");
    }
    assert!(find(&parsed.notes, "M220").message.contains("50 %"));
    assert_eq!(find(&parsed.warnings, "M220").line, 10, "M220 alone reports, nothing to do");
    // E-only moves run at the scaled feed too.
    let s = segments("M83\nM220 S50\nG1 E-1 F2100\n");
    close(s[0].duration, 1.0 / 17.5, "1 mm at 35 mm/s × 50 %");
    // Flow: absolute E positions stay the program's, the filament pushed is scaled.
    let s = segments("M82\nG1 X1 E1 F600\nM221 S90\nG1 X2 E2\nG1 X3 E3\nG1 E2.5\nM221 T1 S50\nG1 X4 E4\n");
    let filament: Vec<f64> = s.iter().map(|s| s.filament).collect();
    close(filament[0], 1.0 * MM, "before M221");
    close(filament[1], 0.9 * MM, "× 0.9");
    close(filament[2], 0.9 * MM, "the E position stays the program's");
    close(filament[3], -0.45 * MM, "E-only move scaled too");
    close(s[3].duration, 0.45 / 10.0, "…and its time with it");
    close(filament[4], 1.35 * MM, "M221 for another tool not acted on");
}

#[test]
fn override_percentages_out_of_range_are_errors_naming_the_column() {
    for (program, column) in [("M220 S0", 6), ("M220 S1001", 6), ("M221 S-5", 6), ("G1 X1 F60\nM221 S0.5", 6)] {
        let err = error(program);
        assert_eq!(err.column, column, "{program}: {err}");
        assert!(err.message.contains("out of range [1, 1000]"), "{program}: {err}");
    }
    // A letter always starts a word: `Sfast` is S, F, A, S, T, and S comes twice.
    let err = error("M220 Sfast");
    assert_eq!((err.line, err.column), (1, 9), "{err}");
    assert!(err.message.contains("word S given twice") && err.message.contains("was a number meant?"), "{err}");
    let err = error("M220 S");
    assert_eq!((err.line, err.column), (1, 6), "{err}");
    let err = error("G1 X1 M220 S50");
    assert!(err.message.contains("M220 must be alone on its line"), "{err}");
}

// ------------------------------------------------------------------------------------------------
// Velocity limits (honoured) and other limits (recorded).
// ------------------------------------------------------------------------------------------------

#[test]
fn m203_clamps_each_axis_share_of_the_feed() {
    let parsed = parse("M203 X50 Y500 Z5 E10\nG1 X100 F6000\nG1 X0 Y100 F12000\nG1 Z10 F600\nG1 X100 Y300 F60000\nM83\nG1 E-5 F3000\n");
    let s: Vec<Segment> = parsed.segments.iter().map(|s| s.segment).collect();
    close(s[0].feed, 0.05, "X alone at 100 mm/s → X limit 50 mm/s");
    // X share 1/√2 of 200 mm/s = 141 mm/s > 50: the feed is 50·√2 mm/s.
    close(s[1].feed, 0.05 * std::f64::consts::SQRT_2, "diagonal limited by X");
    close(s[2].feed, 0.005, "Z at 10 mm/s → 5 mm/s");
    close(s[3].feed, 0.05 * 5f64.sqrt(), "X share 1/√5 of the path (Y: 2/√5 of 1 m/s is below its 0.5 m/s)");
    close(s[4].duration, 0.5, "5 mm of filament at E ≤ 10 mm/s");
    assert_eq!(find(&parsed.notes, "feed limited").count, 5);
    assert!(find(&parsed.notes, "M203").message.contains("honoured"));
    let velocity = parsed.limits.velocity.unwrap();
    assert_eq!((velocity.value, velocity.line, velocity.source), (0.005, 1, "M203"));
    // A limit never raises a feed.
    let s = segments("M203 X5000\nG1 X1 F600\n");
    close(s[0].feed, 0.01, "below the limit: as programmed");
}

#[test]
fn set_velocity_limit_clamps_feed_and_records_the_rest() {
    let parsed = parse(concat!(
        "SET_VELOCITY_LIMIT VELOCITY=50 ACCEL=3000 SQUARE_CORNER_VELOCITY=5 ACCEL_TO_DECEL=1500\n",
        "G1 X100 F12000\n",
        "SET_VELOCITY_LIMIT ACCEL=5000 SQUARE_CORNER_VELOCITY=2.5\n",
        "set_velocity_limit velocity=200\n",
        "G1 X0 F6000\n",
    ));
    let feeds: Vec<f64> = parsed.segments.iter().map(|s| s.segment.feed).collect();
    close(feeds[0], 0.05, "VELOCITY=50 mm/s");
    close(feeds[1], 0.1, "raised back to 200 mm/s: the programmed 100 mm/s");
    let limits = parsed.limits;
    let acceleration = limits.acceleration.unwrap();
    assert_eq!((acceleration.value, acceleration.line, acceleration.source), (3.0, 1, "SET_VELOCITY_LIMIT ACCEL"), "the lowest");
    let corner = limits.square_corner_velocity.unwrap();
    assert_eq!((corner.value, corner.line), (0.0025, 3));
    assert_eq!(limits.velocity.unwrap().value, 0.05);
    assert!(has(&parsed.warnings, "SET_VELOCITY_LIMIT parameters"), "ACCEL_TO_DECEL not acted on");
    assert_eq!(find(&parsed.notes, "SET_VELOCITY_LIMIT").count, 3);
    for (program, column, message) in [
        ("SET_VELOCITY_LIMIT VELOCITY=fast", 29, "not a finite number"),
        ("SET_VELOCITY_LIMIT VELOCITY=nan", 29, "not a finite number"),
        ("SET_VELOCITY_LIMIT VELOCITY=0", 29, "must be > 0"),
        ("SET_VELOCITY_LIMIT ACCEL=-1", 26, "must be > 0"),
        ("SET_VELOCITY_LIMIT 50", 20, "is not KEY=VALUE"),
    ] {
        let err = error(program);
        assert_eq!((err.line, err.column), (1, column), "{program}: {err}");
        assert!(err.message.contains(message), "{program}: {err}");
    }
}

#[test]
fn accelerations_jerk_and_pressure_advance_are_recorded() {
    let parsed = parse(concat!(
        "M201 X500 Y400 Z100 E5000\n",
        "M204 P1000 R3000 T300\n",
        "M205 X8 Y8 Z0.4 E5 J0.02\n",
        "M566 X600 Y600\n",
        "M900 K0.05\n",
        "SET_PRESSURE_ADVANCE ADVANCE=0.04 SMOOTH_TIME=0.03\n",
        "M572 D0 S0.06\n",
        "M204 S2000\n",
    ));
    let l = parsed.limits;
    let a = l.acceleration.unwrap();
    assert_eq!((a.value, a.line, a.source), (0.1, 1, "M201"), "M201 Z100 mm/s² is the lowest");
    let jerk = l.jerk.unwrap();
    assert_eq!((jerk.value, jerk.line), (0.0004, 3), "M205 Z0.4 mm/s");
    close(l.junction_deviation.unwrap().value, 0.02 * MM, "M205 J");
    let advance = l.pressure_advance.unwrap();
    assert_eq!((advance.value, advance.line, advance.source), (0.06, 7, "M572"), "the last");
    assert_eq!(l.smooth_time.unwrap().value, 0.03);
    for kind in ["M201", "M204", "M205", "M566", "M900", "M572", "SET_PRESSURE_ADVANCE"] {
        assert!(has(&parsed.notes, kind), "{kind}: {:#?}", parsed.notes);
    }
    assert_eq!(find(&parsed.notes, "M204").count, 2);
    assert!(parsed.segments.is_empty());
    // Acted on: every segment from the command on carries the program's pressure advance.
    let parsed = parse("G1 X1 E1 F600\nSET_PRESSURE_ADVANCE ADVANCE=0.04\nG1 X2 E2\nG1 E1\nM900 K0.02\nG1 X3 E3\nM900 K30\nG1 X4 E4\n");
    let advances: Vec<Option<f64>> = parsed.segments.iter().map(|s| s.segment.pressure_advance).collect();
    assert_eq!(advances, [None, Some(0.04), Some(0.04), Some(0.02), Some(0.02)], "M900 K30 (Linear Advance 1.0 units) changes nothing");
    for (program, column) in
        [("M204 P0", 6), ("M201 X-5", 6), ("M900 K-1", 6), ("M900 K2000", 6), ("SET_PRESSURE_ADVANCE SMOOTH_TIME=0.5", 34), ("M205 J-1", 6)]
    {
        let err = error(program);
        assert_eq!((err.line, err.column), (1, column), "{program}: {err}");
    }
}

// ------------------------------------------------------------------------------------------------
// Tools.
// ------------------------------------------------------------------------------------------------

#[test]
fn one_tool_per_job() {
    // T codes before any extrusion just select; the one that extrudes is the job's tool.
    let parsed = parse("T1\nT0\nG1 X1 E1 F600\nT0\nM104 T1 S200\nM109 T1 S200\nG1 X2 E2\n");
    assert_eq!(parsed.segments.len(), 2, "a temperature for another tool is reported, not acted on");
    assert_eq!(find(&parsed.warnings, "M104 T").line, 5);
    assert_eq!(find(&parsed.warnings, "T0").count, 2);
    let err = error("T0\nG1 X1 E1 F600\nG1 X2 E2\n  T1\nG1 X3 E3\n");
    assert_eq!((err.line, err.column), (4, 3), "{err}");
    assert!(err.message.contains("tool change to T1") && err.message.contains("multi-tool jobs are not supported"), "{err}");
    // T1 M6 is a tool change; extrusion with the default tool T0 counts.
    let err = error("G1 X1 E1 F600\nT1 M6\n");
    assert_eq!((err.line, err.column), (2, 1), "{err}");
    // Travel and retraction do not use a tool up.
    assert!(try_parse_with("G1 X1 F600\nG1 E-1\nT1\nG1 X2 E1\n", GcodeOptions::default()).is_ok());
    assert!(error("T1.5").message.contains("whole number"));
}

// ------------------------------------------------------------------------------------------------
// Reported codes: free text, firmware and extended commands.
// ------------------------------------------------------------------------------------------------

#[test]
fn free_text_and_unacted_codes_are_reported_never_errors() {
    let program = concat!(
        "M117 X1 Y2 E5 layer (1) 50% done; not a comment\n",
        "M118 E1 Homing X Y #2\n",
        "M73 P10 R5\n",
        "M400\n",
        "M105\nM141 S40\nM191 S40\nM106 S255\nM107\n",
        "M1002 gcode_claim_action : 2\n",
        "M486 AShape-Box id:0 copy 0\n",
        "M624 AQAAAAAAAAA=\n",
        "M620 M\n",
        "M620.1 E F523.843 T240\n",
        "M9999 Q[1+2] #5\n",
    );
    let parsed = parse(program);
    assert!(parsed.segments.is_empty());
    for kind in ["M117", "M118", "M73", "M400", "M105", "M141", "M191", "M106", "M107", "M1002", "M486", "M624"] {
        assert!(has(&parsed.warnings, kind), "{kind}: {:#?}", parsed.warnings);
    }
    assert_eq!(find(&parsed.warnings, "M620").count, 1);
    assert!(has(&parsed.warnings, "M9999"));
    // F beside an M-code is its parameter in firmware G-code: no feed was set.
    assert!(error("M620.1 E F523\nG1 X1\n").message.contains("no feed rate"));
    // In RS274/NGC, unreadable words stay errors, and F on any line is the feed.
    // (A letter always starts a word: `AShape-Box` is A, S, H, A, P, then E with "-Box".)
    let e = error_with("M486 AShape-Box\n", rs274());
    assert!(e.message.contains("malformed number after E"), "{e}");
    assert_eq!(parse_with("F600 M3 S1000\nG1 X1\n", rs274()).segments[0].segment.feed, 0.01);
}

#[test]
fn klipper_extended_commands_are_reported_once_per_name() {
    let program = concat!(
        "EXCLUDE_OBJECT_DEFINE NAME=part_1 CENTER=100,100 POLYGON=[[90,90],[110,90],[110,110],[90,110]]\n",
        "EXCLUDE_OBJECT_DEFINE NAME=part_2 CENTER=50,50 POLYGON=[[40,40],[60,40],[60,60]]\n",
        "START_PRINT BED_TEMP=60 EXTRUDER_TEMP=215\n",
        "PRINT_START\n",
        "BED_MESH_CALIBRATE ADAPTIVE=1\n",
        "SET_GCODE_OFFSET Z=0.05 MOVE=1\n",
        "RESPOND MSG=\"layer 1 ; of 3\"\n",
        "EXCLUDE_OBJECT_START NAME=part_1\n",
        "G1 X1 E1 F600\n",
        "EXCLUDE_OBJECT_END NAME=part_1\n",
        "TIMELAPSE_TAKE_FRAME\n",
        "END_PRINT\n",
    );
    let parsed = parse(program);
    assert_eq!(parsed.segments.len(), 1);
    let define = find(&parsed.warnings, "EXCLUDE_OBJECT_DEFINE");
    assert_eq!((define.line, define.column, define.count), (1, 1, 2));
    for kind in [
        "START_PRINT",
        "PRINT_START",
        "BED_MESH_CALIBRATE",
        "SET_GCODE_OFFSET",
        "RESPOND",
        "EXCLUDE_OBJECT_START",
        "TIMELAPSE_TAKE_FRAME",
        "END_PRINT",
    ] {
        assert!(has(&parsed.warnings, kind), "{kind}");
    }
    // Not RS274/NGC: an error in a LinuxCNC file.
    let err = error_with("G0 X1\nPRINT_START\n", rs274());
    assert_eq!((err.line, err.column), (2, 1));
}

// ------------------------------------------------------------------------------------------------
// Tags.
// ------------------------------------------------------------------------------------------------

#[test]
fn orca_bambu_and_simplify3d_tags() {
    let program = concat!(
        "G1 Z5 F600\n",
        "; CHANGE_LAYER\n; Z_HEIGHT: 0.2\n; LAYER_HEIGHT: 0.2\n",
        "; FEATURE: Outer wall\n",
        "G1 X1 Z0.2 E1\n",
        ";LAYER_CHANGE\n;Z:0.4\n;HEIGHT:0.2\n; CHANGE_LAYER\n; Z_HEIGHT: 0.4\n",
        "G1 X2 Z0.4 E1\n",
        "; layer 3, Z = 0.600\n; feature inner perimeter\n; tool H0.150 W0.480\n",
        "G1 X3 Z0.6 E1\n",
        "; layer end\n",
        ";LAYER:7\n;TYPE:WALL-OUTER\n",
        "G1 X4 E1\n",
    );
    let s = parse(program).segments;
    let tags: Vec<_> =
        s.iter().map(|s| (s.tags.layer, s.tags.z_marker, s.tags.height, s.tags.feature.as_deref().map(str::to_string))).collect();
    assert_eq!(tags[0], (None, None, None, None));
    assert_eq!(tags[1], (Some(0), Some(0.2 * MM), Some(0.2 * MM), Some("Outer wall".into())));
    assert_eq!(tags[2].0, Some(1), "Prusa's and Orca's markers with no move between them are one layer change");
    assert_eq!(tags[2].1, Some(0.4 * MM));
    assert_eq!(tags[3], (Some(2), Some(0.6 * MM), Some(0.15 * MM), Some("inner perimeter".into())), "Simplify3D counts from 1");
    assert_eq!((tags[4].0, tags[4].3.as_deref()), (Some(7), Some("WALL-OUTER")));
    let starts: Vec<bool> = s.iter().map(|s| s.segment.flags.contains(SegmentFlags::LAYER_START)).collect();
    assert_eq!(starts, [false, true, true, true, true]);
}

// ------------------------------------------------------------------------------------------------
// Dwell units.
// ------------------------------------------------------------------------------------------------

#[test]
fn g4_p_is_milliseconds_in_firmware_and_seconds_in_rs274ngc() {
    assert_eq!(segments("G4 P500\n")[0].duration, 0.5);
    assert_eq!(segments("G4 S2\n")[0].duration, 2.0);
    assert_eq!(parse_with("G4 P500\n", rs274()).segments[0].segment.duration, 500.0);
    assert_eq!(GcodeOptions::for_path(&corpus("arcs/cds.ngc")).dialect, Dialect::Rs274ngc);
    assert_eq!(GcodeOptions::for_path(&corpus("orca/square20_klipper.gcode")).dialect, Dialect::Firmware);
}

// ------------------------------------------------------------------------------------------------
// Numbers out of range.
// ------------------------------------------------------------------------------------------------

#[test]
fn positions_beyond_a_million_metres_are_errors_naming_the_column() {
    let huge = format!("1{}", "0".repeat(300));
    let cases: Vec<(String, usize, usize)> = vec![
        ("G1 X10000000000 F60".into(), 1, 4),
        (format!("G1 X{huge} F60"), 1, 4),
        ("F60\nG91\nG1 X900000000\nG1 X900000000".into(), 4, 4),
        (format!("G92 X-{huge}"), 1, 5),
        (format!("G1 X1 E{huge} F60"), 1, 7),
        ("M83\nG1 X1 E900000000 F60\nG1 X2 E900000000".to_string(), 3, 7),
        (format!("F60\nG2 X1 Y0 I{huge}"), 2, 10),
        (format!("F60\nG2 X1 R{huge}"), 2, 7),
    ];
    for (program, line, column) in cases {
        let err = error(&program);
        assert_eq!((err.line, err.column), (line, column), "{program:.60}: {err}");
        assert!(err.message.contains("out of range"), "{program:.60}: {err}");
    }
    close(segments("G1 X999999999 F60\n")[0].end.x, 999_999.999, "just inside");
}

// ------------------------------------------------------------------------------------------------
// The samples.
// ------------------------------------------------------------------------------------------------

struct SampleStats {
    parsed: Parsed,
    layers: Vec<i32>,
    features: Vec<String>,
    filament: f64,
    retraction_dwells: usize,
}

fn sample(name: &str) -> SampleStats {
    let path = corpus(name);
    let mut parser = parse_file(&path, GcodeOptions::for_path(&path)).unwrap();
    let segments = parser.by_ref().collect::<Result<Vec<_>, _>>().unwrap_or_else(|e| panic!("{e}"));
    let parsed =
        Parsed { segments, warnings: parser.warnings().to_vec(), notes: parser.notes().to_vec(), limits: *parser.program_limits() };
    let mut layers: Vec<i32> = parsed.segments.iter().filter_map(|s| s.tags.layer).collect();
    layers.dedup();
    let mut features: Vec<String> = parsed.segments.iter().filter_map(|s| s.tags.feature.as_deref().map(str::to_string)).collect();
    features.dedup();
    let filament = parsed.segments.iter().map(|s| s.segment.filament).sum();
    let retraction_dwells = parsed.segments.iter().filter(|s| s.segment.kind == SegmentKind::Dwell && s.segment.filament < 0.0).count();
    let last = parsed.segments.iter().filter(|s| s.segment.flags.contains(SegmentFlags::LAST)).count();
    assert_eq!(last, 1, "{name}: one LAST segment");
    SampleStats { parsed, layers, features, filament, retraction_dwells }
}

/// Filament of the square's three layers: perimeters 2 × 4 sides, infill 10 lines of 18 mm, at
/// 0.03 mm of filament per mm.
fn square_filament() -> f64 {
    let per_layer = 4.0 * 19.6 + 4.0 * 18.8 + 10.0 * 18.0;
    3.0 * per_layer * 0.03 * MM
}

#[test]
fn orca_klipper_sample_parses_with_firmware_retraction_and_klipper_commands() {
    let s = sample("orca/square20_klipper.gcode");
    assert_eq!(s.layers, [0, 1, 2]);
    assert_eq!(
        s.features,
        [
            "Custom",
            "Inner wall",
            "Outer wall",
            "Bottom surface",
            "Inner wall",
            "Outer wall",
            "Sparse infill",
            "Inner wall",
            "Outer wall",
            "Sparse infill"
        ]
    );
    let g10 = find(&s.parsed.notes, "G10");
    assert_eq!(g10.count, 10, "one retraction before layer 1 and three per layer");
    assert_eq!(s.retraction_dwells, 10);
    assert_eq!(find(&s.parsed.notes, "G11").count, 9);
    // Every G11 returns what the G10 before it took; the last G10 stays retracted.
    close(s.filament, square_filament() - 3.0 * MM, "net filament (m)");
    let l = s.parsed.limits;
    let a = l.acceleration.unwrap();
    assert_eq!((a.value, a.source), (4.0, "M204 S"), "the lowest of ACCEL=5000 and M204 S4000");
    assert_eq!(l.pressure_advance.unwrap().value, 0.04);
    assert_eq!(l.smooth_time.unwrap().value, 0.04);
    assert_eq!(l.square_corner_velocity.unwrap().value, 0.005);
    for kind in ["EXCLUDE_OBJECT_DEFINE", "EXCLUDE_OBJECT_START", "EXCLUDE_OBJECT_END", "PRINT_START", "PRINT_END", "SET_PRINT_STATS_INFO"]
    {
        assert!(has(&s.parsed.warnings, kind), "{kind}");
    }
}

#[test]
fn orca_bambu_sample_parses_with_its_firmware_codes() {
    let s = sample("orca/square20_bambu.gcode");
    assert_eq!(s.layers, [0, 1, 2]);
    assert_eq!(s.features[0], "Custom");
    assert!(s.features.contains(&"Outer wall".to_string()) && s.features.contains(&"Sparse infill".to_string()));
    let heights: Vec<Option<f64>> = s.parsed.segments.iter().filter(|g| g.tags.layer.is_some()).map(|g| g.tags.height).collect();
    assert!(heights.iter().all(|h| *h == Some(0.2 * MM)));
    let l = s.parsed.limits;
    assert_eq!(l.acceleration.unwrap().value, 0.5, "M201 Z500 mm/s²");
    assert_eq!(l.jerk.unwrap().value, 0.003, "M205 Z3 mm/s");
    // M203 X500 Y500 Z20 E30 (mm/s) is honoured: the 42000 mm/min (700 mm/s) travels run at 500·√2 mm/s at most.
    let fastest = s.parsed.segments.iter().map(|g| g.segment.feed).fold(0.0, f64::max);
    assert!(fastest <= 0.5 * std::f64::consts::SQRT_2 + 1e-12, "fastest feed {fastest} m/s");
    assert!(has(&s.parsed.notes, "feed limited"));
    for kind in ["M1002", "M624", "M620", "M620.1", "G29.1", "G380", "M1006", "T1000"] {
        assert!(has(&s.parsed.warnings, kind), "{kind}: {:#?}", s.parsed.warnings);
    }
    // The purge with T0 and the square's walls: the job's tool is T0 (T1000 is Bambu's "no AMS
    // change", given before the prime line).
    assert!(s.filament > square_filament());
}

#[test]
fn simplify3d_sample_parses_with_its_layer_and_feature_comments() {
    let s = sample("simplify3d/square20.gcode");
    assert_eq!(s.layers, [0, 1, 2]);
    assert_eq!(
        s.features,
        [
            "skirt",
            "outer perimeter",
            "inner perimeter",
            "solid layer",
            "outer perimeter",
            "inner perimeter",
            "infill",
            "outer perimeter",
            "inner perimeter",
            "infill"
        ]
    );
    let first = s.parsed.segments.iter().find(|g| g.segment.flags.contains(SegmentFlags::LAYER_START)).unwrap();
    assert_eq!((first.tags.layer, first.tags.z_marker, first.tags.height), (Some(0), Some(0.2 * MM), Some(0.2 * MM)));
    let skirt = 4.0 * 26.0 * 0.03 * MM;
    close(s.filament, square_filament() + skirt - 1.0 * MM, "net filament: the square, the skirt, one retraction left at the end");
    assert!(has(&s.parsed.warnings, "M84") && has(&s.parsed.warnings, "G28"));
}

#[test]
fn cura_sample_parses_through_its_default_end_code() {
    let s = sample("cura/square20.gcode");
    assert_eq!(s.layers, [0, 1, 2]);
    assert_eq!(s.features, ["WALL-OUTER", "WALL-INNER", "SKIN", "WALL-OUTER", "WALL-INNER", "FILL", "WALL-OUTER", "WALL-INNER", "FILL"]);
    let m84 = find(&s.parsed.warnings, "M84");
    assert_eq!(m84.line, 164, "M84 X Y E: Cura's default end code is read to the end");
    // Purge lines (15 + 15 mm) and the square; retractions: 5 mm at start and per layer, undone,
    // then the end code's 2 + 2 mm in relative mode (G91 sets E relative too).
    close(s.filament, 30.0 * MM + square_filament() - 5.0 * MM - 4.0 * MM, "net filament (m)");
    let last = s.parsed.segments.last().unwrap();
    let end = last.segment.end;
    for (axis, expected) in [(0, 0.0), (1, 235.0 * MM), (2, 10.8 * MM)] {
        close(end[axis], expected, "'Present print' at X0 Y235, Z raised 0.2 + 10 mm");
    }
}

// ------------------------------------------------------------------------------------------------
// Robustness.
// ------------------------------------------------------------------------------------------------

/// Slicer- and firmware-like lines with numbers that are sometimes absurd.
fn slicer_line() -> impl Strategy<Value = String> {
    let number = prop_oneof![
        (-500.0f64..500.0).prop_map(|v| format!("{v:.3}")),
        Just("1".repeat(320)),
        Just("nan".to_string()),
        Just("1e308".to_string()),
        Just("-0".to_string()),
        Just(String::new()),
        (0u32..5).prop_map(|v| v.to_string()),
    ];
    let template = proptest::sample::select(vec![
        "G1 X{} Y{} E{} F{}",
        "G0 X{} Y{} Z{}",
        "G2 X{} Y{} I{} J{}",
        "G3 X{} Y{} R{}",
        "G10",
        "G11",
        "G10 L{} P{}",
        "G92 E{}",
        "G92 X{} E",
        "G4 P{}",
        "G28 X Y",
        "M84 X Y E",
        "M18 E",
        "M220 S{}",
        "M220 B",
        "M221 S{} T{}",
        "M203 X{} Y{} E{}",
        "M204 P{} T{}",
        "M205 X{} J{}",
        "M207 S{} F{}",
        "M900 K{}",
        "M117 X{} hello",
        "M486 AShape{}",
        "T{}",
        "M83",
        "G91",
        "G90",
        "G20",
        "SET_VELOCITY_LIMIT VELOCITY={} ACCEL={}",
        "SET_PRESSURE_ADVANCE ADVANCE={} SMOOTH_TIME={}",
        "SET_RETRACTION RETRACT_LENGTH={} RETRACT_SPEED={}",
        "EXCLUDE_OBJECT_DEFINE NAME=a{} POLYGON=[[{},0]]",
        "; CHANGE_LAYER",
        "; Z_HEIGHT: {}",
        "; layer {}, Z = {}",
        ";LAYER:{}",
    ]);
    (template, proptest::collection::vec(number, 4)).prop_map(|(template, numbers)| {
        let mut line = String::new();
        let mut numbers = numbers.into_iter();
        for (i, part) in template.split("{}").enumerate() {
            if i > 0 {
                line.push_str(&numbers.next().unwrap_or_default());
            }
            line.push_str(part);
        }
        line
    })
}

fn check_run(bytes: Vec<u8>, dialect: Dialect) {
    let options = GcodeOptions { dialect, ..GcodeOptions::default() };
    let mut parser = Parser::new(Cursor::new(bytes), "fuzz", options);
    for item in parser.by_ref() {
        match item {
            Ok(g) => {
                let s = g.segment;
                assert!(s.end.iter().chain(s.centre.iter()).all(|v| v.is_finite()));
                assert!(s.feed.is_finite() && s.filament.is_finite() && s.duration.is_finite() && s.sweep.is_finite());
                assert!(s.kind == SegmentKind::Dwell || s.feed > 0.0, "moves have a positive feed");
            }
            Err(e) => {
                assert!(e.line >= 1, "{e}");
                assert!(!e.message.is_empty(), "{e}");
            }
        }
    }
    let limits = parser.program_limits();
    for setting in [limits.velocity, limits.acceleration, limits.jerk, limits.pressure_advance].into_iter().flatten() {
        assert!(setting.value.is_finite() && setting.value >= 0.0 && setting.line >= 1);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_slicer_like_lines_never_panic_and_errors_are_located(
        lines in proptest::collection::vec(slicer_line(), 1..40),
        rs274ngc in any::<bool>(),
    ) {
        let dialect = if rs274ngc { Dialect::Rs274ngc } else { Dialect::Firmware };
        check_run((String::from("F600\n") + &lines.join("\n")).into_bytes(), dialect);
    }

    #[test]
    fn random_bytes_never_panic_in_either_dialect(
        lines in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..80), 0..20),
        rs274ngc in any::<bool>(),
    ) {
        let dialect = if rs274ngc { Dialect::Rs274ngc } else { Dialect::Firmware };
        check_run(lines.join(&b'\n'), dialect);
    }
}

#[test]
fn nul_bytes_invalid_utf8_and_huge_lines_are_located_errors_or_ignored() {
    check_run(b"G1 X1\0 F600\n\xff\xfe G1 X2\nM117 \xc3\x28\n".to_vec(), Dialect::Firmware);
    let long = format!("M117 {}\nG1 X1 F600\n", "x".repeat(70_000));
    let err = error(&long);
    assert_eq!((err.line, err.column), (1, 0));
    assert!(err.message.contains("line longer than"));
}

// ------------------------------------------------------------------------------------------------
// Temperatures (CELL item 2): heat segments in order with the motion.
// ------------------------------------------------------------------------------------------------

fn heats(parsed: &Parsed) -> Vec<(usize, strand_core::HeatRequest)> {
    parsed.segments.iter().filter(|g| g.segment.kind == SegmentKind::Heat).map(|g| (g.line, g.segment.heat)).collect()
}

#[test]
fn temperature_codes_become_heat_segments_in_order() {
    use strand_core::{HeatRequest, HeatWait::*, Heater::*, OPEN_BAND};
    let program = concat!(
        "M140 S60\n",
        "M104 S150 T0\n",
        "M190 S60\n",
        "M109 S210\n",
        "G1 X10 Y10 F3000\n",
        "G1 X20 E1\n",
        "M109 R190\n",
        "SET_HEATER_TEMPERATURE HEATER=extruder TARGET=205\n",
        "SET_HEATER_TEMPERATURE HEATER=heater_bed\n",
        "TEMPERATURE_WAIT SENSOR=extruder MINIMUM=200 MAXIMUM=215\n",
        "TEMPERATURE_WAIT SENSOR=heater_bed MAXIMUM=40\n",
        "M104 S0\n",
    );
    let parsed = parse(program);
    let h = |heater, wait, target| HeatRequest { heater, wait, target, band: OPEN_BAND };
    assert_eq!(
        heats(&parsed),
        [
            (1, h(Bed, None, 60.0)),
            (2, h(HotEnd, None, 150.0)),
            (3, h(Bed, Heating, 60.0)),
            (4, h(HotEnd, Heating, 210.0)),
            (7, h(HotEnd, Both, 190.0)),
            (8, h(HotEnd, None, 205.0)),
            (9, h(Bed, None, 0.0)),
            (10, HeatRequest { heater: HotEnd, wait: Range, target: -1.0, band: [200.0, 215.0] }),
            (11, HeatRequest { heater: Bed, wait: Range, target: -1.0, band: [-273.15, 40.0] }),
            (12, h(HotEnd, None, 0.0)),
        ]
    );
    // In order with the motion: the moves sit between the waits, numbered in sequence, and a
    // heat segment stands where the machine is.
    let kinds: Vec<_> = parsed.segments.iter().map(|g| (g.segment.seq, g.segment.kind)).collect();
    assert_eq!(kinds[4..6], [(4, SegmentKind::Line), (5, SegmentKind::Line)]);
    assert_eq!(parsed.segments[6].segment.end, parsed.segments[5].segment.end);
    assert_eq!(parsed.segments.last().unwrap().segment.kind, SegmentKind::Heat);
    assert!(parsed.segments.last().unwrap().segment.flags.contains(SegmentFlags::LAST), "the job may end on a heat segment");
    // Acted on: notes, not warnings.
    for kind in ["M104", "M109", "M140", "M190", "SET_HEATER_TEMPERATURE", "TEMPERATURE_WAIT"] {
        assert!(has(&parsed.notes, kind), "{kind}: {:#?}", parsed.notes);
        assert!(!has(&parsed.warnings, kind), "{kind}");
    }
    // Without S nothing is set (Marlin); another heater or sensor is reported.
    let parsed = parse("M104\nM109\nSET_HEATER_TEMPERATURE HEATER=extruder1 TARGET=200\nTEMPERATURE_WAIT SENSOR=chamber MINIMUM=30\n");
    assert!(heats(&parsed).is_empty());
    for kind in ["M104", "M109", "SET_HEATER_TEMPERATURE extruder1", "TEMPERATURE_WAIT chamber"] {
        assert!(has(&parsed.warnings, kind), "{kind}: {:#?}", parsed.warnings);
    }
    // RS274/NGC: not a firmware, reported.
    assert!(parse_with("M104 S200\n", rs274()).segments.is_empty());
}

#[test]
fn bad_temperature_parameters_are_errors_with_line_and_column() {
    for (program, line, column, words) in [
        ("G1 X1 F600\nM104 S600\n", 2, 6, "M104 S (°C) 600 is out of range [0, 500]"),
        ("M190 S-5\n", 1, 6, "M190 S (°C) -5 is out of range"),
        ("\n\nM109 S200 R190\n", 3, 11, "S and R both given"),
        ("M140 Snan\n", 1, 0, ""),
        ("SET_HEATER_TEMPERATURE TARGET=200\n", 1, 1, "HEATER= is required"),
        ("SET_HEATER_TEMPERATURE HEATER=extruder TARGET=hot\n", 1, 47, "TARGET=\"hot\": not a finite number"),
        ("SET_HEATER_TEMPERATURE HEATER=extruder TARGET=900\n", 1, 47, "TARGET (°C) 900 is out of range"),
        ("TEMPERATURE_WAIT SENSOR=extruder\n", 1, 1, "MINIMUM= or MAXIMUM= is required"),
        ("TEMPERATURE_WAIT SENSOR=extruder MINIMUM=220 MAXIMUM=200\n", 1, 54, "MINIMUM 220 is above MAXIMUM 200"),
        ("TEMPERATURE_WAIT MINIMUM=200\n", 1, 1, "SENSOR= is required"),
    ] {
        let e = error(program);
        assert_eq!(e.line, line, "{program:?}: {e}");
        if column > 0 {
            assert_eq!(e.column, column, "{program:?}: {e}");
        }
        assert!(e.message.contains(words), "{program:?}: {e}");
        assert!(e.to_string().contains(&format!("test.gcode:{line}")), "{e}");
    }
}
