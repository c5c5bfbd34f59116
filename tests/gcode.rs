//! G-code intake: every corpus file (tests/data/gcode, real slicer output and LinuxCNC programs)
//! parses, with its segment counts, path length and filament pinned (computed independently by a
//! Python reader with mpmath quadrature for the arcs, and agreeing to 1e-15); arcs in the three planes
//! and both directions, R form, full circles, turns and helices against hand-worked geometry; modes,
//! tags, dwells and E-only moves; every error with its line, column and message; bounded warnings and
//! bounded memory over a generated 200,000-line program; no panic on random bytes.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::f64::consts::{FRAC_1_SQRT_2, PI, TAU};
use std::io::{BufReader, Cursor, Read};
use std::path::{Path, PathBuf};

use nalgebra::{Unit, UnitQuaternion, Vector3};
use proptest::prelude::*;
use strand_core::{Segment, SegmentFlags, SegmentKind};
use strand_job::gcode::{
    Dialect, GcodeError, GcodeOptions, GcodeSegment, MAX_REPORT_KINDS, OTHER_KIND, Parser, Warning, parse_file, segment_length,
};

// ------------------------------------------------------------------------------------------------
// Live-heap accounting, for the constant-memory test.
// ------------------------------------------------------------------------------------------------

struct Tracking;

thread_local! {
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn add_live(delta: isize) {
    LIVE.with(|live| {
        live.set(live.get() + delta);
        PEAK.with(|peak| peak.set(peak.get().max(live.get())));
    });
}

unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        add_live(layout.size() as isize);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        add_live(-(layout.size() as isize));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        add_live(new_size as isize - layout.size() as isize);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Tracking = Tracking;

/// Runs `f` and returns its result and the peak of live heap bytes (this thread) above the start.
fn peak_heap<T>(f: impl FnOnce() -> T) -> (T, isize) {
    let base = LIVE.with(|l| l.get());
    PEAK.with(|p| p.set(base));
    let result = f();
    (result, PEAK.with(|p| p.get()) - base)
}

// ------------------------------------------------------------------------------------------------
// Helpers.
// ------------------------------------------------------------------------------------------------

const MM: f64 = 1e-3;

fn mm(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z) * MM
}

struct Parsed {
    segments: Vec<GcodeSegment>,
    warnings: Vec<Warning>,
    notes: Vec<Warning>,
}

fn try_parse_with(text: &str, options: GcodeOptions) -> Result<Parsed, GcodeError> {
    let mut parser = Parser::new(Cursor::new(text.as_bytes().to_vec()), "test.gcode", options);
    let segments = parser.by_ref().collect::<Result<Vec<_>, _>>()?;
    Ok(Parsed { segments, warnings: parser.warnings().to_vec(), notes: parser.notes().to_vec() })
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

fn error(text: &str) -> GcodeError {
    match try_parse_with(text, GcodeOptions::default()) {
        Ok(p) => panic!("expected an error from {text:?}, got {} segments", p.segments.len()),
        Err(e) => e,
    }
}

fn starting_at(start: Vector3<f64>) -> GcodeOptions {
    GcodeOptions { start, ..GcodeOptions::default() }
}

fn assert_close(actual: f64, expected: f64, tolerance: f64, what: &str) {
    assert!((actual - expected).abs() <= tolerance, "{what}: {actual} vs {expected} (tolerance {tolerance})");
}

fn assert_vec_close(actual: &Vector3<f64>, expected: &Vector3<f64>, what: &str) {
    assert!((actual - expected).norm() < 1e-12, "{what}: {actual:?} vs {expected:?}");
}

/// Point of an arc after turning by `angle` from its start.
fn arc_point(start: &Vector3<f64>, arc: &Segment, angle: f64) -> Vector3<f64> {
    let rotation = UnitQuaternion::from_axis_angle(&Unit::new_normalize(arc.normal), angle);
    let h = (arc.end - arc.centre).dot(&arc.normal) * angle / arc.sweep;
    arc.centre + rotation * (start - arc.centre) + arc.normal * h
}

fn warning<'a>(list: &'a [Warning], kind: &str) -> &'a Warning {
    list.iter().find(|w| w.kind == kind).unwrap_or_else(|| panic!("no {kind:?} in {list:#?}"))
}

// ------------------------------------------------------------------------------------------------
// The corpus.
// ------------------------------------------------------------------------------------------------

fn corpus(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/gcode").join(name)
}

/// What a corpus file must give.
struct Expected {
    file: &'static str,
    lines: usize,
    arcs: usize,
    dwells: usize,
    extruding: usize,
    full_circles: usize,
    /// Sum of segment lengths (m).
    length: f64,
    /// Sum of filament (m).
    filament: f64,
    /// Sum of dwell durations (s).
    dwell_time: f64,
    layer_starts: usize,
    zero_length_notes: u64,
}

/// Pinned once from two independent readers: this module, and a separate Python script written for
/// the purpose (regex words, its own modal state, mpmath quadrature of the spiral arc length; not kept
/// in the repository). They agree to ≤ 1e-15 relative on every number here.
const EXPECTED: [Expected; 13] = [
    Expected {
        file: "arcs/3dtest.ngc",
        lines: 46,
        arcs: 3,
        dwells: 0,
        extruding: 0,
        full_circles: 3,
        length: 0.9680826422566291,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 1,
    },
    Expected {
        file: "arcs/arc-arc-planeswitch.ngc",
        lines: 2,
        arcs: 4,
        dwells: 0,
        extruding: 0,
        full_circles: 0,
        length: 0.020799527120157434,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 2,
    },
    Expected {
        file: "arcs/arcspiral.ngc",
        lines: 4,
        arcs: 999,
        dwells: 0,
        extruding: 0,
        full_circles: 0,
        length: 2.6735064801293613,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 2,
    },
    Expected {
        file: "arcs/cds.ngc",
        lines: 215,
        arcs: 50,
        dwells: 0,
        extruding: 0,
        full_circles: 0,
        length: 5.600361868940384,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 1,
    },
    Expected {
        file: "arcs/lathe_pawn.ngc",
        lines: 124,
        arcs: 22,
        dwells: 0,
        extruding: 0,
        full_circles: 0,
        length: 0.631625255552313,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 0,
    },
    Expected {
        file: "arcs/plasmatest.ngc",
        lines: 233,
        arcs: 129,
        dwells: 0,
        extruding: 0,
        full_circles: 0,
        length: 6.549910489111966,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 0,
    },
    Expected {
        file: "arcs/tangent_helix.ngc",
        lines: 3,
        arcs: 1,
        dwells: 0,
        extruding: 0,
        full_circles: 1,
        length: 0.22372465944466777,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 1,
    },
    Expected {
        file: "arcs/tort.ngc",
        lines: 130,
        arcs: 138,
        dwells: 0,
        extruding: 0,
        full_circles: 9,
        length: 3.9273965691482897,
        filament: 0.0,
        dwell_time: 0.0,
        layer_starts: 0,
        zero_length_notes: 0,
    },
    Expected {
        file: "slic3r/box35.gcode",
        lines: 16225,
        arcs: 0,
        dwells: 11,
        extruding: 15824,
        full_circles: 0,
        length: 35.823756031970454,
        filament: 1.669027040000232,
        dwell_time: 0.31428571428571755,
        layer_starts: 0,
        zero_length_notes: 0,
    },
    Expected {
        file: "slic3r/overhang45.gcode",
        lines: 18601,
        arcs: 0,
        dwells: 45,
        extruding: 17202,
        full_circles: 0,
        length: 74.21867812063601,
        filament: 3.3274378499999773,
        dwell_time: 1.285714285714279,
        layer_starts: 0,
        zero_length_notes: 0,
    },
    Expected {
        file: "slic3r/vase_cyl_spiral.gcode",
        lines: 13485,
        arcs: 0,
        dwells: 9,
        extruding: 13474,
        full_circles: 0,
        length: 20.83142337621014,
        filament: 1.048531860000129,
        dwell_time: 0.2571428571428572,
        layer_starts: 0,
        zero_length_notes: 102,
    },
    Expected {
        file: "prusaslicer/box35.gcode",
        lines: 9445,
        arcs: 0,
        dwells: 269,
        extruding: 9043,
        full_circles: 0,
        length: 42.132850885987246,
        filament: 1.7514540100000056,
        dwell_time: 7.685714285714263,
        layer_starts: 67,
        zero_length_notes: 0,
    },
    Expected {
        file: "prusaslicer/truss_plate_1mm.gcode",
        lines: 7730,
        arcs: 0,
        dwells: 321,
        extruding: 7535,
        full_circles: 0,
        length: 34.17498784443422,
        filament: 12.91690603999998,
        dwell_time: 9.171428571427734,
        layer_starts: 4,
        zero_length_notes: 0,
    },
];

