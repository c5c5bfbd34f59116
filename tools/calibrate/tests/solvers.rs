//! Every solve on synthetic data made with the project's own FK (the bundled KR 6 R900 and LBR iiwa 7
//! URDFs through `strand_core::kin`): a known answer plus noise is recovered within the noise, and
//! degenerate touches are refused with a reason.

mod common;

use common::{Noise, frame, ik, kr6, kr6_home, robot};
use nalgebra::{Rotation3, Vector3};
use strand_calibrate::snapshots::{Snapshot, poses};
use strand_calibrate::{CalibrationError, extruder, frame as bed, handeye, tool};
use strand_core::kin::{Frame, JointVector, RobotModel, geom};

const DEG: f64 = std::f64::consts::PI / 180.0;

fn snapshot(model: &RobotModel, q: &JointVector) -> Snapshot {
    Snapshot { line: 0, joints: (0..model.dof()).map(|k| q[k]).collect() }
}

/// The angle (rad) between two rotations, robust where `angle_to` gives NaN (equal rotations).
fn angle(a: impl std::borrow::Borrow<Rotation3<f64>>, b: &Rotation3<f64>) -> f64 {
    geom::rotation_vector(&(a.borrow().inverse() * b)).norm()
}

fn is_degenerate(e: &CalibrationError, words: &str) -> bool {
    matches!(e, CalibrationError::Degenerate { reason } if reason.contains(words))
}

// ---------------------------------------------------------------------------------------------
// tool

/// The KR 6 with a hot end whose tip is at `xyz` and nozzle along `rpy`'s z.
struct ToolCase {
    t_xyz: [f64; 3],
    t_rpy: [f64; 3],
    point: Vector3<f64>,
    nominal: Rotation3<f64>,
}

impl ToolCase {
    fn new() -> Self {
        let (t_xyz, t_rpy) = ([0.1034, 0.0042, -0.0031], [0.0, 1.59, 0.02]);
        let with_tool = kr6().with_tool(frame(t_xyz, t_rpy)).unwrap();
        let home = with_tool.forward_kinematics(&kr6_home());
        ToolCase { t_xyz, t_rpy, point: home.translation.vector, nominal: home.rotation }
    }

    /// Joints that put the point `up` m up the nozzle (0: the tip) on the fixed point, the nozzle
    /// turned by `tilt` (in B) from its nominal orientation, the touch off by `noise` (m).
    fn touch(&self, tilt: &Rotation3<f64>, up: f64, noise: Vector3<f64>) -> (JointVector, Frame) {
        let t = frame(self.t_xyz, self.t_rpy) * frame([0.0, 0.0, -up], [0.0; 3]);
        let model = kr6().with_tool(t).unwrap();
        let target = Frame::from_parts((self.point + noise).into(), tilt * self.nominal);
        let q = ik(&model, &target, &kr6_home());
        (q, kr6().forward_kinematics(&q))
    }
}

fn tilts(angle: f64) -> Vec<Rotation3<f64>> {
    let ax = |x: f64, y: f64, z: f64, a: f64| geom::axis_angle(&Vector3::new(x, y, z).normalize(), a);
    vec![
        ax(1.0, 0.0, 0.0, angle),
        ax(1.0, 0.0, 0.0, -angle),
        ax(0.0, 1.0, 0.0, angle),
        ax(0.0, 1.0, 0.0, -angle),
        ax(1.0, 1.0, 0.0, angle) * ax(0.0, 0.0, 1.0, 0.6),
        ax(-1.0, 1.0, 0.0, angle) * ax(0.0, 0.0, 1.0, -0.6),
    ]
}

#[test]
fn the_tool_offset_and_the_point_are_recovered_exactly_without_noise() {
    let case = ToolCase::new();
    let flanges: Vec<Frame> = tilts(30.0 * DEG).iter().map(|r| case.touch(r, 0.0, Vector3::zeros()).1).collect();
    let fit = tool::solve_tcp(&flanges).unwrap();
    assert!((fit.xyz - Vector3::from(case.t_xyz)).norm() < 1e-9, "{:?}", fit.xyz);
    assert!((fit.point - case.point).norm() < 1e-9, "{:?}", fit.point);
    assert!(fit.residuals_mm.iter().all(|r| *r < 1e-6), "{:?}", fit.residuals_mm);
    assert!(fit.condition < 6.0 && fit.warnings.is_empty(), "{} {:?}", fit.condition, fit.warnings);
}

