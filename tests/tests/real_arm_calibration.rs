//! Calibration on real robot descriptions: a Franka Panda (7 joints) and a
//! Universal Robots UR5 (6 joints) from their published URDFs
//! (`tests/data/urdf`), each placed in front of the simulated head by a rig
//! file (`tests/data/rigs/{panda,ur5}`), before the Nico-like scene's three
//! mirror placements.
//!
//! - A poor fit is explained, not refused: an arm whose encoders read off
//!   by about a degree, calibrated with `joint`, gets a calibration marked
//!   poor whose cause names `joint+kinematics`, which then fits.
//! - The stated uncertainty is honest on these arms too.

use std::path::Path;

use geometry::Rig;
use geometry::sim::{Counts, Dataset, NoiseModel, Scene, generate, nico_noise_scaled, nico_scene};
use mirror_proc::calibrate::{Fit, Method, calibrate};

fn rig(name: &str) -> Rig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("data/rigs/{name}/rig.toml"));
    formats::rig::read(path).unwrap()
}

fn scene(name: &str) -> Scene {
    Scene {
        rig: rig(name),
        ..nico_scene()
    }
}

/// Encoder offsets in the preset's pattern at `scale` rad, for `dof`
/// joints, with tracker-like pixel noise.
fn noise(pixel_sigma: f64, scale: f64, dof: usize) -> NoiseModel {
    let four = nico_noise_scaled(pixel_sigma, scale);
    NoiseModel {
        pixel_sigma,
        joint_offsets: four
            .joint_offsets
            .iter()
            .cycle()
            .take(dof)
            .copied()
            .collect(),
    }
}

fn dataset(scene: &Scene, mirror: usize, noise: &NoiseModel, train: usize, seed: u64) -> Dataset {
    let counts = Counts {
        train,
        test: 0,
        direct: 0,
    };
    generate(scene, mirror, noise, counts, seed).unwrap()
}

/// As on a real Kinova Jaco2 (placement 2, 10 samples): encoders off by
/// about a degree. `joint` cannot model that; the calibration says so and
/// names the method that can, which fits to the noise.
#[test]
fn offset_encoders_give_a_poor_joint_fit_that_names_joint_kinematics() {
    for name in ["panda", "ur5"] {
        let scene = scene(name);
        let dof = scene.rig.arm.as_ref().unwrap().dof();
        let d = dataset(&scene, 2, &noise(0.2, 0.02, dof), 10, 7);
        let joint = calibrate(&d.rig, &d.train, Method::Joint).unwrap();
        let Fit::Poor { cause } = &joint.fit else {
            panic!(
                "{name}: joint fit judged {:?} at {:.2} px",
                joint.fit, joint.train_rms_px
            );
        };
        println!("{name}: joint leaves {:.2} px: {cause}", joint.train_rms_px);
        assert!(
            cause.contains("joint readings look offset: use --method joint+kinematics"),
            "{name}: {cause}"
        );
        let fixed = calibrate(&d.rig, &d.train, Method::JointKinematics).unwrap();
        println!(
            "{name}: joint+kinematics leaves {:.2} px",
            fixed.train_rms_px
        );
        assert_eq!(fixed.fit, Fit::Good, "{name}");
        assert!(
            fixed.train_rms_px < 0.5,
            "{name}: {:.2} px",
            fixed.train_rms_px
        );
        // Against the truth: the plane is recovered once offsets are modelled.
        let truth = d.truth.mirror.plane;
        let plane = fixed.plane.unwrap();
        let angle = plane
            .normal
            .dot(&truth.normal)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        assert!(
            angle < 0.1 && (plane.distance - truth.distance).abs() < 1.0,
            "{name}: {angle} deg"
        );
    }
}

/// Normalised errors pooled over runs: their RMS must lie in [0.7, 1.4].
struct Coverage {
    name: String,
    normalised: Vec<f64>,
}

impl Coverage {
    fn rms(&self) -> f64 {
        (self.normalised.iter().map(|z| z * z).sum::<f64>() / self.normalised.len() as f64).sqrt()
    }
}

