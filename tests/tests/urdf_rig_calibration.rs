//! The simulated robot described as a real one is: the arm by a URDF, the
//! cameras by calibration files (ROS camera_info and OpenCV YAML) whose
//! lenses have p1, p2, k3 != 0 (`tests/data/rigs/nico_urdf`). Calibrating
//! through that rig reaches the same targets as through the DH rig.

use std::path::Path;

use geometry::sim::{Scene, nico_noise, nico_scene};
use mirror_proc::experiment::{self, ExperimentConfig, ExperimentResult};

fn urdf_rig() -> geometry::Rig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/rigs/nico_urdf/rig.toml");
    formats::rig::read(path).unwrap()
}

#[test]
fn the_urdf_rig_describes_the_simulated_arm_and_real_lenses() {
    let rig = urdf_rig();
    let dh = nico_scene().rig;
    let (a, b) = (rig.arm.as_ref().unwrap(), dh.arm.as_ref().unwrap());
    assert_eq!(
        a.joint_names(),
        [
            "r_shoulder_flexion",
            "r_shoulder_abduction",
            "r_upperarm_rotation",
            "r_elbow"
        ]
    );
    assert_eq!(a.limits(), b.limits());
    for i in 0..20 {
        let q: Vec<f64> = b
            .limits()
            .iter()
            .enumerate()
            .map(|(j, (lo, hi))| lo + (hi - lo) * (0.5 + 0.45 * ((i * 5 + j) as f64).sin()))
            .collect();
        let offsets = [0.01, -0.02, 0.015, -0.005];
        let (pa, pb) = (
            a.end_effector(&q, &offsets).unwrap(),
            b.end_effector(&q, &offsets).unwrap(),
        );
        assert!((pa - pb).norm() < 1e-9, "{pa} vs {pb}");
    }
    for k in 0..2 {
        let (c, d) = (&rig.cameras[k], &dh.cameras[k]);
        assert!((c.camera_from_world - d.camera_from_world).norm() < 1e-12);
        assert_eq!(c.center, d.center);
        let dist = c.intrinsics.dist;
        assert!(
            dist.p1 != 0.0 && dist.p2 != 0.0 && dist.k3 != 0.0,
            "{dist:?}"
        );
    }
}

fn run(scene: &Scene) -> ExperimentResult {
    let config = ExperimentConfig {
        sizes: vec![10, 20],
        ..ExperimentConfig::quick("nico", nico_noise(), 1)
    };
    experiment::run(scene, &config, |_| {}).unwrap()
}

/// `joint` within 1.15x of the oracle (true mirror cameras) from 10 poses
/// on; `joint+kinematics` within 1.15x of the noise floor from 20.
fn assert_targets(result: &ExperimentResult, what: &str) {
    let oracle = result.summary_for("oracle", 0).unwrap();
    let floor = result.summary_for("noise floor", 0).unwrap();
    for size in [10, 20] {
        let joint = result.summary_for("joint", size).unwrap();
        let (a, b) = (joint.mirror_3d_mm.unwrap(), oracle.mirror_3d_mm.unwrap());
        println!(
            "{what}: joint at {size}: mirror 3D {a:.2} mm, oracle {b:.2} mm ({:.3}x)",
            a / b
        );
        assert!(
            a <= 1.15 * b,
            "{what}: joint at {size}: {a} mm vs oracle {b} mm"
        );
    }
    let jk = result.summary_for("joint+kinematics", 20).unwrap();
    let (a, b) = (jk.mirror_2d_px.unwrap(), floor.mirror_2d_px.unwrap());
    println!(
        "{what}: joint+kinematics at 20: mirror 2D {a:.3} px, floor {b:.3} px ({:.3}x)",
        a / b
    );
    assert!(
        a <= 1.15 * b,
        "{what}: joint+kinematics at 20: {a} px vs floor {b} px"
    );
}

#[test]
fn calibrating_through_the_urdf_rig_reaches_the_dh_rigs_targets() {
    let dh = nico_scene();
    let urdf = Scene {
        rig: urdf_rig(),
        mirrors: dh.mirrors.clone(),
    };
    assert_targets(&run(&dh), "DH rig");
    assert_targets(&run(&urdf), "URDF rig + calibration files");
}