#[derive(Default, Debug)]
struct Stats {
    lines: usize,
    arcs: usize,
    dwells: usize,
    extruding: usize,
    full_circles: usize,
    helical: usize,
    length: f64,
    filament: f64,
    dwell_time: f64,
    layer_starts: usize,
    last_flags: usize,
}

fn stats(file: &str) -> (Stats, Vec<Warning>, Vec<Warning>) {
    let options = GcodeOptions { first_seq: 100, ..GcodeOptions::for_path(&corpus(file)) };
    let mut parser = parse_file(&corpus(file), options.clone()).unwrap_or_else(|e| panic!("{e}"));
    let mut s = Stats::default();
    let mut start = options.start;
    let mut line = 0;
    for (seq, item) in (options.first_seq..).zip(&mut parser) {
        let item = item.unwrap_or_else(|e| panic!("{e}"));
        let g = item.segment;
        assert_eq!(g.seq, seq, "{file}: sequence numbers count up from first_seq");
        assert!(item.line >= line, "{file}: lines in order");
        assert_eq!(g.source_line as usize, item.line);
        assert_eq!(g.orientation, options.orientation);
        line = item.line;
        match g.kind {
            SegmentKind::Line => s.lines += 1,
            SegmentKind::Arc => {
                s.arcs += 1;
                s.full_circles += usize::from(g.sweep == TAU);
                s.helical += usize::from((g.end - g.centre).dot(&g.normal).abs() > 1e-12);
                assert_close((start - g.centre).dot(&g.normal), 0.0, 1e-15, "centre in the start's plane");
            }
            SegmentKind::Dwell => {
                s.dwells += 1;
                s.dwell_time += g.duration;
                assert_eq!(g.end, start, "a dwell stands still");
            }
            SegmentKind::Heat => assert_eq!(g.end, start, "a heat segment stands still"),
        }
        if !matches!(g.kind, SegmentKind::Dwell | SegmentKind::Heat) {
            assert!(g.feed > 0.0 && g.feed.is_finite());
            let extrude = g.flags.contains(SegmentFlags::EXTRUDE);
            assert_eq!(extrude, g.filament > 0.0);
            assert_eq!(g.flags.contains(SegmentFlags::TRAVEL), !extrude);
        }
        s.extruding += usize::from(g.extrudes());
        s.layer_starts += usize::from(g.flags.contains(SegmentFlags::LAYER_START));
        s.last_flags += usize::from(g.flags.contains(SegmentFlags::LAST));
        s.length += segment_length(&start, &g);
        s.filament += g.filament;
        start = g.end;
    }
    assert_eq!(parser.position(), start, "{file}: the parser ends where the last segment does");
    (s, parser.warnings().to_vec(), parser.notes().to_vec())
}

#[test]
fn every_corpus_file_parses_to_its_pinned_numbers() {
    for e in &EXPECTED {
        let (s, warnings, notes) = stats(e.file);
        let f = e.file;
        assert_eq!((s.lines, s.arcs, s.dwells), (e.lines, e.arcs, e.dwells), "{f}: lines, arcs, dwells");
        assert_eq!(s.extruding, e.extruding, "{f}: extruding segments");
        assert_eq!(s.full_circles, e.full_circles, "{f}: full circles");
        assert_close(s.length, e.length, 1e-9 * e.length, &format!("{f}: path length (m)"));
        assert_close(s.filament, e.filament, 1e-9 * e.filament, &format!("{f}: filament (m)"));
        assert_close(s.dwell_time, e.dwell_time, 1e-9 * e.dwell_time, &format!("{f}: dwell time (s)"));
        assert_eq!(s.layer_starts, e.layer_starts, "{f}: layer starts");
        assert_eq!(s.last_flags, 1, "{f}: exactly one LAST segment");
        let zero = notes.iter().find(|n| n.kind == "zero-length").map_or(0, |n| n.count);
        assert_eq!(zero, e.zero_length_notes, "{f}: zero-length moves skipped");
        assert!(warnings.len() <= 10, "{f}: few kinds of warnings: {warnings:#?}");
    }
}