#[test]
fn the_tool_offset_is_recovered_within_the_touch_noise() {
    let case = ToolCase::new();
    let mut noise = Noise::new(7);
    let sigma = 0.1e-3 / 3f64.sqrt(); // 0.1 mm RMS touch error in 3-D
    let flanges: Vec<Frame> = tilts(30.0 * DEG).iter().map(|r| case.touch(r, 0.0, noise.vector(sigma)).1).collect();
    let fit = tool::solve_tcp(&flanges).unwrap();
    let err = (fit.xyz - Vector3::from(case.t_xyz)).norm();
    let point_err = (fit.point - case.point).norm();
    println!(
        "tool: error {:.3} mm, point {:.3} mm, residuals {:?} mm, condition {:.2}",
        err * 1e3,
        point_err * 1e3,
        fit.residuals_mm,
        fit.condition
    );
    // The offset within the noise times the condition (≈ 3.4 here): 0.1 mm × 3.4.
    assert!(err < 0.35e-3, "tool off by {} mm", err * 1e3);
    assert!(point_err < 0.35e-3, "point off by {} mm", point_err * 1e3);
    assert!(fit.residuals_mm.iter().all(|r| *r < 0.3), "{:?}", fit.residuals_mm);
    assert_eq!(fit.residuals_mm.len(), 6);
}

#[test]
fn touches_from_one_orientation_are_refused() {
    let case = ToolCase::new();
    let mut noise = Noise::new(3);
    let same = Rotation3::identity();
    let flanges: Vec<Frame> = (0..5).map(|_| case.touch(&same, 0.0, noise.vector(0.05e-3)).1).collect();
    let e = tool::solve_tcp(&flanges).unwrap_err();
    assert!(is_degenerate(&e, "too alike"), "{e}");
    assert!(e.to_string().contains("condition"), "{e}");
}

#[test]
fn touches_turned_about_the_nozzle_only_are_refused() {
    // Spinning about the nozzle through the point leaves the offset along the nozzle undetermined.
    let case = ToolCase::new();
    let nozzle = case.nominal * Vector3::z();
    let flanges: Vec<Frame> =
        [0.0, 40.0, 80.0, 120.0].iter().map(|a| case.touch(&geom::axis_angle(&nozzle, a * DEG), 0.0, Vector3::zeros()).1).collect();
    let e = tool::solve_tcp(&flanges).unwrap_err();
    assert!(is_degenerate(&e, "too alike"), "{e}");
}

#[test]
fn orientations_a_few_degrees_apart_solve_with_a_warning() {
    let case = ToolCase::new();
    let flanges: Vec<Frame> = tilts(3.0 * DEG).iter().map(|r| case.touch(r, 0.0, Vector3::zeros()).1).collect();
    let fit = tool::solve_tcp(&flanges).unwrap();
    assert!(fit.condition > tool::WARN_CONDITION && fit.condition < tool::MAX_CONDITION, "{}", fit.condition);
    assert_eq!(fit.warnings.len(), 1, "{:?}", fit.warnings);
    assert!((fit.xyz - Vector3::from(case.t_xyz)).norm() < 1e-8);
}

#[test]
fn fewer_than_four_touches_are_refused() {
    let case = ToolCase::new();
    let flanges: Vec<Frame> = tilts(30.0 * DEG)[..3].iter().map(|r| case.touch(r, 0.0, Vector3::zeros()).1).collect();
    assert_eq!(tool::solve_tcp(&flanges).unwrap_err(), CalibrationError::TooFew { what: "touches", needed: 4, got: 3 });
}