#[test]
fn the_stated_uncertainty_is_honest_on_real_arms() {
    const SEEDS: u64 = 16;
    for name in ["panda", "ur5"] {
        let scene = scene(name);
        let arm = scene.rig.arm.clone().unwrap();
        let names = arm.joint_names();
        let mut table: Vec<Coverage> = Vec::new();
        let mut push = |what: String, error: f64, sigma: f64| {
            assert!(
                sigma > 0.0 && sigma.is_finite(),
                "{name} {what}: sigma {sigma}"
            );
            match table.iter_mut().find(|c| c.name == what) {
                Some(c) => c.normalised.push(error / sigma),
                None => table.push(Coverage {
                    name: what,
                    normalised: vec![error / sigma],
                }),
            }
        };
        for mirror in 0..3 {
            for seed in 0..SEEDS {
                let d = dataset(&scene, mirror, &noise(0.3, 0.01, arm.dof()), 30, 300 + seed);
                let cal = calibrate(&d.rig, &d.train, Method::JointKinematics).unwrap();
                assert_eq!(cal.fit, Fit::Good, "{name}, mirror {mirror}, seed {seed}");
                let u = &cal.uncertainty;
                let (plane, truth) = (cal.plane.unwrap(), d.truth.mirror.plane);
                let angle = plane.normal.dot(&truth.normal).clamp(-1.0, 1.0).acos();
                push(
                    "plane angle".into(),
                    angle.to_degrees(),
                    u.plane_angle_deg.unwrap(),
                );
                push(
                    "plane distance".into(),
                    plane.distance - truth.distance,
                    u.plane_distance_mm.unwrap(),
                );
                // The marker sits on the last joint's axis: its offset is
                // not seen, and the calibration names it.
                let last = names.last().unwrap();
                assert!(
                    u.undetermined.iter().any(|w| w.contains(last.as_str())),
                    "{name}: {:?}",
                    u.undetermined
                );
                let offsets = cal.joint_offsets.as_ref().unwrap();
                let sigmas = u.joint_offsets_deg.as_ref().unwrap();
                for (j, sigma) in sigmas.iter().enumerate() {
                    // An offset the marker's position does not depend on
                    // (a wrist roll about the axis through the marker) is
                    // stated undetermined, not given a sigma.
                    if let Some(sigma) = sigma {
                        let error = (offsets[j] - d.truth.joint_offsets[j]).to_degrees();
                        push(format!("offset of {}", names[j]), error, *sigma);
                    }
                }
            }
        }
        println!("| {name} | runs | RMS of error / sigma |");
        for c in &table {
            println!("| {} | {} | {:.2} |", c.name, c.normalised.len(), c.rms());
        }
        for c in &table {
            assert!(
                (0.7..=1.4).contains(&c.rms()),
                "{name} {}: {:.2}",
                c.name,
                c.rms()
            );
        }
    }
}

/// Part 3 on the real arms: the rig's base 20 mm and 2 deg off and its
/// tool 5 mm off; three placements of 20 mirror and 10 direct poses
/// (encoders read true, 0.2 px). Base within 1 mm and 0.1 deg, tool within
/// 1 mm, and over 20 seeds the RMS of error / sigma of each within
/// [0.7, 1.4].
#[test]
fn base_and_tool_are_recovered_on_real_arms_with_honest_sigmas() {
    use geometry::Sample;
    use mirror_proc::calibrate::{CalibrateOptions, Estimate, calibrate_placements};
    use nalgebra::{Isometry3, Vector3};
    const SEEDS: u64 = 20;
    for name in ["panda", "ur5"] {
        let scene = scene(name);
        let truth = scene.rig.arm.clone().unwrap();
        let dof = truth.dof();
        let counts = Counts {
            train: 20,
            test: 0,
            direct: 10,
        };
        let mut worst = [0.0f64; 3];
        let mut z = ["base rotation", "base position", "tool"].map(|what| Coverage {
            name: what.into(),
            normalised: Vec::new(),
        });
        for seed in 0..SEEDS {
            let sets: Vec<Vec<Sample>> = (0..3)
                .map(|m| {
                    let d = generate(
                        &scene,
                        m,
                        &noise(0.2, 0.0, dof),
                        counts,
                        50 * seed + m as u64,
                    )
                    .unwrap();
                    d.train
                        .into_iter()
                        .chain(d.direct)
                        .map(|mut s| {
                            s.model_point = None;
                            s
                        })
                        .collect()
                })
                .collect();
            let mut rig = scene.rig.clone();
            let arm = rig.arm.as_mut().unwrap();
            let a = seed as f64;
            arm.world_from_base *= Isometry3::new(
                Vector3::new(a.cos(), a.sin(), 0.6).normalize() * 20.0,
                Vector3::new(0.3, (1.7 * a).cos(), (1.7 * a).sin()).normalize() * 2f64.to_radians(),
            );
            arm.tool += Vector3::new((0.9 * a).sin(), 0.5, (0.9 * a).cos()).normalize() * 5.0;
            let placements: Vec<&[Sample]> = sets.iter().map(Vec::as_slice).collect();
            let both = Estimate {
                base: true,
                tool: true,
            };
            let cal = calibrate_placements(
                &rig,
                &placements,
                Method::Joint,
                both,
                CalibrateOptions::default(),
            )
            .unwrap_or_else(|e| panic!("{name} seed {seed}: {e}"));
            let base = cal.world_from_base.unwrap();
            let errors = [
                base.rotation
                    .angle_to(&truth.world_from_base.rotation)
                    .to_degrees(),
                (base.translation.vector - truth.world_from_base.translation.vector).norm(),
                (cal.tool.unwrap() - truth.tool).norm(),
            ];
            let u = &cal.uncertainty;
            let sigmas = [
                u.base_rotation_deg.unwrap(),
                u.base_translation_mm.unwrap(),
                u.tool_mm.unwrap(),
            ];
            for k in 0..3 {
                worst[k] = worst[k].max(errors[k]);
                z[k].normalised.push(errors[k] / sigmas[k]);
            }
        }
        let rms = z.each_ref().map(Coverage::rms);
        println!(
            "{name}: worst base {:.4} deg {:.3} mm, tool {:.3} mm; RMS of error / sigma {:.2} {:.2} {:.2}",
            worst[0], worst[1], worst[2], rms[0], rms[1], rms[2]
        );
        assert!(
            worst[0] < 0.1 && worst[1] < 1.0 && worst[2] < 1.0,
            "{name}: {worst:?}"
        );
        for r in &rms {
            assert!(
                (0.7..=1.4).contains(r),
                "{name}: RMS of error / sigma {rms:?}"
            );
        }
    }
}