#[test]
fn corpus_arcs_match_their_sources() {
    // SOURCES.md: tort has 138 arcs, 132 helical, 9 full circles in all three planes and directions.
    let (tort, _, _) = stats("arcs/tort.ngc");
    assert_eq!((tort.arcs, tort.helical, tort.full_circles), (138, 132, 9));
    let normals = |file: &str| {
        let parser = parse_file(&corpus(file), GcodeOptions::for_path(&corpus(file))).unwrap();
        let arcs: Vec<Segment> = parser.map(|s| s.unwrap().segment).filter(|s| s.kind == SegmentKind::Arc).collect();
        let mut normals: Vec<[i8; 3]> = arcs.iter().map(|a| [a.normal.x as i8, a.normal.y as i8, a.normal.z as i8]).collect();
        normals.sort();
        normals.dedup();
        (arcs, normals)
    };
    let (_, tort_normals) = normals("arcs/tort.ngc");
    assert_eq!(tort_normals.len(), 6, "tort turns both ways in G17, G18 and G19");
    // A lathe profile is made of minor arcs: with G18's direction flipped, all 22 would exceed 225°.
    let (pawn, pawn_normals) = normals("arcs/lathe_pawn.ngc");
    assert_eq!(pawn_normals, vec![[0, -1, 0], [0, 1, 0]], "lathe_pawn is G18 only");
    assert!(pawn.iter().all(|a| a.sweep < 0.75 * PI), "lathe_pawn arcs are all minor");
    let (cds, _) = normals("arcs/cds.ngc");
    assert!(cds.iter().all(|a| a.sweep < PI / 2.0 + 0.01), "cds's R arcs are the small ones");
    // arcspiral: 999 R arcs, radius 2 in shrinking by 0.002 in per arc, ending 0.002 in from the centre.
    let (spiral, _) = normals("arcs/arcspiral.ngc");
    assert_eq!(spiral.len(), 999);
    let radius = |a: &Segment| (a.end - a.centre).xy().norm() / 0.0254;
    assert_close(radius(&spiral[0]), 1.997999, 1e-6, "first spiral radius (in)");
    assert_close(radius(&spiral[998]), 0.002, 1e-6, "last spiral radius (in)");
    // tangent_helix: one full turn of radius 1 in rising 1.951523 in (G2 with no X/Y: end over start).
    let (helix, _) = normals("arcs/tangent_helix.ngc");
    assert_eq!(helix[0].sweep, TAU);
    assert_close(helix[0].end.z - helix[0].centre.z, 1.6835744289 * 0.0254, 1e-12, "helix rise (m)");
}

#[test]
fn corpus_warnings_name_what_was_not_acted_on() {
    let (_, warnings, _) = stats("slic3r/box35.gcode");
    let kinds: Vec<&str> = warnings.iter().map(|w| w.kind.as_str()).collect();
    // The temperatures (M190, M104, M109, M140) are acted on: notes, not warnings.
    assert_eq!(kinds, ["M107", "G28", "M106", "M84"]);
    let g28 = warning(&warnings, "G28");
    assert_eq!((g28.line, g28.column, g28.count), (12, 1, 2));
    let (_, warnings, _) = stats("arcs/plasmatest.ngc");
    assert_eq!(warning(&warnings, "M3").count, 15);
    assert_eq!(warning(&warnings, "M5").count, 16);
    assert_eq!((warning(&warnings, "word S").line, warning(&warnings, "word S").column), (7, 7));
    let (_, warnings, _) = stats("arcs/tort.ngc");
    assert_eq!(warning(&warnings, "(msg)").line, 3);
    assert_eq!(warning(&warnings, "M0").line, 4);
    let (_, warnings, _) = stats("arcs/cds.ngc");
    assert_eq!(warning(&warnings, "G43").column, 7);
}

#[test]
fn prusaslicer_tags_carry_feature_layer_and_z() {
    let parser = parse_file(&corpus("prusaslicer/box35.gcode"), GcodeOptions::default()).unwrap();
    let mut layers = Vec::new();
    let mut features = std::collections::BTreeSet::new();
    for item in parser {
        let item = item.unwrap();
        if item.segment.flags.contains(SegmentFlags::LAYER_START) {
            let layer = item.tags.layer.unwrap();
            let z = item.tags.z_marker.unwrap();
            assert_close(item.segment.end.z, z, 1e-12, "the layer's first move goes to the ;Z: height");
            layers.push(layer);
        }
        if let Some(f) = &item.tags.feature {
            features.insert(f.to_string());
        }
    }
    assert_eq!(layers, (0..67).collect::<Vec<_>>());
    let expected = ["Custom", "External perimeter", "Perimeter", "Skirt/Brim", "Solid infill", "Top solid infill"];
    assert_eq!(features.iter().map(String::as_str).collect::<Vec<_>>(), expected);
    // Slic3r 1.3 writes no layer or feature comments.
    let slic3r = parse_file(&corpus("slic3r/box35.gcode"), GcodeOptions::default()).unwrap();
    assert!(slic3r.map(|s| s.unwrap().tags).all(|t| t == Default::default()));
}

#[test]
fn plasmatest_keeps_its_crlf_and_reads_like_lf() {
    let bytes = std::fs::read(corpus("arcs/plasmatest.ngc")).unwrap();
    assert!(bytes.windows(2).filter(|w| w == b"\r\n").count() > 400, "the corpus copy keeps CRLF");
    let lf: Vec<u8> = bytes.iter().copied().filter(|b| *b != b'\r').collect();
    let read = |data: Vec<u8>| -> Vec<Segment> {
        let options = GcodeOptions { dialect: Dialect::Rs274ngc, ..GcodeOptions::default() };
        Parser::new(Cursor::new(data), "p", options).map(|s| s.unwrap().segment).collect()
    };
    assert_eq!(read(bytes), read(lf));
}

// ------------------------------------------------------------------------------------------------
// Arcs.
// ------------------------------------------------------------------------------------------------

#[test]
fn ijk_arcs_in_all_three_planes_and_both_directions() {
    let s = FRAC_1_SQRT_2;
    let x = mm(1.0, 0.0, 0.0);
    let y = mm(0.0, 1.0, 0.0);
    // (start, program, normal, sweep, end, point half-way), by hand: G17 is XY about z, G18 is ZX
    // about y (G2 clockwise seen from +y: from +x towards +z), G19 is YZ about x; G2 turns about −axis.
    let cases = [
        (x, "G17 G2 X0 Y-1 I-1", -Vector3::z(), PI / 2.0, mm(0.0, -1.0, 0.0), mm(s, -s, 0.0)),
        (x, "G17 G3 X0 Y1 I-1", Vector3::z(), PI / 2.0, mm(0.0, 1.0, 0.0), mm(s, s, 0.0)),
        (x, "G17 G2 X0 Y1 I-1", -Vector3::z(), 1.5 * PI, mm(0.0, 1.0, 0.0), mm(-s, -s, 0.0)),
        (x, "G18 G2 X0 Z1 I-1", -Vector3::y(), PI / 2.0, mm(0.0, 0.0, 1.0), mm(s, 0.0, s)),
        (x, "G18 G3 X0 Z-1 I-1", Vector3::y(), PI / 2.0, mm(0.0, 0.0, -1.0), mm(s, 0.0, -s)),
        (x, "G18 G3 X0 Z1 I-1", Vector3::y(), 1.5 * PI, mm(0.0, 0.0, 1.0), mm(-s, 0.0, -s)),
        (y, "G19 G2 Y0 Z-1 J-1", -Vector3::x(), PI / 2.0, mm(0.0, 0.0, -1.0), mm(0.0, s, -s)),
        (y, "G19 G3 Y0 Z1 J-1", Vector3::x(), PI / 2.0, mm(0.0, 0.0, 1.0), mm(0.0, s, s)),
        (y, "G19 G2 Y0 Z1 J-1", -Vector3::x(), 1.5 * PI, mm(0.0, 0.0, 1.0), mm(0.0, -s, -s)),
    ];
    for (start, program, normal, sweep, end, middle) in cases {
        let parsed = parse_with(&format!("F600\n{program}\n"), starting_at(start));
        let arc = parsed.segments[0].segment;
        assert_eq!(arc.kind, SegmentKind::Arc, "{program}");
        assert_vec_close(&arc.centre, &Vector3::zeros(), program);
        assert_eq!(arc.normal, normal, "{program}");
        assert_close(arc.sweep, sweep, 1e-12, program);
        assert_vec_close(&arc.end, &end, program);
        assert_vec_close(&arc_point(&start, &arc, arc.sweep / 2.0), &middle, program);
        assert_vec_close(&arc_point(&start, &arc, arc.sweep), &end, program);
        assert_close(arc.feed, 0.01, 1e-15, "F600 = 10 mm/s");
        assert_close(segment_length(&start, &arc), sweep * MM, 1e-15, program);
        assert!(arc.flags.contains(SegmentFlags::TRAVEL));
    }
}

