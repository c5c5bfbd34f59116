//! Loading robots: the five bundled URDFs, folding of fixed joints, and errors that name the file and
//! the element (URDF) or the key (config).

mod common;

use std::path::Path;

use common::{ROBOTS, jv, robot};
use strand::config::{Config, RobotConfig};
use strand_core::kin::{JointKind, ModelError, RobotModel};

#[test]
fn the_bundled_robots_load_with_their_chains() {
    let expect = [
        ("iiwa7", 7, "iiwa_joint_1"),
        ("iiwa14", 7, "iiwa_joint_1"),
        ("vp6242", 6, "joint1"),
        ("meca500", 6, "meca_axis_1_joint"),
        ("irb140", 6, "joint_1"),
        ("kr6r900", 6, "joint_a1"),
        ("ur5e", 6, "shoulder_pan_joint"),
    ];
    for ((name, dof, first), listed) in expect.iter().zip(ROBOTS) {
        assert_eq!(*name, listed);
        let m = robot(name);
        assert_eq!(m.dof(), *dof, "{name}");
        assert_eq!(m.joints()[0].name, *first);
        for j in m.joints() {
            assert_eq!(j.kind, JointKind::Revolute);
            assert!(j.limits.lower < j.limits.upper && j.limits.velocity > 0.0);
            assert!(j.limits.acceleration.is_finite() && j.limits.jerk.is_finite(), "{name}: config limits applied");
        }
    }
    // irb140 has a leaf link `base` beside the chain.
    assert!(robot("irb140").off_chain_links().iter().any(|l| l == "base"));
}

#[test]
fn fk_matches_the_published_dimensions() {
    // iiwa7 R800 stretched upright: 340 + 400 + 400 + 126 mm to the flange, plus the 100 mm tool.
    let m = robot("iiwa7");
    let p = m.forward_kinematics(&jv(&[0.0; 7])).translation.vector;
    assert!((p - nalgebra::Vector3::new(0.0, 0.0, 1.366)).norm() < 1e-9, "{p:?}");
    // VP6242 (DENSO convention, q3 = 90° puts the forearm horizontal): 280 mm to J2, 210 mm upper arm,
    // forearm 210 mm + 70 mm flange + the 60 mm tool ahead of J2 along x, elbow offset 75 mm.
    let m = robot("vp6242");
    let p = m.forward_kinematics(&jv(&[0.0, 0.0, std::f64::consts::FRAC_PI_2, 0.0, 0.0, 0.0])).translation.vector;
    assert!((p - nalgebra::Vector3::new(0.21 + 0.07 + 0.06, 0.0, 0.28 + 0.21 + 0.075)).norm() < 1e-6, "{p:?}");
    // The TCP's z axis points along the approach direction on every arm (tool transforms in config).
    let m = robot("irb140");
    let flange =
        strand::config::robot_model_from_urdf_file(&strand_testkit::root().join("config/robots/irb140.urdf"), "base_link", "tool0")
            .unwrap();
    let q = jv(&[0.3, 0.2, -0.4, 0.5, 0.6, 0.7]);
    let (tcp, fl) = (m.forward_kinematics(&q), flange.forward_kinematics(&q));
    let approach = fl.rotation * nalgebra::Vector3::x();
    assert!((tcp.rotation * nalgebra::Vector3::z() - approach).norm() < 1e-12);
    assert!((tcp.translation.vector - (fl.translation.vector + approach * 0.10)).norm() < 1e-12);
}

const GOOD: &str = r#"<robot name="t">
  <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1"/></joint>
  <joint name="f" type="fixed"><parent link="b"/><child link="c"/><origin xyz="0 0 0.2" rpy="0 1.5707963267948966 0"/></joint>
  <joint name="j2" type="JTYPE"><parent link="c"/><child link="d"/><origin xyz="0.3 0 0"/><axis xyz="0 1 0"/>LIMIT</joint>
</robot>"#;

fn urdf(jtype: &str, limit: &str) -> String {
    GOOD.replace("JTYPE", jtype).replace("LIMIT", limit)
}

fn load(text: &str, root: &str, tip: &str) -> Result<RobotModel, ModelError> {
    RobotModel::from_urdf_str(text, "test.urdf", root, tip)
}

