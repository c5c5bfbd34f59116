//! What a positioner costs a tick: `Controller::step` on the KR 6 of `cells/kr6-turntable` printing
//! the same 30 mm helix twice — once with the table turning under it (each segment carries the
//! table's angle: the work is carried, the arm nearly still), once in a fixed cell with the arm
//! going round it (the table left at rest: the same points in W, no axes). The difference is
//! the external axes' share: the axes in the path engine, the work's motion and its derivative
//! (`Positioner::carry`, two extra FK of the table's chain per moving axis), one more joint in
//! the final stage.

use criterion::{Criterion, criterion_group, criterion_main};
use strand::config::Config;
use strand_core::{Controller, TickInput};
use strand_ipc::{self as ipc, segment_flags};

const DOWN: [f64; 4] = [0.0, 0.0, 1.0, 0.0];

/// A travel, then `turns` turns of the helix around the table's axis (0.7, 0) m, 5° a line: with
/// `carried`, the points on the part at home and the table's angle turning each back beside the
/// table; without, the nozzle going round in W.
fn helix(carried: bool, turns: usize) -> Vec<ipc::Segment> {
    let point = |a: f64, z: f64| [0.7 + 0.03 * (std::f64::consts::PI + a).cos(), 0.03 * (std::f64::consts::PI + a).sin(), 0.2503 + z];
    let segment = |seq: u64, end: [f64; 3], table: f64, filament: f64| ipc::Segment {
        seq,
        kind: ipc::SegmentKind::Line as u32,
        flags: if carried { segment_flags::AXES } else { 0 } | if filament > 0.0 { segment_flags::EXTRUDE } else { segment_flags::TRAVEL },
        end,
        orientation: DOWN,
        feed: 0.02,
        filament,
        axes: if carried { [table, 0.0] } else { [0.0; 2] },
        ..Default::default()
    };
    let mut job = vec![segment(1, point(0.0, 0.005), 0.0, 0.0), segment(2, point(0.0, 0.0), 0.0, 0.0)];
    for k in 1..=turns * 72 {
        let a = (k as f64 * 5.0).to_radians();
        job.push(segment(job.len() as u64 + 1, point(a, 3e-4 * a / std::f64::consts::TAU), -a, 1e-4));
    }
    job.last_mut().unwrap().flags |= segment_flags::LAST;
    job
}

/// A controller of the turntable cell with the job queued and started, the robot following its
/// commands exactly; `step` runs one tick.
struct Cell {
    ctl: Controller,
    q: [f64; 8],
    dof: u32,
    tick: u64,
    job: Vec<ipc::Segment>,
    next: usize,
}

impl Cell {
    fn new(cfg: &Config, carried: bool) -> Cell {
        let ctl = cfg.robot.build_controller(&cfg.controller_settings()).unwrap();
        let mut q = [0.0; 8];
        q[..6].copy_from_slice(&cfg.service.initial_joints[..6]);
        let dof = ctl.cell_dof() as u32;
        Cell { ctl, q, dof, tick: 0, job: helix(carried, 40), next: 0 }
    }

    fn step(&mut self) {
        let mut input = TickInput::new(self.tick, 1_000_000_000 + self.tick * 4_000_000);
        input.joint_state =
            Some(ipc::JointState { seq: self.tick + 1, stamp_ns: input.time_ns, dof: self.dof, position: self.q, ..Default::default() });
        while self.next < self.job.len() && input.segment_room() > 0 && self.ctl.engine().free_space() > 64 {
            input.push_segment(&self.job[self.next]);
            self.next += 1;
        }
        if self.tick == 1 {
            input.push_control(&ipc::Control {
                seq: 1,
                stamp_ns: input.time_ns,
                command: ipc::Command::Start as u32,
                value: 0.0,
                _reserved: 0,
            });
        }
        let out = self.ctl.step(&input);
        self.q = out.joint_command.position;
        self.tick += 1;
    }
}

fn bench(c: &mut Criterion) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let turntable = Config::load(&root.join("config/cells/kr6-turntable.toml")).unwrap();
    let mut fixed = Config::load(&root.join("config/kr6r900.toml")).unwrap();
    // The same path limits as the turntable cell, so both print at the same speed.
    fixed.path = turntable.path.clone();
    for (name, cfg, carried) in
        [("controller_step/helix_table_turning", &turntable, true), ("controller_step/helix_arm_going_round", &fixed, false)]
    {
        c.bench_function(name, |b| {
            let mut cell = Cell::new(cfg, carried);
            // Past the approach and onto the helix (4 s of robot time).
            for _ in 0..1000 {
                cell.step();
            }
            b.iter(|| cell.step());
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
