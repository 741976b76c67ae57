//! The solvers against the simulator's ground truth.

use geometry::sim::{Counts, Dataset, NoiseModel, generate, nico_noise, nico_scene};
use geometry::{Camera, Plane, Sample, View};
use mirror_proc::calibrate::{CalibrateError, Fit, Method, calibrate, paper_initial_estimate};
use mirror_proc::experiment::rotation_error;
use nalgebra::Vector3;

fn dataset(mirror: usize, noise: &NoiseModel, train: usize, seed: u64) -> Dataset {
    generate(
        &nico_scene(),
        mirror,
        noise,
        Counts {
            train,
            test: 0,
            direct: 0,
        },
        seed,
    )
    .unwrap()
}

fn assert_cameras_equal(got: &[Camera; 2], want: &[Camera; 2], what: &str) {
    for k in 0..2 {
        let dc = (got[k].center - want[k].center).norm();
        let dr = rotation_error(&got[k], &want[k]);
        // Noiseless data: LM stops at machine precision (observed ~1e-12 mm).
        assert!(dc < 1e-6, "{what}: camera {k} centre off by {dc:e} mm");
        assert!(dr < 1e-9, "{what}: camera {k} rotation off by {dr:e} rad");
    }
}

#[test]
fn noiseless_data_gives_the_true_mirror_cameras() {
    for mirror in 0..3 {
        let d = dataset(mirror, &NoiseModel::none(4), 10, 11);
        for method in Method::ALL {
            let cal = calibrate(&d.rig, &d.train, method).unwrap();
            assert_cameras_equal(
                &cal.mirror_cameras,
                &d.truth.mirror_cameras,
                &format!("{method}, mirror {mirror}"),
            );
            assert!(cal.train_rms_px < 1e-6);
            if let Some(plane) = cal.plane {
                let t = d.truth.mirror.plane;
                assert!(
                    plane.normal.dot(&t.normal) > 1.0 - 1e-12
                        && (plane.distance - t.distance).abs() < 1e-6
                );
            }
        }
    }
}

#[test]
fn joint_kinematics_recovers_encoder_offsets() {
    // No pixel noise, but the encoders are off: only joint+kinematics can be exact.
    let noise = NoiseModel {
        pixel_sigma: 0.0,
        ..nico_noise()
    };
    for mirror in 0..3 {
        let d = dataset(mirror, &noise, 15, 5);
        let cal = calibrate(&d.rig, &d.train, Method::JointKinematics).unwrap();
        assert_cameras_equal(
            &cal.mirror_cameras,
            &d.truth.mirror_cameras,
            "joint+kinematics",
        );
        for (got, want) in cal
            .joint_offsets
            .unwrap()
            .iter()
            .zip(&d.truth.joint_offsets)
        {
            assert!((got - want).abs() < 1e-9, "offset {got} vs {want}");
        }
        let biased = calibrate(&d.rig, &d.train, Method::Joint).unwrap();
        assert!((biased.mirror_cameras[0].center - d.truth.mirror_cameras[0].center).norm() > 0.1);
    }
}

#[test]
fn paper_initial_estimate_has_the_right_axis_but_is_half_a_turn_off_in_roll() {
    for mirror in 0..3 {
        let d = dataset(mirror, &NoiseModel::none(4), 10, 2);
        let init = paper_initial_estimate(&d.rig, &d.train).unwrap();
        for k in 0..2 {
            let t = &d.truth.mirror_cameras[k];
            assert!((init[k].center - t.center).norm() < 1e-6);
            let axis = |c: &Camera| c.camera_from_world.row(2).transpose();
            assert!(
                (axis(&init[k]) - axis(t)).norm() < 1e-9,
                "optical axis differs"
            );
            let roll = rotation_error(&init[k], t).to_degrees();
            assert!((roll - 180.0).abs() < 1e-6, "roll error {roll} deg");
        }
    }
}

