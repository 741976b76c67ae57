//! Real arm descriptions (UR5, 6 joints; Franka Panda, 7 joints plus a
//! hand with mimicking fingers) read by `formats::urdf`, their forward
//! kinematics checked against an independent implementation (the `k`
//! crate, on its own URDF parser), and the corrected URDF that `export`
//! writes checked to load back to the calibrated model.

use std::path::{Path, PathBuf};

use formats::urdf;
use geometry::{Chain, JointKind};
use nalgebra::Vector3;

fn data(file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data/urdf")
        .join(file)
}

/// Deterministic joint values spread over each input's limits.
fn poses(chain: &Chain, count: usize) -> Vec<Vec<f64>> {
    (0..count)
        .map(|p| {
            chain
                .inputs
                .iter()
                .enumerate()
                .map(|(i, j)| {
                    let t = 0.5 + 0.45 * ((p * 7 + i * 3) as f64 * 0.91).sin();
                    j.min + t * (j.max - j.min)
                })
                .collect()
        })
        .collect()
}

/// The tip in the base frame by the `k` crate, in mm.
fn k_base_from_tip(
    file: &Path,
    base: &str,
    tip: &str,
    chain: &Chain,
    q: &[f64],
) -> nalgebra::Matrix4<f64> {
    let robot = k::Chain::<f64>::from_urdf_file(file).unwrap();
    for node in robot.iter() {
        let name = node.joint().name.clone();
        if let Some(i) = chain.inputs.iter().position(|j| j.name == name) {
            let scale = if chain.inputs[i].kind == JointKind::Prismatic {
                1e-3
            } else {
                1.0
            };
            node.set_joint_position(q[i] * scale).unwrap();
        }
    }
    robot.update_transforms();
    let world = |link: &str| {
        robot
            .find_link(link)
            .map(|n| n.world_transform().unwrap())
            .unwrap_or_else(k::nalgebra::Isometry3::identity)
    };
    let t = (world(base).inverse() * world(tip)).to_homogeneous();
    let mut out = nalgebra::Matrix4::from_fn(|r, c| t[(r, c)]);
    for r in 0..3 {
        out[(r, 3)] *= 1000.0;
    }
    out
}

const CASES: &[(&str, &str, &str, usize)] = &[
    // 6 joints; the file's root `world` lies above base_link.
    ("ur5/ur5_robot.urdf", "base_link", "ee_link", 6),
    ("ur5/ur5_robot.urdf", "world", "wrist_3_link", 6),
    // 7 joints, then fixed flange, hand and tool-centre frames.
    ("panda/panda.urdf", "panda_link0", "panda_hand_tcp", 7),
    // A prismatic finger: 8 inputs.
    ("panda/panda.urdf", "panda_link0", "panda_leftfinger", 8),
    // The other finger mimics the first, which is off this chain: the
    // input is the first finger's joint.
    ("panda/panda.urdf", "panda_link0", "panda_rightfinger", 8),
    // A chain starting mid-arm.
    ("panda/panda.urdf", "panda_link3", "panda_link8", 4),
];

#[test]
fn forward_kinematics_match_an_independent_implementation() {
    for &(file, base, tip, dof) in CASES {
        let path = data(file);
        let chain = urdf::read(&path, base, tip).unwrap();
        assert_eq!(chain.inputs.len(), dof, "{file} {base}..{tip}");
        for q in poses(&chain, 25) {
            let ours = chain.base_from_tip(&q, &[]).to_homogeneous();
            let theirs = k_base_from_tip(&path, base, tip, &chain, &q);
            let diff = (ours - theirs).abs().max();
            assert!(
                diff < 1e-9,
                "{file} {base}..{tip} at {q:?}: {diff}\n{ours}{theirs}"
            );
        }
    }
}

#[test]
fn names_limits_and_units_come_from_the_file() {
    let chain = urdf::read(data("panda/panda.urdf"), "panda_link0", "panda_rightfinger").unwrap();
    let names: Vec<&str> = chain.inputs.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "panda_joint1",
            "panda_joint2",
            "panda_joint3",
            "panda_joint4",
            "panda_joint5",
            "panda_joint6",
            "panda_joint7",
            "panda_finger_joint1"
        ]
    );
    assert_eq!(
        (chain.inputs[3].min, chain.inputs[3].max),
        (-3.0718, -0.0698)
    );
    // The finger travels 0 to 0.04 m: 0 to 40 mm.
    assert_eq!(chain.inputs[7].kind, JointKind::Prismatic);
    assert!((chain.inputs[7].max - 40.0).abs() < 1e-12);
    // Link 1 is 333 mm above the base.
    let up = chain.joints[1].origin.translation.vector + chain.joints[0].origin.translation.vector;
    assert!((up - Vector3::new(0.0, 0.0, 333.0)).norm() < 1e-9, "{up}");
}

#[test]
fn the_corrected_urdf_loads_back_to_the_calibrated_model() {
    for &(file, base, tip, _) in CASES {
        let path = data(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let chain = urdf::read(&path, base, tip).unwrap();
        let offsets: Vec<f64> = chain
            .inputs
            .iter()
            .enumerate()
            .map(|(i, j)| match j.kind {
                JointKind::Revolute => 0.03 * (i as f64 - 2.5),
                JointKind::Prismatic => 1.5,
            })
            .collect();
        let fixed = urdf::corrected(&path, &text, base, tip, &offsets).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("corrected.urdf");
        std::fs::write(&out, &fixed).unwrap();
        let again = urdf::read(&out, base, tip).unwrap();
        for q in poses(&chain, 10) {
            let calibrated = chain.base_from_tip(&q, &offsets).to_homogeneous();
            let ours = again.base_from_tip(&q, &[]).to_homogeneous();
            assert!(
                (calibrated - ours).abs().max() < 1e-9,
                "{file} {base}..{tip}"
            );
            // And by the independent implementation.
            let theirs = k_base_from_tip(&out, base, tip, &again, &q);
            assert!(
                (calibrated - theirs).abs().max() < 1e-9,
                "{file} {base}..{tip} (k)"
            );
        }
        // Only origins of the chain's joints changed.
        let changed = text
            .lines()
            .zip(fixed.lines())
            .filter(|(a, b)| a != b)
            .count();
        assert!(changed <= chain.joints.len(), "{changed} lines changed");
        assert_eq!(text.lines().count(), fixed.lines().count());
    }
}
