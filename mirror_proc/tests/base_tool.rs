//! The arm's base and tool estimated beside the mirrors, from three mirror
//! placements and direct views (issue targets: the rig's base off by 20 mm
//! and 2 deg, its tool by 5 mm; 3 placements of 20 mirror and 10 direct
//! poses; base within 1 mm and 0.1 deg, tool within 1 mm, test errors
//! within 1.15x of the oracle that knows the true base and tool), beside the
//! closed-form registration a user would do today (Umeyama on the
//! triangulated direct views); the stated sigmas are honest over many
//! seeds; and what cannot be determined is refused.

use geometry::sim::{Counts, Dataset, NoiseModel, generate, nico_scene};
use geometry::triangulate::triangulate;
use geometry::{Rig, Sample, register};
use mirror_proc::calibrate::{
    CalibrateError, CalibrateOptions, Calibration, Estimate, Method, calibrate_placements,
};
use mirror_proc::evaluate::evaluate_against;
use nalgebra::{Isometry3, Vector3};

/// Our tracker's noise, as stated by default (its centre errors on renders:
/// median 0.11 px, live fits leave 0.05-0.08 px).
const PIXEL_SIGMA: f64 = 0.2;
const BOTH: Estimate = Estimate {
    base: true,
    tool: true,
};

/// The scene's three placements, each with 20 mirror training poses, 10
/// direct poses and 30 mirror test poses; encoders read true.
fn datasets(seed: u64, pixel_sigma: f64) -> Vec<Dataset> {
    let scene = nico_scene();
    let dof = scene.rig.arm.as_ref().unwrap().dof();
    let noise = NoiseModel {
        pixel_sigma,
        joint_offsets: vec![0.0; dof],
    };
    let counts = Counts {
        train: 20,
        test: 30,
        direct: 10,
    };
    (0..3)
        .map(|m| generate(&scene, m, &noise, counts, 1000 * seed + m as u64).unwrap())
        .collect()
}

/// The rig as a user would write it: base 20 mm and 2 deg off, tool 5 mm
/// off, in directions that change with the seed.
fn measured_rig(truth: &Rig, seed: u64) -> Rig {
    let mut rig = truth.clone();
    let arm = rig.arm.as_mut().unwrap();
    let a = seed as f64;
    let unit = |v: Vector3<f64>| v.normalize();
    let shift = unit(Vector3::new(a.sin(), (1.3 * a).cos(), 0.5)) * 20.0;
    let turn = unit(Vector3::new((0.7 * a).cos(), 0.4, a.sin())) * 2f64.to_radians();
    arm.world_from_base *= Isometry3::new(shift, turn);
    arm.tool += unit(Vector3::new(0.3, (2.1 * a).sin(), (1.7 * a).cos())) * 5.0;
    rig
}

/// Training samples of each placement: its mirror poses and direct poses,
/// `J` left to the solver's arm.
fn training(data: &[Dataset]) -> Vec<Vec<Sample>> {
    data.iter()
        .map(|d| {
            d.train
                .iter()
                .chain(&d.direct)
                .cloned()
                .map(|mut s| {
                    s.model_point = None;
                    s
                })
                .collect()
        })
        .collect()
}

fn sets(v: &[Vec<Sample>]) -> Vec<&[Sample]> {
    v.iter().map(Vec::as_slice).collect()
}

fn solve(rig: &Rig, train: &[Vec<Sample>], method: Method, estimate: Estimate) -> Calibration {
    calibrate_placements(
        rig,
        &sets(train),
        method,
        estimate,
        CalibrateOptions::default(),
    )
    .unwrap()
}

/// Base rotation (deg) and translation (mm) errors, tool error (mm).
fn arm_errors(truth: &Rig, base: &Isometry3<f64>, tool: &Vector3<f64>) -> (f64, f64, f64) {
    let arm = truth.arm.as_ref().unwrap();
    (
        base.rotation
            .angle_to(&arm.world_from_base.rotation)
            .to_degrees(),
        (base.translation.vector - arm.world_from_base.translation.vector).norm(),
        (tool - arm.tool).norm(),
    )
}

/// Mean mirror 3D error (mm) on every placement's test poses, against the
/// simulator's true positions.
fn test_error_mm(cal: &Calibration, data: &[Dataset]) -> f64 {
    let mut all = Vec::new();
    for (p, d) in data.iter().enumerate() {
        let e = evaluate_against(
            &d.rig,
            &cal.placements[p].mirror_cameras,
            &d.test,
            &d.truth.test_points,
        )
        .unwrap();
        all.extend(e.mirror.mm);
    }
    all.iter().sum::<f64>() / all.len() as f64
}