#[test]
fn paper_method_can_settle_on_a_wrong_resection_with_three_poses() {
    // Three points and six unknowns per camera: camera resection has several
    // exact solutions, and from the paper's start LM finds a wrong one here.
    let d = dataset(1, &NoiseModel::none(4), 3, 1);
    let cal = calibrate(&d.rig, &d.train, Method::Paper).unwrap();
    assert!(cal.train_rms_px < 1e-6, "fits the training poses exactly");
    let off = (cal.mirror_cameras[0].center - d.truth.mirror_cameras[0].center).norm();
    assert!(
        off > 100.0,
        "yet the camera is {off} mm away from the truth"
    );
    // The shared plane has no such ambiguity.
    let joint = calibrate(&d.rig, &d.train, Method::Joint).unwrap();
    assert!((joint.mirror_cameras[0].center - d.truth.mirror_cameras[0].center).norm() < 1e-6);
}

#[test]
fn estimates_converge_towards_the_truth_as_samples_grow() {
    let noise = nico_noise();
    for method in Method::ALL {
        let (mut few, mut many) = (0.0, 0.0);
        for seed in 1..=3 {
            for mirror in 0..3 {
                let d = dataset(mirror, &noise, 50, seed);
                let err = |n: usize| {
                    let cal = calibrate(&d.rig, &d.train[..n], method).unwrap();
                    (0..2)
                        .map(|k| {
                            (cal.mirror_cameras[k].center - d.truth.mirror_cameras[k].center).norm()
                        })
                        .sum::<f64>()
                };
                few += err(6);
                many += err(50);
            }
        }
        assert!(
            many < 0.7 * few,
            "{method}: centre error {many:.1} at 50 vs {few:.1} at 6 poses"
        );
    }
}

#[test]
fn joint_kinematics_offsets_converge_with_noise() {
    let noise = nico_noise();
    let (mut few, mut many) = (0.0, 0.0);
    for seed in 1..=3 {
        for mirror in 0..3 {
            let d = dataset(mirror, &noise, 50, seed);
            let err = |n: usize| {
                let cal = calibrate(&d.rig, &d.train[..n], Method::JointKinematics).unwrap();
                let o = cal.joint_offsets.unwrap();
                o.iter()
                    .zip(&d.truth.joint_offsets)
                    .map(|(a, b)| (a - b).abs())
                    .sum::<f64>()
            };
            few += err(10);
            many += err(50);
        }
    }
    assert!(
        many < 0.7 * few,
        "offset error {many:.4} at 50 vs {few:.4} at 10 poses"
    );
}

fn expect_err(samples: &[Sample], method: Method) -> CalibrateError {
    let d = dataset(0, &NoiseModel::none(4), 1, 1);
    calibrate(&d.rig, samples, method).unwrap_err()
}

#[test]
fn degenerate_input_is_a_clear_error() {
    let d = dataset(0, &NoiseModel::none(4), 10, 1);
    for method in Method::ALL {
        assert_eq!(
            expect_err(&d.train[..2], method),
            CalibrateError::TooFewSamples { found: 2 }
        );
        let same = vec![d.train[0].clone(); 10];
        assert!(
            matches!(expect_err(&same, method), CalibrateError::PosesAlike { .. }),
            "{method}"
        );
        let mut nan = d.train.clone();
        nan[4].pixels[1].x = f64::NAN;
        let e = expect_err(&nan, method);
        assert!(
            matches!(e, CalibrateError::BadSample { pose: 4, .. }),
            "{e}"
        );
        // Direct views do not count towards the mirror samples.
        let direct: Vec<Sample> = d
            .train
            .iter()
            .map(|s| Sample {
                view: View::Direct,
                ..s.clone()
            })
            .collect();
        assert_eq!(
            expect_err(&direct, method),
            CalibrateError::TooFewSamples { found: 0 }
        );
    }
    let no_joints: Vec<Sample> = d
        .train
        .iter()
        .map(|s| Sample {
            joints: None,
            ..s.clone()
        })
        .collect();
    let e = expect_err(&no_joints, Method::JointKinematics);
    assert!(e.to_string().contains("joint angles"), "{e}");
    assert!(
        calibrate(&d.rig, &no_joints, Method::Joint).is_ok(),
        "jx,jy,jz suffice without kinematics"
    );
}