#[test]
fn r_form_small_and_large_arcs() {
    let arcs = segments("F600\nG2 X1 Y1 R1\nG0 X0 Y0\nG2 X1 Y1 R-1\nG0 X0 Y0\nG3 X2 R1\nG0 X0 Y0\nG3 X1 Y1 R1\n");
    let (small, large, half, ccw) = (arcs[0], arcs[2], arcs[4], arcs[6]);
    assert_vec_close(&small.centre, &mm(1.0, 0.0, 0.0), "R > 0: the arc of at most half a circle");
    assert_close(small.sweep, PI / 2.0, 1e-12, "small");
    assert_vec_close(&large.centre, &mm(0.0, 1.0, 0.0), "R < 0: the larger arc");
    assert_close(large.sweep, 1.5 * PI, 1e-12, "large");
    assert_vec_close(&half.centre, &mm(1.0, 0.0, 0.0), "chord = 2R: a half circle");
    assert_close(half.sweep, PI, 1e-12, "half");
    assert_vec_close(&ccw.centre, &mm(0.0, 1.0, 0.0), "G3 R > 0 turns left of the chord");
    assert_close(ccw.sweep, PI / 2.0, 1e-12, "ccw");
}

#[test]
fn full_circles_with_end_omitted_or_equal_to_start_and_p_turns() {
    let arcs = segments("F600\nG0 X1\nG17 G2 I1\nG2 X1 Y0 I1 J0\nG3 I1 P3\nG2 X3 I1 P2\n");
    for arc in &arcs[1..3] {
        assert_eq!((arc.sweep, arc.normal), (TAU, -Vector3::z()));
        assert_vec_close(&arc.end, &mm(1.0, 0.0, 0.0), "a full circle ends where it starts");
        assert_vec_close(&arc.centre, &mm(2.0, 0.0, 0.0), "centre = start + (I, J)");
    }
    assert_close(arcs[3].sweep, 3.0 * TAU, 1e-12, "P3: three turns");
    assert_close(arcs[4].sweep, PI + TAU, 1e-12, "P2 on a half circle: one more turn");
    assert_close(segment_length(&mm(1.0, 0.0, 0.0), &arcs[4]), 3.0 * PI * MM, 1e-15, "length of 1.5 turns of r = 1 mm");
}

#[test]
fn helix_moves_the_normal_axis_linearly() {
    let options = starting_at(mm(1.0, 0.0, 0.0));
    let helix = parse_with("F600\nG3 Z3 I-1\nG18 G2 X1 Y2 K0 I-1\n", options).segments;
    let (a, b) = (helix[0].segment, helix[1].segment);
    assert_eq!((a.sweep, a.normal), (TAU, Vector3::z()));
    assert_vec_close(&a.centre, &Vector3::zeros(), "centre in the start's plane (z = 0)");
    assert_vec_close(&a.end, &mm(1.0, 0.0, 3.0), "end off the plane");
    assert_close(segment_length(&mm(1.0, 0.0, 0.0), &a), libm::hypot(TAU, 3.0) * MM, 1e-15, "helix length");
    assert_vec_close(&arc_point(&mm(1.0, 0.0, 0.0), &a, PI), &mm(-1.0, 0.0, 1.5), "half-way: half the rise");
    // G18 helix: rises along y.
    assert_eq!((b.sweep, b.normal), (TAU, -Vector3::y()));
    assert_vec_close(&b.centre, &mm(0.0, 0.0, 3.0), "G18 centre: start + (I, ·, K), at the start's y");
    assert_vec_close(&b.end, &mm(1.0, 2.0, 3.0), "G18 helix end");
}

#[test]
fn spiral_arcs_within_tolerance_have_the_length_of_a_linear_spiral() {
    // Start radius 10 mm, end radius 10.008 mm (inside max(0.05 mm, 0.1 %)), a quarter turn, 2 mm rise.
    let start = mm(10.0, 0.0, 0.0);
    let arc = parse_with("F600\nG3 X0 Y10.008 Z2 I-10\n", starting_at(start)).segments[0].segment;
    let length = segment_length(&start, &arc);
    // Brute force: a polyline through the spiral r(φ) = 10 + 0.008·φ/θ, z = 2·φ/θ.
    let n = 200_000;
    let point = |k: usize| {
        let phi = arc.sweep * k as f64 / n as f64;
        let r = 10.0 + 0.008 * phi / arc.sweep;
        mm(r * phi.cos(), r * phi.sin(), 2.0 * phi / arc.sweep)
    };
    let polyline: f64 = (0..n).map(|k| (point(k + 1) - point(k)).norm()).sum();
    assert_close(arc.sweep, PI / 2.0, 1e-12, "quarter turn");
    assert_close(length, polyline, 1e-12, "spiral length vs a 200,000-piece polyline");
    let err = error("F600\nG0 X10\nG3 X0 Y10.06 I-10\n");
    assert_eq!((err.line, err.column), (3, 1));
    assert!(err.message.contains("radius to end of arc differs from radius to start"), "{err}");
}

#[test]
fn absolute_arc_centres_with_g90_1() {
    let arcs = segments("F600\nG0 X5 Y5\nG90.1 G2 X7 Y5 I6 J5\nG91.1 G2 X5 Y5 I-1 J0\n");
    assert_vec_close(&arcs[1].centre, &mm(6.0, 5.0, 0.0), "G90.1: I J are the centre");
    assert_vec_close(&arcs[2].centre, &mm(6.0, 5.0, 0.0), "G91.1: offsets again");
    assert_close(arcs[1].sweep, PI, 1e-12, "half circle");
}

// ------------------------------------------------------------------------------------------------
// Modes.
// ------------------------------------------------------------------------------------------------