#[test]
fn fixed_joints_fold_and_all_movable_types_load() {
    let lim = r#"<limit lower="-0.5" upper="0.5" velocity="2"/>"#;
    let m = load(&urdf("revolute", lim), "a", "d").unwrap();
    assert_eq!(m.dof(), 2);
    // j2's origin carries the folded fixed joint: 0.1 + 0.2 up, then 0.3 along the rotated x (= −z).
    let p = m.forward_kinematics(&jv(&[0.0, 0.0])).translation.vector;
    assert!((p - nalgebra::Vector3::new(0.0, 0.0, 0.0)).norm() < 1e-12, "{p:?}");
    let m = load(&urdf("continuous", r#"<limit velocity="2"/>"#), "a", "d").unwrap();
    assert_eq!(m.joints()[1].kind, JointKind::Continuous);
    assert!(m.joints()[1].limits.upper.is_infinite());
    let m = load(&urdf("prismatic", lim), "a", "d").unwrap();
    assert_eq!(m.joints()[1].kind, JointKind::Prismatic);
    let p0 = m.forward_kinematics(&jv(&[0.0, 0.0])).translation.vector;
    let p1 = m.forward_kinematics(&jv(&[0.0, 0.25])).translation.vector;
    assert!(((p1 - p0).norm() - 0.25).abs() < 1e-12);
}

#[test]
fn urdf_errors_name_the_file_and_the_element() {
    let lim = r#"<limit lower="-0.5" upper="0.5" velocity="2"/>"#;
    let cases: Vec<(Result<RobotModel, ModelError>, &[&str])> = vec![
        (load(&urdf("revolute", lim), "a", "nope"), &["test.urdf", "tip link \"nope\""]),
        (load(&urdf("revolute", lim), "zz", "d"), &["test.urdf", "root link \"zz\""]),
        (load(&urdf("revolute", lim), "d", "a"), &["test.urdf", "no chain", "\"d\"", "\"a\""]),
        (load(&urdf("floating", lim), "a", "d"), &["test.urdf", "joint \"j2\"", "floating"]),
        (load(&urdf("planar", lim), "a", "d"), &["joint \"j2\"", "planar"]),
        (load(&urdf("revolute", ""), "a", "d"), &["test.urdf", "joint \"j2\"", "no <limit>"]),
        (load(&urdf("revolute", r#"<limit lower="1" upper="-1" velocity="1"/>"#), "a", "d"), &["joint \"j2\"", "lower=1"]),
        (load(&urdf("revolute", r#"<limit lower="-1" upper="1" velocity="-3"/>"#), "a", "d"), &["joint \"j2\"", "velocity=-3"]),
        (load(&urdf("revolute", lim).replace(r#"<axis xyz="0 1 0"/>"#, r#"<axis xyz="0 0 0"/>"#), "a", "d"), &["joint \"j2\"", "axis"]),
        (load("<robot name=\"x\"><link name=\"a\"/>", "a", "a"), &["test.urdf", "cannot read URDF"]),
        (load(&urdf("revolute", lim), "a", "a"), &["test.urdf", "0 movable joints"]),
    ];
    for (result, needles) in cases {
        let msg = result.expect_err("must fail").to_string();
        for n in needles {
            assert!(msg.contains(n), "{msg:?} should mention {n:?}");
        }
    }
    // A <limit> without velocity: urdf-rs rejects the file; the error still names the joint.
    let msg = load(&urdf("revolute", r#"<limit lower="-1" upper="1"/>"#), "a", "d").unwrap_err().to_string();
    assert!(msg.contains("test.urdf") && msg.contains("joint \"j2\"") && msg.contains("velocity"), "{msg}");
    // URDF 1.2 acceleration limits must be positive.
    let v12 = urdf("revolute", r#"<limit lower="-1" upper="1" velocity="1" acceleration="0"/>"#)
        .replace(r#"<robot name="t">"#, r#"<robot name="t" version="1.2">"#);
    let msg = load(&v12, "a", "d").unwrap_err().to_string();
    assert!(msg.contains("joint \"j2\"") && msg.contains("acceleration=0"), "{msg}");
    // Curly quotes (pasted from a word processor) are a parse error, not a crash.
    let curly = urdf("revolute", lim).replace(r#"type="revolute""#, "type=\u{201c}revolute\u{201d}");
    let msg = load(&curly, "a", "d").unwrap_err().to_string();
    assert!(msg.contains("test.urdf"), "{msg}");
    // A link with two parents: the chain branches.
    let branch =
        urdf("revolute", lim).replace("</robot>", r#"<joint name="j3" type="fixed"><parent link="a"/><child link="c"/></joint></robot>"#);
    let msg = load(&branch, "a", "d").unwrap_err().to_string();
    assert!(msg.contains("link \"c\"") && msg.contains("\"f\"") && msg.contains("\"j3\"") && msg.contains("branches"), "{msg}");
    // A missing file.
    let msg = strand::config::robot_model_from_urdf_file(Path::new("/nonexistent/robot.urdf"), "a", "b").unwrap_err().to_string();
    assert!(msg.contains("/nonexistent/robot.urdf"), "{msg}");
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn config_errors_name_the_file_and_the_key() {
    let dir = std::env::temp_dir().join(format!("strand-config-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(strand_testkit::root().join("config/robots/vp6242.urdf"), dir.join("vp6242.urdf")).unwrap();
    let good = std::fs::read_to_string(strand_testkit::root().join("config/robots/vp6242.toml")).unwrap();
    let ok = write(&dir, "ok.toml", &good);
    assert_eq!(RobotConfig::load(&ok).unwrap().build_model().unwrap().dof(), 6);

    let short = write(&dir, "short.toml", &good.replace("acceleration = [4.0, 4.0, 4.0, 6.0, 6.0, 6.0]", "acceleration = [4.0, 4.0]"));
    let msg = RobotConfig::load(&short).unwrap().build_model().unwrap_err().to_string();
    assert!(
        msg.contains("short.toml") && msg.contains("limits.acceleration") && msg.contains("2 values") && msg.contains("6 joints"),
        "{msg}"
    );

    let negative = write(&dir, "neg.toml", &good.replace("jerk = [40.0,", "jerk = [-40.0,"));
    let msg = RobotConfig::load(&negative).unwrap().build_model().unwrap_err().to_string();
    assert!(msg.contains("limits.jerk") && msg.contains("joint 0") && msg.contains("\"joint1\""), "{msg}");

    let unknown = write(&dir, "unknown.toml", &good.replace("tip_link = \"tool0\"", "tip_link = \"tool0\"\ntip_lnk = 3"));
    let msg = RobotConfig::load(&unknown).unwrap_err().to_string();
    assert!(msg.contains("unknown.toml") && msg.contains("tip_lnk") && msg.contains("line"), "{msg}");

    let bad_link = write(&dir, "badlink.toml", &good.replace("tip_link = \"tool0\"", "tip_link = \"tool9\""));
    let msg = RobotConfig::load(&bad_link).unwrap().build_model().unwrap_err().to_string();
    assert!(msg.contains("badlink.toml") && msg.contains("vp6242.urdf") && msg.contains("tool9"), "{msg}");

    // The service config: a bad CLIK key or value is named.
    let svc = write(&dir, "svc.toml", "robot = \"ok.toml\"\n[clik]\ngains = [1.0, 1.0, 1.0, 1.0, 1.0, -2.0]\n");
    let msg = Config::load(&svc).unwrap_err().to_string();
    assert!(msg.contains("svc.toml") && msg.contains("clik.gains[5]"), "{msg}");
    let svc = write(&dir, "svc2.toml", "robot = \"ok.toml\"\n[clik]\ntask = \"pose7\"\n");
    let msg = Config::load(&svc).unwrap_err().to_string();
    assert!(msg.contains("svc2.toml") && msg.contains("pose7") && msg.contains("line 3"), "{msg}");
    let svc = write(&dir, "svc3.toml", "robot = \"missing.toml\"\n");
    let msg = Config::load(&svc).unwrap_err().to_string();
    assert!(msg.contains("svc3.toml") && msg.contains("robot") && msg.contains("missing.toml"), "{msg}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_bundled_default_config_loads() {
    let cfg = Config::load(&strand_testkit::root().join("config/default.toml")).unwrap();
    assert_eq!(cfg.robot.build_model().unwrap().dof(), 7);
    assert_eq!(cfg.clik, strand_core::kin::ClikConfig::default(), "default.toml and ClikConfig::default() agree");
}