/// The user's closed form: every direct view triangulated, registered to
/// the arm's model points in its base frame (the rig's tool).
fn umeyama_base(rig: &Rig, data: &[Dataset]) -> Isometry3<f64> {
    let mut arm = rig.arm.clone().unwrap();
    arm.world_from_base = Isometry3::identity();
    let (mut from, mut to) = (Vec::new(), Vec::new());
    for s in data.iter().flat_map(|d| &d.direct) {
        from.push(arm.end_effector(s.joints.as_ref().unwrap(), &[]).unwrap());
        to.push(triangulate(rig.camera_refs(), s.pixels).unwrap());
    }
    register::rigid(&from, &to).unwrap()
}

#[test]
fn base_and_tool_are_recovered_from_three_placements_and_direct_views() {
    println!(
        "seed | ours: base deg, mm, tool mm | Umeyama: base deg, mm | test mm: ours, oracle, rig as written"
    );
    let mut worst = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut umeyama_worst = (0.0f64, 0.0f64);
    for seed in 1..=8 {
        let data = datasets(seed, PIXEL_SIGMA);
        let truth = data[0].rig.clone();
        let rig = measured_rig(&truth, seed);
        let train = training(&data);
        let cal = solve(&rig, &train, Method::Joint, BOTH);
        let (rot, pos, tool) = arm_errors(
            &truth,
            cal.world_from_base.as_ref().unwrap(),
            cal.tool.as_ref().unwrap(),
        );
        let oracle = solve(&truth, &train, Method::Joint, Estimate::default());
        let as_written = solve(&rig, &train, Method::Joint, Estimate::default());
        let ratio = test_error_mm(&cal, &data) / test_error_mm(&oracle, &data);
        let u = umeyama_base(&rig, &data);
        let (u_rot, u_pos, _) = arm_errors(&truth, &u, &rig.arm.as_ref().unwrap().tool);
        println!(
            "{seed} | {rot:.4} {pos:.3} {tool:.3} (sigma {:.4} {:.3} {:.3}) | {u_rot:.3} {u_pos:.2} | {:.2} {:.2} {:.2} ({ratio:.3}x) fit {:?}",
            cal.uncertainty.base_rotation_deg.unwrap(),
            cal.uncertainty.base_translation_mm.unwrap(),
            cal.uncertainty.tool_mm.unwrap(),
            test_error_mm(&cal, &data),
            test_error_mm(&oracle, &data),
            test_error_mm(&as_written, &data),
            cal.fit
        );
        worst = (
            worst.0.max(rot),
            worst.1.max(pos),
            worst.2.max(tool),
            worst.3.max(ratio),
        );
        umeyama_worst = (umeyama_worst.0.max(u_rot), umeyama_worst.1.max(u_pos));
    }
    println!("worst: ours {worst:?}, Umeyama {umeyama_worst:?}");
    assert!(worst.0 < 0.1, "base rotation {} deg", worst.0);
    assert!(worst.1 < 1.0, "base position {} mm", worst.1);
    assert!(worst.2 < 1.0, "tool {} mm", worst.2);
    assert!(worst.3 < 1.15, "test error {}x the oracle's", worst.3);
}

/// RMS of error / sigma over runs.
fn rms(normalised: &[f64]) -> f64 {
    (normalised.iter().map(|z| z * z).sum::<f64>() / normalised.len() as f64).sqrt()
}

#[test]
fn the_stated_base_tool_and_plane_sigmas_are_honest_over_many_seeds() {
    const SEEDS: u64 = 24;
    let names = [
        "base rotation",
        "base position",
        "tool",
        "plane angle",
        "plane distance",
    ];
    let mut normalised: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    for seed in 101..101 + SEEDS {
        let data = datasets(seed, PIXEL_SIGMA);
        let truth = data[0].rig.clone();
        let rig = measured_rig(&truth, seed);
        let cal = solve(&rig, &training(&data), Method::Joint, BOTH);
        let u = &cal.uncertainty;
        let (rot, pos, tool) = arm_errors(
            &truth,
            cal.world_from_base.as_ref().unwrap(),
            cal.tool.as_ref().unwrap(),
        );
        normalised[0].push(rot / u.base_rotation_deg.unwrap());
        normalised[1].push(pos / u.base_translation_mm.unwrap());
        normalised[2].push(tool / u.tool_mm.unwrap());
        for (p, d) in data.iter().enumerate() {
            let (plane, sigma) = (cal.placements[p].plane.unwrap(), u.placements[p]);
            let angle = plane
                .normal
                .angle(&d.truth.mirror.plane.normal)
                .to_degrees();
            normalised[3].push(angle / sigma.angle_deg.unwrap());
            normalised[4].push(
                (plane.distance - d.truth.mirror.plane.distance) / sigma.distance_mm.unwrap(),
            );
        }
    }
    println!("quantity | RMS of error / sigma ({SEEDS} seeds, planes of 3 placements each)");
    for (name, z) in names.iter().zip(&normalised) {
        println!("{name} | {:.2}", rms(z));
    }
    for (name, z) in names.iter().zip(&normalised) {
        let r = rms(z);
        assert!(
            (0.7..=1.4).contains(&r),
            "{name}: RMS of error / sigma {r:.2}"
        );
    }
}