#[test]
fn inches_under_g20_apply_to_coordinates_offsets_and_feed() {
    let s = segments("G20 G1 X1 F10\nG2 X3 I1\nG21 G1 X100\n");
    assert_vec_close(&s[0].end, &Vector3::new(0.0254, 0.0, 0.0), "X1 in");
    assert_close(s[0].feed, 10.0 * 0.0254 / 60.0, 1e-18, "F10 in/min");
    assert_vec_close(&s[1].centre, &Vector3::new(0.0508, 0.0, 0.0), "I1 in");
    assert_vec_close(&s[2].end, &Vector3::new(0.1, 0.0, 0.0), "back to mm");
    assert_close(s[2].feed, 10.0 * 0.0254 / 60.0, 1e-18, "F keeps its speed across G21");
}

#[test]
fn relative_moves_under_g91_and_back() {
    let s = segments("F60\nG91\nG1 X1 Y2\nX1 Z1\nG90 X0\n");
    assert_vec_close(&s[0].end, &mm(1.0, 2.0, 0.0), "relative");
    assert_vec_close(&s[1].end, &mm(2.0, 2.0, 1.0), "relative again, modal G1");
    assert_vec_close(&s[2].end, &mm(0.0, 2.0, 1.0), "absolute");
}

#[test]
fn relative_and_absolute_extrusion() {
    let relative = segments("M83\nG1 X1 E0.5 F60\nG1 X2 E0.25\nG1 X3 E-0.1\n");
    let filament: Vec<f64> = relative.iter().map(|s| s.filament).collect();
    assert_eq!(filament, [0.5 * MM, 0.25 * MM, -0.1 * MM]);
    let flags: Vec<bool> = relative.iter().map(|s| s.extrudes()).collect();
    assert_eq!(flags, [true, true, false], "a move with negative E is a travel");
    assert!(relative[2].flags.contains(SegmentFlags::TRAVEL));
    let absolute = segments("M82\nG1 X1 E2 F60\nG1 X2 E3\nG92 E0\nG1 X3 E1\nG92\nG1 X1 E1.5\n");
    let filament: Vec<f64> = absolute.iter().map(|s| s.filament).collect();
    assert_close(filament[0], 2.0 * MM, 1e-18, "absolute E2");
    assert_close(filament[1], 1.0 * MM, 1e-18, "E2 → E3");
    assert_close(filament[2], 1.0 * MM, 1e-18, "after G92 E0: E0 → E1");
    assert_close(filament[3], 1.5 * MM, 1e-18, "after a bare G92 (all zero): E0 → E1.5");
    assert_vec_close(&absolute[3].end, &mm(4.0, 0.0, 0.0), "bare G92 made X3 the new X0");
    // Like Marlin, G91 makes E relative too, and G90 absolute again.
    let g91 = segments("G91\nG1 X1 E1 F60\nG1 X1 E1\n");
    assert_eq!(g91[1].filament, 1.0 * MM);
}

#[test]
fn g92_shifts_the_program_coordinates() {
    let s = segments("F60\nG1 X5 Y5\nG92 X10\nG1 X20\nG1 Y0\nG92.1\nG1 X0\n");
    assert_vec_close(&s[1].end, &mm(15.0, 5.0, 0.0), "after G92 X10 at X5, X20 is 15 mm");
    assert_vec_close(&s[2].end, &mm(15.0, 0.0, 0.0), "Y untouched by G92 X");
    assert_vec_close(&s[3].end, &mm(0.0, 0.0, 0.0), "G92.1 clears the offset");
}

#[test]
fn modal_motion_lines_without_a_g_word() {
    let s = segments("G0 X1 F600\nY1\nG1 X2 F60\nY2\nG2 X3 Y3 I1\nX4 Y2 I0 J-1\n");
    let kinds: Vec<SegmentKind> = s.iter().map(|s| s.kind).collect();
    use SegmentKind::{Arc, Line};
    assert_eq!(kinds, [Line, Line, Line, Line, Arc, Arc]);
    assert_close(s[1].feed, 0.01, 1e-15, "modal G0 at its own F600");
    assert_close(s[3].feed, 0.001, 1e-15, "modal G1 at F60");
    assert_vec_close(&s[5].end, &mm(4.0, 2.0, 0.0), "modal G2");
}

#[test]
fn rapid_feed_choice() {
    // No F yet: the options' rapid feed. Then the modal F. Once a G0 line gives F, G0 keeps it.
    let options = GcodeOptions { rapid_feed: 0.25, ..GcodeOptions::default() };
    let s = parse_with("G0 X1\nG1 X2 F600\nG0 X3\nG0 X4 F6000\nG1 X5 F1200\nG0 X6\nG1 X7\n", options).segments;
    let expected = [0.25, 0.01, 0.01, 0.1, 0.02, 0.1, 0.02];
    assert_eq!(s.len(), expected.len());
    for (segment, feed) in s.iter().zip(expected) {
        assert_close(segment.segment.feed, feed, 1e-15, &format!("line {}", segment.line));
    }
}

#[test]
fn lower_case_line_numbers_crlf_comments_and_whitespace() {
    let program = "%\r\n  n10 g1 x1 (move (not nested) y2 f600\r\nN20G1X+2Y-3 ; comment\r\n\t(msg, hello)\r\nN30 G1 X3*80\r\n%\r\n";
    let parsed = parse(program);
    let ends: Vec<Vector3<f64>> = parsed.segments.iter().map(|s| s.segment.end).collect();
    assert_eq!(ends, [mm(1.0, 2.0, 0.0), mm(2.0, -3.0, 0.0), mm(3.0, -3.0, 0.0)]);
    assert_eq!(parsed.segments[1].line, 3);
    assert_eq!(warning(&parsed.warnings, "(msg)").column, 2);
    // The checksum is the XOR of the bytes before '*'.
    let body = "N30 G1 X3";
    let checksum = body.bytes().fold(0u8, |x, b| x ^ b);
    assert_eq!(checksum, 80);
    let err = error("F60\nN30 G1 X3*94\n");
    assert_eq!((err.line, err.column), (2, 10));
    assert!(err.message.contains("checksum mismatch"), "{err}");
}

