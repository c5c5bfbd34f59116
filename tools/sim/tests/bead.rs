//! The bead (`strand_replay::bead`) and the calibration of the hot end's and the arm's lags
//! (`strand_replay::bead::calibrate`) measured on the sim's plant: the controller and the sim in one
//! loop, no processes, so the truth is exact and the runs are short.

/// The controller and the sim in one loop, no processes: a job run on the plant, for tests of the
/// bead and its calibration.
mod closed_loop {
    use std::path::Path;

    use strand::config::Config;
    use strand_core::{Controller, MAX_SEGMENTS_PER_TICK, TickInput};
    use strand_ipc::{self as ipc, Command, JobOutcome};

    use strand_replay::bead::{Executing, asked_sections};
    use strand_replay::truth::Truth;
    use strand_sim::Sim;
    use strand_sim::config::SimConfig;

    /// A short program with what a bead goes through: a retraction before the first travel and
    /// its prime, speed changes at corners, a travel with a retraction between two beads.
    pub(crate) const PROGRAM: &str = "G21\nG90\nM83\nG1 Z0.3 F3000\nG1 E-1 F2100\nG1 X100 Y100 F6000\nG1 E1 F2100\n\
        G1 X130 Y100 E1.2 F1800\nG1 X130 Y115 E0.6 F1200\nG1 X100 Y115 E1.2 F2400\nG1 E-1 F2100\n\
        G1 X100 Y130 F6000\nG1 E1 F2100\nG1 X130 Y130 E1.2 F1500\nG1 X130 Y120 E0.4 F1500\n";

    /// What a run gave: the ticks, the program's sections, the truth, the commanded filament rate
    /// per tick (m/s) and the tick (ns).
    pub(crate) struct Run {
        pub ticks: Vec<Executing>,
        pub sections: std::collections::HashMap<u64, f64>,
        pub truth: Vec<Truth>,
        pub commanded: Vec<f64>,
        pub dt_ns: u64,
    }