#[test]
fn encoder_offsets_are_estimated_beside_the_base_and_tool() {
    // The first joint's offset is a turn of the base and the last's a shift
    // of the tool: with both estimated, those two are not separate unknowns,
    // so the truth here has offsets on the joints between.
    let scene = nico_scene();
    let dof = scene.rig.arm.as_ref().unwrap().dof();
    let mut offsets = vec![0.0; dof];
    for (j, o) in offsets.iter_mut().enumerate().take(dof - 1).skip(1) {
        *o = (0.8 - 0.5 * j as f64).to_radians();
    }
    let noise = NoiseModel {
        pixel_sigma: PIXEL_SIGMA,
        joint_offsets: offsets.clone(),
    };
    let counts = Counts {
        train: 20,
        test: 30,
        direct: 10,
    };
    let data: Vec<Dataset> = (0..3)
        .map(|m| generate(&scene, m, &noise, counts, 77 + m as u64).unwrap())
        .collect();
    let truth = data[0].rig.clone();
    let rig = measured_rig(&truth, 5);
    let cal = solve(&rig, &training(&data), Method::JointKinematics, BOTH);
    let (rot, pos, tool) = arm_errors(
        &truth,
        cal.world_from_base.as_ref().unwrap(),
        cal.tool.as_ref().unwrap(),
    );
    let found = cal.joint_offsets.clone().unwrap();
    let sigmas = cal.uncertainty.joint_offsets_deg.clone().unwrap();
    println!(
        "base {rot:.4} deg {pos:.3} mm, tool {tool:.3} mm; offsets {found:?} (true {offsets:?}), sigmas {sigmas:?}"
    );
    assert!(rot < 0.1 && pos < 1.0 && tool < 1.0);
    // Not estimated: the first and the last, which have no sigma.
    assert_eq!((found[0], found[dof - 1]), (0.0, 0.0));
    assert_eq!((sigmas[0], sigmas[dof - 1]), (None, None));
    for j in 1..dof - 1 {
        let error = (found[j] - offsets[j]).to_degrees().abs();
        assert!(
            error < 4.0 * sigmas[j].unwrap(),
            "joint {j}: {error} deg off, sigma {:?}",
            sigmas[j]
        );
    }
}

#[test]
fn what_cannot_be_determined_is_refused_in_one_line() {
    let data = datasets(3, PIXEL_SIGMA);
    let truth = data[0].rig.clone();
    let rig = measured_rig(&truth, 3);
    let options = CalibrateOptions::default();
    let mirror_only: Vec<Vec<Sample>> = data.iter().map(|d| d.train.clone()).collect();
    let refusal = |placements: &[Vec<Sample>], method, estimate| match calibrate_placements(
        &rig,
        &sets(placements),
        method,
        estimate,
        options,
    ) {
        Err(e @ CalibrateError::CannotEstimate { .. }) => e.to_string(),
        other => panic!("{method} {estimate:?}: {other:?}"),
    };
    let base = Estimate {
        base: true,
        tool: false,
    };
    // One placement, mirror views only: the plane trades off against the base.
    let one = refusal(&mirror_only[..1], Method::Joint, base);
    println!("{one}");
    assert!(one.contains("the arm's base") && one.contains("trades off") && !one.contains('\n'));
    // Two placements, mirror views only: the planes may still turn together
    // about their line of intersection with the base.
    let two = refusal(&mirror_only[..2], Method::Joint, BOTH);
    println!("{two}");
    assert!(two.contains("base") && !two.contains('\n'));
    // The paper's method has no arm to correct.
    let paper = refusal(&training(&data)[..1], Method::Paper, BOTH);
    assert!(paper.contains("paper"), "{paper}");
    // Three placements of mirror views alone do determine it.
    let cal =
        calibrate_placements(&rig, &sets(&mirror_only), Method::Joint, BOTH, options).unwrap();
    let (rot, pos, _) = arm_errors(
        &truth,
        cal.world_from_base.as_ref().unwrap(),
        &truth.arm.as_ref().unwrap().tool,
    );
    println!(
        "three placements, mirror views only: base {rot:.3} deg, {pos:.2} mm (sigma {:?} deg, {:?} mm), rms {:.3} px, fit {:?}",
        cal.uncertainty.base_rotation_deg,
        cal.uncertainty.base_translation_mm,
        cal.train_rms_px,
        cal.fit
    );
    // Weakly (through the planes' lines of intersection), so within three
    // of its sigmas, which are ten times those with direct views.
    let u = &cal.uncertainty;
    assert!(rot < 3.0 * u.base_rotation_deg.unwrap() && pos < 3.0 * u.base_translation_mm.unwrap());
}