#[test]
fn a_mirror_through_a_camera_is_rejected() {
    let d = dataset(0, &NoiseModel::none(4), 30, 1);
    let left = d.rig.cameras[0];
    // A plane through the left camera's centre, tilted so both cameras still see reflections.
    let plane = Plane::through(&left.center, Vector3::new(0.4, 0.1, -1.0)).unwrap();
    let samples: Vec<Sample> = d
        .truth
        .train_points
        .iter()
        .zip(&d.train)
        .filter(|(p, _)| plane.signed_distance(p) > 0.0)
        .filter_map(|(p, s)| {
            let v = plane.reflect_point(p);
            let px = [
                d.rig.cameras[0].project(&v).ok()?,
                d.rig.cameras[1].project(&v).ok()?,
            ];
            (d.rig.cameras[0].depth(&v) > 0.0 && d.rig.cameras[1].depth(&v) > 0.0).then(|| Sample {
                pixels: px,
                model_point: Some(*p),
                ..s.clone()
            })
        })
        .collect();
    assert!(samples.len() >= 5, "only {} usable samples", samples.len());
    for method in Method::ALL {
        let e = calibrate(&d.rig, &samples, method).unwrap_err();
        assert!(
            matches!(e, CalibrateError::PlaneThroughCamera { .. }),
            "{method}: {e}"
        );
    }
}

/// A mirror seen edge-on, its plane nearly along the cameras' view
/// direction: refused with the angle, instead of a plane fitted along rays
/// that do not determine it.
#[test]
fn a_mirror_seen_edge_on_is_rejected() {
    let d = dataset(0, &NoiseModel::none(4), 10, 1);
    let [left, right] = d.rig.cameras;
    let normal = (right.center - left.center).normalize();
    let middle = (left.center + right.center) / 2.0;
    let plane = Plane::through(&middle, normal).unwrap();
    let forward = left.camera_from_world.row(2).transpose();
    let up = normal.cross(&forward).normalize();
    let samples: Vec<Sample> = (0..20)
        .map(|i| {
            let (t, s, e) = (
                400.0 + 25.0 * i as f64,
                -100.0 + 10.0 * i as f64,
                2.0 + (i % 5) as f64,
            );
            let j = middle + forward * t + up * s + normal * e;
            let v = plane.reflect_point(&j);
            Sample {
                pose: i,
                view: View::Mirror,
                joints: None,
                model_point: Some(j),
                pixels: [left.project(&v).unwrap(), right.project(&v).unwrap()],
            }
        })
        .collect();
    // (joint+kinematics needs joint angles, which these samples lack.)
    for method in [Method::Paper, Method::Joint] {
        let e = calibrate(&d.rig, &samples, method).unwrap_err();
        assert!(
            matches!(e, CalibrateError::MirrorEdgeOn { grazing_deg } if grazing_deg < 5.0),
            "{method}: {e}"
        );
        assert!(e.to_string().contains("edge-on"), "{e}");
    }
}

/// Samples that do not fit one mirror (half of them paired with the wrong
/// pose) give a calibration marked poor, saying why, not a silent one.
#[test]
fn samples_from_no_single_mirror_are_marked_poor_with_the_cause() {
    let d = dataset(0, &NoiseModel::none(4), 20, 3);
    let mut samples = d.train.clone();
    let n = samples.len();
    for i in 0..n / 2 {
        let other = samples[n - 1 - i].pixels;
        samples[i].pixels = other;
    }
    for method in [Method::Joint, Method::JointKinematics] {
        let cal = calibrate(&d.rig, &samples, method).unwrap();
        match &cal.fit {
            Fit::Poor { cause } => {
                assert!(cause.contains("do not fit one mirror"), "{method}: {cause}")
            }
            other => panic!("{method}: {other:?} at {:.1} px RMS", cal.train_rms_px),
        }
        assert!(cal.train_rms_px > 10.0, "{method}: {}", cal.train_rms_px);
    }
    // The same samples, rightly paired, fit.
    for method in [Method::Joint, Method::JointKinematics] {
        assert_eq!(calibrate(&d.rig, &d.train, method).unwrap().fit, Fit::Good);
    }
}