/// Packed words (no blanks, as space-stripping senders and post-processors write them) read as
/// every firmware reads them: a letter always starts a word, so `E` after a number is the next
/// word, never an exponent; with `N` numbers and `*` checksums, lower case, and bare flags (`G28XY`).
#[test]
fn packed_words_read_as_the_firmwares_read_them() {
    let with_checksum = |body: &str| format!("{body}*{}", body.bytes().fold(0u8, |x, b| x ^ b));
    let packed = [
        "M82".to_string(),
        "G92E0".into(),
        with_checksum("N1G1X10Y0F1200"),
        "G1X120.5Y121.77005E22.97101F2400".into(),
        "g1x130e23.5".into(),
        with_checksum("N2G1X140E24.0"),
        "G28XY".into(),
        "G1X1e5F60".into(),
    ]
    .join("\n");
    let spaced =
        "M82\nG92 E0\nN1 G1 X10 Y0 F1200\nG1 X120.5 Y121.77005 E22.97101 F2400\nG1 X130 E23.5\nN2 G1 X140 E24.0\nG28 X Y\nG1 X1 E5 F60";
    let (a, b) = (parse(&packed), parse(spaced));
    assert_eq!(a.segments.len(), 5, "{packed}");
    for (p, s) in a.segments.iter().zip(&b.segments) {
        assert_eq!(
            (p.segment.end, p.segment.filament, p.segment.feed),
            (s.segment.end, s.segment.filament, s.segment.feed),
            "line {}",
            p.line
        );
    }
    assert_vec_close(&a.segments[1].segment.end, &mm(120.5, 121.77005, 0.0), "X120.5Y121.77005");
    assert_close(a.segments[1].segment.filament, 22.97101 * MM, 1e-12, "E22.97101 after Y, not an exponent");
    assert_close(a.segments[4].segment.filament, (5.0 - 24.0) * MM, 1e-12, "X1e5 is X1 E5");
    // An M-code's parameters the parser does not act on may repeat a letter once packed (Bambu's
    // base64 argument): set aside, as firmwares ignore them.
    assert_eq!(parse("M624 AQAAAAAAAAA=\nG1 X1 F60").segments.len(), 1);
    // A packed line's checksum is checked like a spaced one's.
    let err = error("F60\nN2G1X140E24.0*1\n");
    assert!(err.message.contains("checksum mismatch"), "{err}");
}

#[test]
fn slicer_tags_and_layer_start() {
    let program = "\
;TYPE:Custom
G1 Z5 F600
;LAYER_CHANGE
;Z:0.3
G1 Z0.3
;TYPE:External perimeter
G1 X1 E1
G1 X2 E1
;LAYER_CHANGE
;Z:0.6
G1 E-1
G1 Z0.6
;LAYER:7
;TYPE:WALL-OUTER
G1 X3 E1
";
    let s = parse(program).segments;
    let layer_start: Vec<bool> = s.iter().map(|s| s.segment.flags.contains(SegmentFlags::LAYER_START)).collect();
    assert_eq!(layer_start, [false, true, false, false, false, true, true], "the first line or arc after a marker");
    assert_eq!(s[0].tags.feature.as_deref(), Some("Custom"));
    assert_eq!((s[0].tags.layer, s[0].tags.z_marker), (None, None));
    assert_eq!((s[1].tags.layer, s[1].tags.z_marker), (Some(0), Some(0.3 * MM)));
    assert_eq!(s[2].tags.feature.as_deref(), Some("External perimeter"));
    assert_eq!(s[4].segment.kind, SegmentKind::Dwell, "the retraction");
    assert_eq!((s[5].tags.layer, s[5].tags.z_marker), (Some(1), Some(0.6 * MM)));
    assert_eq!(s[6].tags.layer, Some(7), "Cura's ;LAYER:n gives n");
    assert_eq!(s[6].tags.feature.as_deref(), Some("WALL-OUTER"));
}

// ------------------------------------------------------------------------------------------------
// Dwells, E-only moves, zero-length moves, things not acted on.
// ------------------------------------------------------------------------------------------------

#[test]
fn dwell_units_depend_on_the_dialect() {
    let rs274 = GcodeOptions { dialect: Dialect::Rs274ngc, ..GcodeOptions::default() };
    let cnc = parse_with("G4 P1.5\nG4 P500\n", rs274).segments;
    assert_eq!((cnc[0].segment.kind, cnc[0].segment.duration), (SegmentKind::Dwell, 1.5), "LinuxCNC: P in seconds");
    assert_eq!(cnc[1].segment.duration, 500.0);
    let firmware = segments("G4 P500\nG4 S2\nG4\nG4 P1.5\n");
    let durations: Vec<f64> = firmware.iter().map(|s| s.duration).collect();
    assert_eq!(durations, [0.5, 2.0, 0.0, 0.0015], "firmware: P in ms, S in s; a bare G4 waits for nothing");
    // The dialect follows the file's extension.
    for (name, dialect) in [
        ("a.ngc", Dialect::Rs274ngc),
        ("b.NC", Dialect::Rs274ngc),
        ("c.tap", Dialect::Rs274ngc),
        ("d.gcode", Dialect::Firmware),
        ("e", Dialect::Firmware),
    ] {
        assert_eq!(GcodeOptions::for_path(Path::new(name)).dialect, dialect, "{name}");
    }
    let options = starting_at(mm(1.0, 2.0, 3.0));
    let dwell = parse_with("G4 S1\n", options).segments[0].segment;
    assert_eq!((dwell.end, dwell.filament, dwell.flags), (mm(1.0, 2.0, 3.0), 0.0, SegmentFlags::LAST));
}

#[test]
fn e_only_moves_become_dwells_with_filament() {
    let s = segments("G1 X1 F1200\nG1 E-1 F2100\nG1 E0\nM83\nG1 E1.5\n");
    assert_eq!(s.len(), 4);
    let retract = s[1];
    assert_eq!(retract.kind, SegmentKind::Dwell);
    assert_eq!(retract.filament, -MM);
    assert_close(retract.duration, 1.0 / 35.0, 1e-15, "1 mm at 2100 mm/min = 35 mm/s");
    assert_vec_close(&retract.end, &mm(1.0, 0.0, 0.0), "the arm stands still");
    assert!(!retract.flags.contains(SegmentFlags::EXTRUDE) && !retract.flags.contains(SegmentFlags::TRAVEL));
    assert_eq!((s[2].filament, s[3].filament), (1.0 * MM, 1.5 * MM));
}

#[test]
fn zero_length_moves_are_skipped_with_a_note() {
    let parsed = parse("G1 X1 F60\nG1 X1\nG1 X1 Y0 Z0\nG1 F1200\nG0\n");
    assert_eq!(parsed.segments.len(), 1);
    let note = warning(&parsed.notes, "zero-length");
    assert_eq!((note.line, note.column, note.count), (2, 1, 2));
    assert_eq!(note.message, "zero-length move skipped");
    assert!(parsed.warnings.is_empty(), "G1 F1200 and G0 alone set modes, they are not moves");
}

