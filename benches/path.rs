//! Path engine costs: one tick of sampling while cruising (no re-plan), one tick through a curve of
//! short segments (re-plans included), and planning throughput (segments through the lookahead).

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{UnitQuaternion, Vector3};
use strand_core::{PathConfig, PathEngine, Segment, SegmentKind};

fn line(seq: u64, end: Vector3<f64>) -> Segment {
    Segment { seq, kind: SegmentKind::Line, end, feed: 0.04, orientation: UnitQuaternion::identity(), ..Segment::default() }
}

fn circle_segments(n: usize, first: u64) -> Vec<Segment> {
    (0..n)
        .map(|k| {
            let th = (k + 1) as f64 * 0.08; // 5 mm radius, 0.4 mm chords
            line(first + k as u64, Vector3::new(0.005 * th.cos() - 0.005, 0.005 * th.sin(), 1e-5 * k as f64))
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let config = PathConfig { queue_capacity: 4096, ..PathConfig::default() };
    c.bench_function("path_tick_cruise", |b| {
        let mut e = PathEngine::new(&config, 1e-3, Vector3::zeros(), UnitQuaternion::identity()).unwrap();
        e.push(&line(1, Vector3::new(1000.0, 0.0, 0.0))).unwrap();
        for _ in 0..1000 {
            e.step(1.0);
        }
        b.iter(|| std::hint::black_box(e.step(1.0)));
    });
    c.bench_function("path_tick_curve", |b| {
        let mut e = PathEngine::new(&config, 1e-3, Vector3::zeros(), UnitQuaternion::identity()).unwrap();
        let segments = circle_segments(2_000_000, 1);
        let mut next = 0;
        b.iter(|| {
            while e.free_space() > 0 && next < segments.len() {
                e.push(&segments[next]).unwrap();
                next += 1;
            }
            std::hint::black_box(e.step(1.0))
        });
    });
    c.bench_function("path_plan_1000_segments", |b| {
        let segments = circle_segments(1000, 1);
        b.iter(|| {
            let mut e = PathEngine::new(&config, 1e-3, Vector3::zeros(), UnitQuaternion::identity()).unwrap();
            for s in &segments {
                e.push(s).unwrap();
            }
            std::hint::black_box(e.step(1.0))
        });
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