#[test]
fn the_nozzle_axis_is_recovered_from_two_touches_up_it() {
    let case = ToolCase::new();
    let true_z = geom::rpy(case.t_rpy[0], case.t_rpy[1], case.t_rpy[2]) * Vector3::z();
    let configured = geom::rpy(0.0, std::f64::consts::FRAC_PI_2, 0.0);
    for (seed, sigma, within_deg) in [(0u64, 0.0, 1e-6), (11, 0.05e-3, 0.5)] {
        let mut noise = Noise::new(seed.max(1));
        let ts = tilts(30.0 * DEG);
        let flanges: Vec<Frame> = ts.iter().map(|r| case.touch(r, 0.0, noise.vector(sigma)).1).collect();
        let fit = tool::solve_tcp(&flanges).unwrap();
        let axis: Vec<Frame> = [(0.02, &ts[0]), (0.04, &ts[2])].iter().map(|(up, r)| case.touch(r, *up, noise.vector(sigma)).1).collect();
        let a = tool::solve_axis(&fit, &axis, &configured).unwrap();
        let off = a.z.angle(&true_z) / DEG;
        println!("axis: σ {:.3} mm → {off:.4}° off, residuals {:?} mm", sigma * 1e3, a.residuals_mm);
        assert!(off < within_deg, "{off}°");
        // The rpy written turns z onto the axis.
        let r = geom::rpy(a.rpy[0], a.rpy[1], a.rpy[2]);
        assert!((r * Vector3::z() - a.z).norm() < 1e-9);
        assert!((a.change_deg - true_z.angle(&(configured * Vector3::z())) / DEG).abs() < within_deg.max(1e-6));
    }
    // An axis touch at the tip says nothing about the direction.
    let flanges: Vec<Frame> = tilts(30.0 * DEG).iter().map(|r| case.touch(r, 0.0, Vector3::zeros()).1).collect();
    let fit = tool::solve_tcp(&flanges).unwrap();
    let at_tip = [case.touch(&Rotation3::identity(), 0.001, Vector3::zeros()).1];
    assert!(is_degenerate(&tool::solve_axis(&fit, &at_tip, &configured).unwrap_err(), "up the nozzle"));
}

// ---------------------------------------------------------------------------------------------
// frame

/// Touches on a bed at `bed` (in B) at bed points `uv` (m), nozzle normal to the bed, each touch off
/// by `sigma` (m) along every axis; returns the TCP poses FK gives for the joints IK found.
fn bed_touches(bed: &Frame, uv: &[[f64; 3]], noise: &mut Noise, sigma: f64) -> Vec<Frame> {
    let model = kr6().with_tool(frame([0.1, 0.0, 0.0], [0.0, std::f64::consts::FRAC_PI_2, 0.0])).unwrap();
    let down = bed.rotation * geom::axis_angle(&Vector3::y(), std::f64::consts::PI);
    uv.iter()
        .map(|p| {
            let at = bed * nalgebra::Point3::new(p[0], p[1], p[2]);
            let target = Frame::from_parts((at.coords + noise.vector(sigma)).into(), down);
            let q = ik(&model, &target, &kr6_home());
            poses(&model, &[snapshot(&model, &q)]).unwrap()[0]
        })
        .collect()
}

fn nozzle(tcps: &[Frame]) -> Vector3<f64> {
    tcps.iter().map(|t| t.rotation * Vector3::z()).sum()
}

#[test]
fn the_bed_frame_is_recovered_from_three_points_and_from_more() {
    let truth = frame([0.5, -0.05, 0.2], [0.03, -0.02, 0.4]);
    let grid =
        [[0.0, 0.0, 0.0], [0.12, 0.0, 0.0], [0.02, 0.1, 0.0], [0.12, 0.1, 0.0], [0.06, 0.05, 0.0], [0.0, 0.1, 0.0], [0.1, 0.03, 0.0]];
    for (n, sigma, xyz_mm, rot_deg) in [(3usize, 0.0, 1e-6, 1e-6), (7, 0.0, 1e-6, 1e-6), (3, 0.05e-3, 0.2, 0.2), (7, 0.05e-3, 0.2, 0.1)] {
        let mut noise = Noise::new(5);
        let tcps = bed_touches(&truth, &grid[..n], &mut noise, sigma);
        let points: Vec<Vector3<f64>> = tcps.iter().map(|t| t.translation.vector).collect();
        let fit = bed::solve_frame(&points, Some(nozzle(&tcps))).unwrap();
        let xyz_err = (Vector3::from(fit.xyz) - truth.translation.vector).norm() * 1e3;
        let rot_err = angle(fit.rotation, &truth.rotation) / DEG;
        println!(
            "frame: {n} points, σ {:.3} mm: origin {xyz_err:.4} mm, rotation {rot_err:.4}°, flatness {:.3} mm",
            sigma * 1e3,
            fit.flatness_mm
        );
        assert!(xyz_err < xyz_mm, "{xyz_err} mm");
        assert!(rot_err < rot_deg, "{rot_err}°");
        // rpy is the rotation.
        assert!(angle(geom::rpy(fit.rpy[0], fit.rpy[1], fit.rpy[2]), &fit.rotation) < 1e-12);
        assert!(fit.flatness_mm < 6.0 * sigma * 1e3 + 1e-6, "{}", fit.flatness_mm);
        assert_eq!(fit.residuals_mm.len(), n);
    }
}