#[test]
fn codes_not_acted_on_are_reported_once_per_kind_with_a_count() {
    let parsed = parse("M107 S200\nM107 S210\nG28\nT0\nT1\nT0\nM106 S255\nS1000\nG1 X1 F60 M107 S1\nM862.3 P \"MK3S\"\n");
    let w = &parsed.warnings;
    assert_eq!((warning(w, "M107").line, warning(w, "M107").column, warning(w, "M107").count), (1, 1, 3));
    assert_eq!(warning(w, "G28").count, 1);
    assert_eq!((warning(w, "T0").count, warning(w, "T1").count), (2, 1));
    assert_eq!((warning(w, "word S").line, warning(w, "word S").count), (8, 1), "S owned by M107/M106 is its parameter");
    assert_eq!(warning(w, "M862.3").count, 1);
    assert_eq!(parsed.segments.len(), 1, "the G1 beside an M-code still moves");
    // Free-text M-codes and extended (Klipper) commands.
    let parsed = parse("M117 Printing (layer 1) 50% done\nEXCLUDE_OBJECT_START NAME=part_1\nSET_PRESSURE_ADVANCE ADVANCE=0.05\n");
    assert_eq!(warning(&parsed.warnings, "M117").count, 1);
    assert_eq!(warning(&parsed.warnings, "EXCLUDE_OBJECT_START").line, 2);
    assert_eq!(warning(&parsed.notes, "SET_PRESSURE_ADVANCE").line, 3, "acted on: a note");
    // Parameters of an M-code, G28 or G10 are not moves (Marlin: M92 X80 E93 sets steps/mm) ...
    let parsed = parse("G1 F60\nM92 X80 E93\nG28 X0\n");
    assert!(parsed.segments.is_empty());
    assert_eq!(parsed.warnings.len(), 2);
    // ... but beside G43 (tool length) the axis words still move, with the modal G1.
    let parsed = parse("G1 F60\nG43 H1 Z5\n");
    assert_eq!(parsed.segments[0].segment.end, mm(0.0, 0.0, 5.0));
    assert_eq!(warning(&parsed.warnings, "G43").count, 1);
    assert!(parsed.warnings.iter().all(|w| w.kind != "word H"), "H is G43's parameter");
}

#[test]
fn the_warning_list_is_bounded_by_its_kinds() {
    let program: String = (0..500).map(|i| format!("M{}\n", 1000 + i)).collect();
    let parsed = parse(&program);
    assert_eq!(parsed.warnings.len(), MAX_REPORT_KINDS + 1);
    let other = warning(&parsed.warnings, OTHER_KIND);
    assert_eq!((other.line, other.count), (MAX_REPORT_KINDS + 1, 500 - MAX_REPORT_KINDS as u64));
    assert!(other.message.contains("M1064"), "{}", other.message);
    assert!(parsed.warnings.iter().all(|w| w.kind == OTHER_KIND || w.count == 1));
}

#[test]
fn program_end_marks_the_last_segment_and_counts_what_follows() {
    let options = GcodeOptions { first_seq: 7, ..GcodeOptions::default() };
    let parsed = parse_with("G1 X1 F60\nG1 X2\nM2\nG1 X3\n(comment)\n;c\n%\nG1 X4\n", options.clone());
    let seqs: Vec<(u64, bool)> = parsed.segments.iter().map(|s| (s.segment.seq, s.segment.flags.contains(SegmentFlags::LAST))).collect();
    assert_eq!(seqs, [(7, false), (8, true)]);
    assert!(parsed.segments.iter().all(|s| s.segment.orientation == options.orientation));
    let after = warning(&parsed.warnings, "after end");
    assert_eq!((after.line, after.count), (4, 2));
    // A closing % ends the program too; an opening one does not.
    let parsed = parse("%\nG1 X1 F60\n%\nG1 X2\n");
    assert_eq!(parsed.segments.len(), 1);
    // The default orientation points the nozzle down: the tool z axis along −z.
    let down = GcodeOptions::default().orientation * Vector3::z();
    assert_vec_close(&down, &-Vector3::z(), "nozzle down");
}

// ------------------------------------------------------------------------------------------------
// Errors: line, column, message.
// ------------------------------------------------------------------------------------------------

#[test]
fn errors_name_line_column_and_cause() {
    let huge = format!("G1 X1{} F60", "0".repeat(400));
    let cases: Vec<(String, usize, usize, &str)> = vec![
        ("G1 X1.2.3 F60".into(), 1, 4, "malformed number after X: \"1.2.3\""),
        ("G1 Xabc F60".into(), 1, 4, "X without a number"),
        ("G1 X F60".into(), 1, 4, "X without a number"),
        ("G1 X- F60".into(), 1, 4, "malformed number after X: \"-\""),
        ("G1 X1 ?5".into(), 1, 7, "unexpected character '?' where a word letter should be"),
        ("(°) G1 Xq F60".into(), 1, 8, "X without a number"),
        (huge, 1, 4, "number out of range after X"),
        // A letter always starts a word: `Xnan` is X, N, A, N, and N needs a number.
        ("G1 Xnan F60".into(), 1, 5, "N without a number"),
        ("G1 Xinf F60".into(), 1, 6, "N without a number"),
        ("G1 X1 F0".into(), 1, 7, "F0 is an error"),
        ("G1 X1 F-5".into(), 1, 7, "F-5 is an error"),
        (format!("G1 X1 F0.{}1", "0".repeat(320)), 1, 7, "is too small to be a feed"),
        ("G1 X1".into(), 1, 1, "G1 with no feed rate"),
        ("F60\nX1".into(), 2, 1, "no motion mode"),
        ("F60\nG1 X1 Y0\nG2 X3 Y0 I1.5".into(), 3, 1, "radius to end of arc differs from radius to start"),
        ("F60\nG2 X0 Y0 R5".into(), 2, 1, "R-form arc with its end on its start"),
        ("F60\nG2 X10 R1".into(), 2, 8, "arc radius too small to reach the end point"),
        ("F60\nG2 X1 R0".into(), 2, 7, "zero radius arc"),
        ("F60\nG2 X0 Y0 I0 J0".into(), 2, 1, "zero radius arc"),
        ("F60\nG2 X1 Y1".into(), 2, 1, "arc without a centre"),
        ("F60\nG2 X1 I1 K1".into(), 2, 10, "K word given for an arc in the XY plane (G17)"),
        ("F60\nG2 X1 R1 I1".into(), 2, 10, "both R and I"),
        ("F60\nG2 X0 I1 P1.5".into(), 2, 10, "number of turns"),
        ("F60\nG2 X0 I1 P1001".into(), 2, 10, "more than 1000 turns"),
        ("G5 X1 Y1 I1 J1 P1 Q1".into(), 1, 1, "unsupported motion G5"),
        ("F60\nG41 G1 X1".into(), 2, 1, "unsupported motion G41 (cutter radius compensation)"),
        ("F60\nG1 X1 A5".into(), 2, 7, "unsupported axis word A"),
        ("F60\nG52 X10".into(), 2, 1, "unsupported motion G52 (local coordinate offset)"),
        ("G71 P1 Q2 D1".into(), 1, 1, "unsupported motion G71 (canned cycle)"),
        ("G0 G1 X1".into(), 1, 4, "G1 conflicts with another code of its group at column 1"),
        ("G1 X1 X2 F60".into(), 1, 7, "word X given twice"),
        ("G1 X1 (open".into(), 1, 7, "unclosed '(' comment"),
        ("#1 = 5".into(), 1, 1, "parameters (#) are not supported"),
        ("o100 sub".into(), 1, 1, "O words"),
        ("G1 X[1+2]".into(), 1, 4, "expressions ([...]) are not supported"),
        ("G1 X#1".into(), 1, 4, "parameters (#) are not supported"),
        ("G4 P1 S1".into(), 1, 4, "G4 with both P and S"),
        ("G4 P-1".into(), 1, 1, "negative dwell time"),
        ("G92 X1 G1 Y2 F60".into(), 1, 8, "G1 and G92 on one line"),
        ("G1 X\"a\" F60".into(), 1, 4, "X needs a number, not a string"),
    ];
    for (program, line, column, message) in cases {
        let err = error(&program);
        assert_eq!((err.line, err.column), (line, column), "{program:?}: {err}");
        assert!(err.message.contains(message), "{program:?}: {err}");
        assert_eq!(err.to_string(), format!("test.gcode:{line}:{column}: {}", err.message));
    }
}

