//! Diagnosis tool for the path engine's speed caps on real slicer files.
//!
//! `cargo run --release --example centripetal_probe -- [--window N] FILE...` runs each G-code
//! file through the lookahead engine with config/default.toml at its controller rate (as
//! `strand-plan time`, without the extruder) and prints: segments, duration, feed-rate bound and
//! their ratio, forced brakes, the highest centripetal acceleration |acc − (acc·t)t| and the
//! number of ticks over the limit. With `--window N` it also prints the N ticks either side of
//! the worst one: source line, speed, path acceleration, centripetal acceleration, the current
//! piece's cap and blend radius, and the executor's plan (`brake→v` is a forced brake).
//!
//! Lines the parser does not take yet (`M115 U…`, `G28 W`, `M84 X Y E`) are blanked so that every
//! corpus file runs; line numbers are kept.

use std::collections::VecDeque;
use std::io::Cursor;
use std::path::PathBuf;

use strand::config::Config;
use strand_core::{PathEngine, SegmentFlags, SegmentKind};
use strand_job::bed::BedTransform;
use strand_job::gcode::{GcodeOptions, Parser, segment_length};

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let config = Config::load(&root.join("config/default.toml")).unwrap_or_else(|e| panic!("{e}"));
    let mut window = 0usize;
    let mut files = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--window" {
            window = args.next().and_then(|n| n.parse().ok()).expect("--window N");
        } else {
            files.push(PathBuf::from(a));
        }
    }
    println!("{:<40} {:>6} {:>8} {:>8} {:>6} {:>6} {:>7} {:>6}", "file", "segs", "time s", "bound s", "ratio", "brakes", "max ac", "over");
    for file in files {
        probe(&config, &file, window);
    }
}

fn probe(config: &Config, file: &PathBuf, window: usize) {
    let text = std::fs::read_to_string(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let text: String = text
        .lines()
        .map(|l| {
            let t = l.trim_start();
            if t.starts_with("M115") || t.starts_with("G28 W") || t.starts_with("M84") { ";" } else { l }
        })
        .flat_map(|l| [l, "\n"])
        .collect();
    let name = file.display().to_string();
    let mut parser = Parser::new(Cursor::new(text), &name, GcodeOptions::default());
    let bed = BedTransform::new(&config.bed).unwrap();
    let path = &config.path;
    let dt = 1.0 / config.controller.rate_hz;
    let start = bed.point(&nalgebra::Vector3::zeros());
    let mut engine = PathEngine::new(path, dt, start, bed.tool_orientation()).unwrap();
    let mut last_end = start;
    let mut pending = None;
    let mut done_feeding = false;
    let (mut segments, mut bound) = (0u64, 0.0);
    let mut tick = 0u64;
    let mut recent: VecDeque<String> = VecDeque::new();
    let (mut worst, mut worst_window, mut after) = (0.0f64, Vec::<String>::new(), 0usize);
    let mut over = 0u64;
    let mut brakes_before = 0;
    loop {
        while !done_feeding && engine.free_space() > 0 {
            let next = pending.take().or_else(|| parser.next());
            let Some(next) = next else {
                done_feeding = true;
                break;
            };
            let g = next.unwrap_or_else(|e| panic!("{e}"));
            let mut segment = bed.segment(&g.segment);
            let peek = parser.next();
            if peek.is_none() {
                segment.flags = segment.flags.with(SegmentFlags::LAST);
            }
            pending = peek;
            let length = segment_length(&last_end, &segment);
            engine.push(&segment).unwrap_or_else(|e| panic!("line {}: {e}", g.line));
            if segment.kind == SegmentKind::Dwell || length >= 1e-9 || segment.flags.contains(SegmentFlags::LAST) {
                segments += 1;
                bound += match segment.kind {
                    SegmentKind::Dwell => segment.duration,
                    _ => length / segment.feed.min(path.max_speed),
                };
                last_end = segment.end;
            }
        }
        engine.release_wait(); // heat waits: no heaters here
        let s = engine.step(1.0);
        tick += 1;
        let mut ac = 0.0;
        if s.speed > 1e-9 {
            let t = s.velocity / s.speed;
            ac = (s.acceleration - t * s.acceleration.dot(&t)).norm();
        }
        if ac > path.centripetal_acceleration * (1.0 + 1e-6) {
            over += 1;
        }
        if window > 0 {
            let (plan, cap, radius) = engine.debug_plan();
            let brakes = engine.stats().forced_brakes;
            let line = format!(
                "{tick:>9} L{:<6} v {:8.5} a {:8.4} ac {:7.4} cap {:8.5} r {:10.3e} {}{plan}",
                s.source_line,
                s.speed,
                s.path_acceleration,
                ac,
                cap,
                radius,
                if brakes > brakes_before { "FORCED " } else { "" }
            );
            brakes_before = brakes;
            if ac > worst {
                worst = ac;
                worst_window = recent.iter().cloned().collect();
                worst_window.push(format!("{line}   <== worst"));
                after = window;
            } else if after > 0 {
                worst_window.push(line.clone());
                after -= 1;
            }
            recent.push_back(line);
            if recent.len() > window {
                recent.pop_front();
            }
        } else {
            worst = worst.max(ac);
        }
        if done_feeding && pending.is_none() && engine.is_at_rest() {
            break;
        }
        assert!(tick < 100_000_000, "{name}: no end");
    }
    let duration = tick as f64 * dt;
    let short = file.strip_prefix(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/gcode")).unwrap_or(file);
    println!(
        "{:<40} {:>6} {:>8.1} {:>8.1} {:>6.3} {:>6} {:>9.6} {:>6}",
        short.display(),
        segments,
        duration,
        bound,
        duration / bound,
        engine.stats().forced_brakes,
        worst,
        over
    );
    for l in worst_window {
        println!("    {l}");
    }
}