#[test]
fn a_warped_bed_shows_in_the_flatness() {
    let truth = frame([0.5, 0.0, 0.2], [0.0, 0.0, 0.0]);
    let grid = [[0.0, 0.0, 0.0], [0.12, 0.0, 0.0], [0.0, 0.1, 0.0], [0.12, 0.1, 0.0], [0.06, 0.05, 0.0008]];
    let tcps = bed_touches(&truth, &grid, &mut Noise::new(1), 0.0);
    let points: Vec<Vector3<f64>> = tcps.iter().map(|t| t.translation.vector).collect();
    let fit = bed::solve_frame(&points, Some(nozzle(&tcps))).unwrap();
    // A 0.8 mm bump among four corners: the plane takes a fifth of it, peak to valley all of it.
    assert!((fit.flatness_mm - 0.8).abs() < 1e-6, "{}", fit.flatness_mm);
}

#[test]
fn three_collinear_points_are_refused() {
    let truth = frame([0.5, 0.0, 0.2], [0.0, 0.0, 0.3]);
    let tcps = bed_touches(&truth, &[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.15, 0.0005, 0.0]], &mut Noise::new(1), 0.0);
    let points: Vec<Vector3<f64>> = tcps.iter().map(|t| t.translation.vector).collect();
    for n in [3, 4] {
        let e = bed::solve_frame(&points[..n], Some(nozzle(&tcps))).unwrap_err();
        assert!(is_degenerate(&e, "collinear"), "{e}");
    }
    // The +y point on the wrong side would turn the bed upside down.
    let tcps = bed_touches(&truth, &[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.05, -0.08, 0.0]], &mut Noise::new(1), 0.0);
    let points: Vec<Vector3<f64>> = tcps.iter().map(|t| t.translation.vector).collect();
    let e = bed::solve_frame(&points, Some(nozzle(&tcps))).unwrap_err();
    assert!(is_degenerate(&e, "other side"), "{e}");
    // An x point on the origin.
    let e = bed::solve_frame(&[points[0], points[0], points[2]], None).unwrap_err();
    assert!(is_degenerate(&e, "+x point"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// hand–eye

fn iiwa() -> RobotModel {
    robot("iiwa7", "world", "iiwa_link_ee")
}

fn iiwa_pose(noise: &mut Noise, spread: f64, only: Option<usize>) -> JointVector {
    let nominal = [0.0, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0];
    let mut q = JointVector::zeros();
    for k in 0..7 {
        let vary = only.is_none_or(|j| j == k);
        q[k] = nominal[k] + if vary { (noise.uniform() * 2.0 - 1.0) * spread } else { 0.0 };
    }
    q
}

/// Flange poses and the marker poses the tracker would see (with noise).
fn hand_eye_data(n: usize, only: Option<usize>, sigma_m: f64, sigma_rad: f64, z: &Frame, x: &Frame) -> (Vec<Frame>, Vec<Frame>) {
    let model = iiwa();
    let mut noise = Noise::new(17);
    let mut flanges = Vec::new();
    let mut markers = Vec::new();
    for _ in 0..n {
        let q = iiwa_pose(&mut noise, 0.6, only);
        let f = model.forward_kinematics(&q);
        let c = z * f * x;
        let c = Frame::from_parts((c.translation.vector + noise.vector(sigma_m)).into(), noise.rotation(sigma_rad) * c.rotation);
        flanges.push(f);
        markers.push(c);
    }
    (flanges, markers)
}

#[test]
fn the_base_is_recovered_by_hand_eye_within_the_tracker_noise() {
    let z = frame([1.5, -0.7, 0.05], [0.01, -0.02, 2.5]);
    let x = frame([0.03, -0.02, 0.09], [0.4, -0.3, 1.1]);
    for (sigma_m, sigma_deg, mm, deg) in [(0.0, 0.0, 1e-6, 1e-6), (0.1e-3, 0.05, 1.0, 0.1)] {
        let (flanges, markers) = hand_eye_data(12, None, sigma_m, sigma_deg * DEG, &z, &x);
        let fit = handeye::solve_hand_eye(&flanges, &markers).unwrap();
        let mount_mm = (fit.mount.translation.vector - z.translation.vector).norm() * 1e3;
        let mount_deg = angle(fit.mount.rotation, &z.rotation) / DEG;
        let hand_mm = (fit.hand.translation.vector - x.translation.vector).norm() * 1e3;
        let hand_deg = angle(fit.hand.rotation, &x.rotation) / DEG;
        println!(
            "hand-eye: σ {:.2} mm {sigma_deg}°: mount {mount_mm:.4} mm {mount_deg:.4}°, marker {hand_mm:.4} mm {hand_deg:.4}°, condition {:.2}, residuals {:?} mm",
            sigma_m * 1e3,
            fit.condition,
            fit.residuals_mm
        );
        assert!(mount_mm < mm && hand_mm < mm, "{mount_mm} {hand_mm}");
        assert!(mount_deg < deg && hand_deg < deg, "{mount_deg} {hand_deg}");
        assert_eq!(fit.residuals_mm.len(), 12);
        assert!(fit.residuals_mm.iter().all(|r| *r < 1.0), "{:?}", fit.residuals_mm);
        assert!(angle(geom::rpy(fit.mount_rpy[0], fit.mount_rpy[1], fit.mount_rpy[2]), &z.rotation) < deg * DEG);
    }
}

#[test]
fn hand_eye_motions_about_one_axis_are_refused() {
    let z = frame([1.5, -0.7, 0.05], [0.01, -0.02, 2.5]);
    let x = frame([0.03, -0.02, 0.09], [0.4, -0.3, 1.1]);
    // Only the last joint (the flange's spin) or only the first (about the base's z) moves.
    for only in [6, 0] {
        let (flanges, markers) = hand_eye_data(8, Some(only), 0.1e-3, 0.05 * DEG, &z, &x);
        let e = handeye::solve_hand_eye(&flanges, &markers).unwrap_err();
        assert!(is_degenerate(&e, "one axis"), "joint {only}: {e}");
    }
    let (flanges, markers) = hand_eye_data(3, None, 0.0, 0.0, &z, &x);
    assert!(matches!(handeye::solve_hand_eye(&flanges, &markers).unwrap_err(), CalibrationError::TooFew { .. }));
}

// ---------------------------------------------------------------------------------------------
// extruder

#[test]
fn the_drive_wheel_radius_is_rescaled_by_measured_over_commanded() {
    let fit = extruder::rescale(5.5e-3, 50e-3, 47.5e-3).unwrap();
    assert!((fit.drive_wheel_radius - 5.225e-3).abs() < 1e-15, "{}", fit.drive_wheel_radius);
    assert!((fit.ratio - 0.95).abs() < 1e-15);
    // The rescaled drive moves what it is told: a motor angle of 50 mm / r_new gives 50 mm on the
    // wheel that measured 47.5 for 50.
    let wheel = 5.5e-3 * 0.95;
    assert!((50e-3 / fit.drive_wheel_radius * wheel - 50e-3).abs() < 1e-15);
    for (c, m) in [(0.0, 0.05), (0.05, -1.0), (0.05, f64::NAN), (0.05, 0.5)] {
        assert!(matches!(extruder::rescale(5.5e-3, c, m), Err(CalibrationError::BadValue { .. })), "{c} {m}");
    }
}