#[test]
fn an_error_ends_the_iteration_after_the_segments_before_it() {
    let mut parser = Parser::new(Cursor::new("G1 X1 F60\nG1 X2\nG1 X3 F0\nG1 X4\n"), "e.gcode", GcodeOptions::default());
    let first = parser.next().unwrap().unwrap();
    let second = parser.next().unwrap().unwrap();
    assert!(!second.segment.flags.contains(SegmentFlags::LAST), "no LAST before an error");
    assert_eq!((first.line, second.line), (1, 2));
    let err = parser.next().unwrap().unwrap_err();
    assert_eq!((err.file.as_str(), err.line, err.column), ("e.gcode", 3, 7));
    assert!(parser.next().is_none());
    assert_eq!(parser.lines_read(), 3);
    let missing = parse_file(&corpus("no/such.gcode"), GcodeOptions::default()).err().unwrap();
    assert!(missing.to_string().contains("cannot open"), "{missing}");
}

#[test]
fn overlong_lines_are_an_error_not_a_memory_leak() {
    let program = format!("G1 X1 F60\n;{}\n", "x".repeat(100_000));
    let err = error(&program);
    assert_eq!(err.line, 2);
    assert!(err.message.contains("line longer than"), "{err}");
}

// ------------------------------------------------------------------------------------------------
// Streaming: constant memory.
// ------------------------------------------------------------------------------------------------

/// A slicer-like program generated line by line as it is read: per 10 lines a layer marker, a
/// feature marker, an M-code (7 kinds), a T word, a retraction, a travel, a zero-length
/// move, an un-retraction and two extruding moves.
struct Generated {
    lines: usize,
    next: usize,
    pending: Vec<u8>,
    offset: usize,
}

impl Generated {
    fn new(lines: usize) -> Self {
        Generated { lines, next: 0, pending: Vec::new(), offset: 0 }
    }

    fn line(i: usize) -> String {
        let k = i / 10;
        let x = (k % 100) as f64;
        match i % 10 {
            _ if i == 0 => "M83\n".to_string(),
            0 => format!(";LAYER:{k}\n"),
            1 => format!(";TYPE:feature {}\n", k % 3),
            2 => format!("M{} S1\n", 900 + k % 7),
            3 => "T0\n".to_string(),
            4 => "G1 E-1 F2100\n".to_string(),
            5 => "G1 X0 Y0 F7200\n".to_string(),
            6 => "G1 X0 Y0\n".to_string(),
            7 => "G1 E1 F2100\n".to_string(),
            8 => format!("G1 X{x:.1} Y50 E0.5 F1200\n"),
            _ => format!("G1 X{:.1} Y50 E0.05\n", x + 1.0),
        }
    }
}

impl Read for Generated {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.offset == self.pending.len() {
            if self.next == self.lines {
                return Ok(0);
            }
            self.pending = Generated::line(self.next).into_bytes();
            self.offset = 0;
            self.next += 1;
        }
        let n = buf.len().min(self.pending.len() - self.offset);
        buf[..n].copy_from_slice(&self.pending[self.offset..n + self.offset]);
        self.offset += n;
        Ok(n)
    }
}

/// Parses a generated program of `lines` lines and returns (segments, warnings, notes, peak heap bytes).
fn run_generated(lines: usize) -> (usize, Vec<Warning>, Vec<Warning>, isize) {
    let ((count, warnings, notes), peak) = peak_heap(|| {
        let options = GcodeOptions { start: mm(0.0, 0.0, 0.0), ..GcodeOptions::default() };
        let mut parser = Parser::new(BufReader::new(Generated::new(lines)), "generated", options);
        let mut count = 0;
        for item in &mut parser {
            let item = item.unwrap_or_else(|e| panic!("{e}"));
            std::hint::black_box(&item);
            count += 1;
        }
        (count, parser.warnings().to_vec(), parser.notes().to_vec())
    });
    (count, warnings, notes, peak)
}

#[test]
fn a_200000_line_program_streams_in_constant_memory() {
    let (_, _, _, small_peak) = run_generated(20_000);
    let (count, warnings, notes, peak) = run_generated(200_000);
    // Per 10 lines: 2 dwells, a travel and 2 moves; the first travel (from the start, 0) is zero-length.
    assert_eq!(count, 20_000 * 5 - 1);
    let kinds: Vec<&str> = warnings.iter().map(|w| w.kind.as_str()).collect();
    assert_eq!(kinds, ["M900", "T0", "M901", "M902", "M903", "M904", "M905", "M906"]);
    assert_eq!(warnings.iter().map(|w| w.count).sum::<u64>(), 2 * 20_000);
    assert_eq!(notes.len(), 1);
    assert_eq!(notes[0].count, 20_000 + 1);
    // Peak heap during the parse does not grow with the program.
    println!("peak heap while parsing: {small_peak} bytes for 20,000 lines, {peak} bytes for 200,000 lines");
    assert!(peak < 256 * 1024, "peak heap {peak} bytes");
    assert!(peak <= small_peak + 1024, "peak heap grew with length: {small_peak} → {peak} bytes");
}

// ------------------------------------------------------------------------------------------------
// Robustness: no panic on any input.
// ------------------------------------------------------------------------------------------------

fn run_to_end(bytes: Vec<u8>) {
    let parser = Parser::new(Cursor::new(bytes), "fuzz", GcodeOptions::default());
    // The parser ends after its first error, so flattening stops there.
    for g in parser.flatten().map(|s| s.segment) {
        assert!(g.end.iter().all(|v| v.is_finite()) && g.centre.iter().all(|v| v.is_finite()));
        assert!(g.sweep.is_finite() && g.duration.is_finite() && g.filament.is_finite() && g.feed.is_finite());
        assert!(segment_length(&Vector3::zeros(), &g).is_finite());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(lines in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..60), 0..20)) {
        run_to_end(lines.join(&b'\n'));
    }

    #[test]
    fn random_g_code_like_lines_never_panic(
        words in proptest::collection::vec(
            (proptest::sample::select(b"GMXYZEIJKRPFSTN;( )*%#".to_vec()), -3.0e3f64..3.0e3, 0u8..4),
            0..80,
        )
    ) {
        run_to_end(strand_testkit::gcode_from_words(&words));
    }
}