    pub(crate) fn root() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    /// Runs `program` on the default cell with `cfg` and the plant `sim_cfg` until the job ends.
    pub(crate) fn run(program: &str, cfg: &Config, sim_cfg: &SimConfig) -> Run {
        let dir = std::env::temp_dir().join(format!("strand-bead-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join(format!("job-{:x}.gcode", program.len() ^ (cfg.extruder.pressure_advance * 1e6) as usize));
        std::fs::write(&file, program).unwrap();
        let job = strand_feed::load_gcode(&file, cfg, None).unwrap();
        let _ = std::fs::remove_file(&file);
        let start = cfg.service.initial_joints.clone();
        let mut sim = Sim::new(cfg, sim_cfg, &start, 1_000_000_000).unwrap();
        let model = cfg.robot.build_model().unwrap();
        let mut ctl = Controller::new(&cfg.controller_settings(), model).unwrap();
        let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
        let filament_area = std::f64::consts::PI * 0.25 * cfg.extruder.filament_diameter.powi(2);
        let mut out = Run {
            ticks: Vec::new(),
            sections: asked_sections(&job.segments, filament_area),
            truth: Vec::new(),
            commanded: Vec::new(),
            dt_ns,
        };
        let mut sent = 0;
        let (mut pose_seq, mut poses) = (0u64, Vec::new());
        let start_tick = if cfg.base.mode == strand_core::BaseMode::Tracked { 200 } else { 1 };
        for tick in 0..200_000u64 {
            // Tracking first, as strand-sim sends it (a tracked base's samples; none for a fixed one).
            poses.clear();
            sim.base_poses(&mut pose_seq, &mut poses);
            let js = sim.joint_state(tick + 1);
            let mut input = TickInput::new(tick, js.stamp_ns);
            input.joint_state = Some(js);
            for p in &poses {
                input.push_base_pose(p);
            }
            while sent < job.segments.len()
                && (input.segment_count as usize) < MAX_SEGMENTS_PER_TICK
                && input.push_segment(&job.segments[sent])
            {
                sent += 1;
            }
            // On a tracked base the job starts once tracking has had time to come (a start with
            // no base pose yet is a TrackingLost fault, as it should be).
            if tick == start_tick {
                input.push_control(&ipc::Control {
                    seq: 1,
                    stamp_ns: js.stamp_ns,
                    command: Command::Start as u32,
                    value: 0.0,
                    _reserved: 0,
                });
            }
            let o = ctl.step(&input);
            sim.command_joints(&o.joint_command);
            sim.command_extruder(&o.extruder);
            out.truth.push(sim.step());
            out.commanded.push(o.extruder.filament_rate);
            let s = &o.status;
            out.ticks.push(Executing::of(input.time_ns, &o));
            if tick > 10 && s.job_outcome != JobOutcome::InProgress as u32 {
                assert_eq!(s.job_outcome, JobOutcome::Finished as u32, "the job finishes (fault {}, tick {tick})", s.fault);
                // The melt still on its way.
                for _ in 0..500 {
                    out.truth.push(sim.step());
                }
                return out;
            }
        }
        panic!("the job did not end");
    }

    pub(crate) fn configs() -> (Config, SimConfig) {
        (Config::load(&root().join("config/default.toml")).unwrap(), SimConfig::load(&root().join("config/sim/default.toml")).unwrap())
    }
}

mod bead {
    use super::closed_loop::{PROGRAM, configs, run};
    use strand_replay::bead::*;

    fn bead_of(cfg_change: impl FnOnce(&mut strand::config::Config)) -> Bead {
        let (mut cfg, sim) = configs();
        cfg_change(&mut cfg);
        let r = run(PROGRAM, &cfg, &sim);
        measure_run(&r.ticks, &r.sections, &r.truth, r.dt_ns, None)
    }

    /// The compensation the bundled configs ship (pressure advance with the motor's second-order
    /// term, smoothing, the arm's delay) against none, on the sim's plant: the bead is within 10 %
    /// everywhere with it, and is not without it.
    #[test]
    fn compensation_makes_the_bead_match_the_program_and_without_it_it_does_not() {
        let on = bead_of(|_| {});
        let off = bead_of(|c| {
            c.extruder.pressure_advance = 0.0;
            c.extruder.motor_lag = 0.0;
            c.extruder.motion_delay = 0.0;
            c.extruder.pressure_advance_smooth_time = 0.0;
        });
        eprintln!("on  {:?} blobs {:.4} strings {:.4}", on.all, on.blob_share(), on.string_share());
        eprintln!("off {:?} blobs {:.4} strings {:.4}", off.all, off.blob_share(), off.string_share());
        assert!(on.all.bins > 80, "{} bins", on.all.bins);
        assert_eq!(on.all.bins, off.all.bins);
        assert!(on.all.beyond_10pct == 0.0 && on.all.p95 < 0.03, "with compensation: {:?}", on.all);
        assert!(on.blob_share() < 0.002 && on.string_share() < 0.002, "blobs {} strings {}", on.blob_share(), on.string_share());
        assert!(off.all.beyond_10pct > 0.05 && off.all.p95 > 0.10, "without: {:?}", off.all);
        assert!(off.blob_share() > 0.001 && off.blob_share() > 10.0 * on.blob_share(), "blobs without: {}", off.blob_share());
    }

    /// The free flyer (`config/free-flyer.toml` on its plant, `config/sim/free-flyer.toml`): four
    /// 100 mm lines at the truss's 3.33 mm/s, where no flow changes and the bead's error is the
    /// nozzle surging along its path as the arm follows the base estimate, tracker noise included.
    /// The shipped estimator gain (α 0.04, set for the bead) against the gain it replaced (α 0.1,
    /// set for the TCP error alone).
    #[test]
    fn on_the_free_flyer_the_shipped_base_estimator_keeps_tracker_noise_out_of_the_bead() {
        const LINES: &str = "G21\nG90\nM83\nG0 X0 Y0 Z1 F3000\nG1 F199.8\nG1 X100 Y0 E17.72853\nG1 X100 Y10 E1.77285\n\
            G1 X0 Y10 E17.72853\nG1 X0 Y20 E1.77285\nG1 X100 Y20 E17.72853\nG1 X100 Y30 E1.77285\nG1 X0 Y30 E17.72853\n";
        let root = super::closed_loop::root();
        let cfg = strand::config::Config::load(&root.join("config/free-flyer.toml")).unwrap();
        let sim = strand_sim::config::SimConfig::load(&root.join("config/sim/free-flyer.toml")).unwrap();
        let bead = |alpha: f64, beta: f64| {
            let mut cfg = cfg.clone();
            cfg.base.alpha = alpha;
            cfg.base.beta = beta;
            let r = run(LINES, &cfg, &sim);
            measure_run(&r.ticks, &r.sections, &r.truth, r.dt_ns, None)
        };
        let shipped = bead(cfg.base.alpha, cfg.base.beta);
        let before = bead(0.1, 0.0025);
        eprintln!("shipped {:?}", shipped.all);
        eprintln!("before  {:?}", before.all);
        assert!(shipped.all.bins > 200, "{} bins", shipped.all.bins);
        assert!(shipped.all.beyond_10pct < 0.04 && shipped.all.p95 < 0.095, "shipped: {:?}", shipped.all);
        assert!(before.all.beyond_10pct > 0.06 && before.all.p95 > 0.11, "α 0.1: {:?}", before.all);
    }
}

mod calibrate {
    use super::closed_loop::{PROGRAM, configs, run};
    use strand_replay::bead::calibrate::*;

    /// The plant's lags found again from a run on it, at the shipped value and 30 % off it.
    #[test]
    fn the_hot_end_and_the_arm_delay_are_found_from_a_run() {
        for melt in [0.08, 0.104, 0.056] {
            let (cfg, mut sim) = configs();
            sim.extruder.melt_lag = melt;
            let r = run(PROGRAM, &cfg, &sim);
            let area = std::f64::consts::PI * 0.25 * cfg.extruder.filament_diameter.powi(2);
            let flow: Vec<f64> = r.truth.iter().map(|t| t.flow_actual).collect();
            let dt = r.dt_ns as f64 * 1e-9;
            let hot = melt_lag(&r.commanded, &flow, area, dt);
            assert!((hot.melt_lag_s / melt - 1.0).abs() < 0.02, "melt lag {} for {melt}", hot.melt_lag_s);
            assert!((hot.motor_lag_s - sim.extruder.motor_lag).abs() < 1e-3, "motor lag {}", hot.motor_lag_s);
            assert!(hot.rms_relative < 0.01, "{hot:?}");
            let delay = path_delay_ticks(&r.ticks, &r.truth, r.dt_ns) as f64 * dt;
            let cal = Calibration::new(hot, delay, dt);
            assert!((cal.motion_delay - cfg.extruder.motion_delay).abs() < 1.5e-3, "{cal:?}");
        }
    }
}

/// The bed mesh end to end (DAYONE item 3): the sim's bed tilted and warped, probed (a probe's
/// points, with noise) into `[bed.mesh]` by `strand calibrate mesh`'s fit, and a first layer
/// printed on it with the mesh and without: on the truth, the nozzle's height above the real
/// surface while it extrudes.
mod bed_mesh {
    use super::closed_loop::{configs, run};
    use nalgebra::Vector3;
    use strand_calibrate::mesh::{MeshGrid, solve_mesh};
    use strand_core::{BedMeshConfig, MeshAlgorithm};
    use strand_sim::config::BedSurfaceConfig;

    /// The true bed (m above the config's bed plane, bed frame): 0.4 mm of tilt across 100 mm of x,
    /// 0.15 mm across y, and a 0.25 mm saddle-and-bowl warp.
    fn truth(x: f64, y: f64) -> f64 {
        let (u, v) = ((x - 0.12) / 0.06, (y - 0.115) / 0.05);
        4e-3 * (x - 0.12) - 1.5e-3 * (y - 0.115) + 0.15e-3 * (u * u + v * v) - 0.1e-3 * u * v + 0.05e-3 * (3.0 * u).sin()
    }

    /// A first layer (0.3 mm) of lines across the probed area, and a travel between each.
    fn first_layer() -> String {
        let mut g = String::from("G21\nG90\nM83\nG1 Z0.3 F3000\nG1 X90 Y95 F6000\n");
        for k in 0..5 {
            let y = 95.0 + 10.0 * k as f64;
            let (from, to) = if k % 2 == 0 { (90.0, 150.0) } else { (150.0, 90.0) };
            g.push_str(&format!("G1 X{from} Y{y} F6000\nG1 X{to} Y{y} E2.4 F2400\n"));
        }
        g
    }

    /// Worst |nozzle height above the true bed − 0.3 mm| (m) while extruding, and the count of rows.
    fn first_layer_error(cfg: &strand::config::Config, sim: &strand_sim::config::SimConfig) -> (f64, usize) {
        let r = run(&first_layer(), cfg, sim);
        let rows: Vec<f64> =
            r.truth.iter().zip(&r.commanded).filter(|(_, rate)| **rate > 0.0).map(|(t, _)| (t.bed_gap - 0.3e-3).abs()).collect();
        (rows.iter().copied().fold(0.0, f64::max), rows.len())
    }

    #[test]
    fn a_probed_mesh_takes_a_warped_tilted_bed_out_of_the_first_layer() {
        let (mut cfg, mut sim) = configs();
        // The sim's bed: the truth on a 25 × 21 grid (2.5 mm), wider than the print.
        let (min, max) = ([0.06, 0.065], [0.18, 0.165]);
        let points = (0..21).map(|j| (0..25).map(|i| truth(min[0] + 0.005 * i as f64, min[1] + 0.005 * j as f64)).collect()).collect();
        sim.bed = Some(BedSurfaceConfig { min, max, points });
        let (warped, rows) = first_layer_error(&cfg, &sim);
        // A probe's points: a 5 × 5 grid over the print's area, each with up to 5 µm of noise.
        let probes: Vec<Vector3<f64>> = (0..25)
            .map(|k| {
                let (x, y) = (0.085 + 0.0175 * (k % 5) as f64, 0.09 + 0.0125 * (k / 5) as f64);
                Vector3::new(x, y, truth(x, y) + 5e-6 * ((k as f64 * 1.7).sin()))
            })
            .collect();
        let fit = solve_mesh(&probes, MeshGrid { algorithm: MeshAlgorithm::Bicubic, counts: [5, 5], bounds: None }).unwrap();
        cfg.bed.mesh = Some(BedMeshConfig {
            min: fit.min,
            max: fit.max,
            points: fit.points,
            algorithm: MeshAlgorithm::Bicubic,
            fade_start: 1e-3,
            fade_end: 10e-3,
            fade_target: None,
        });
        let (meshed, meshed_rows) = first_layer_error(&cfg, &sim);
        eprintln!(
            "first layer height error: {:.3} mm on the warped bed, {:.3} mm with the mesh ({rows} and {meshed_rows} rows)",
            warped * 1e3,
            meshed * 1e3
        );
        assert!(rows > 5000 && meshed_rows > 5000, "{rows} {meshed_rows}");
        assert!(warped > 0.25e-3, "the warp shows without the mesh: {warped}");
        assert!(meshed <= 0.05e-3, "with the mesh the first layer is within 0.05 mm of its height: {meshed}");
    }
}
