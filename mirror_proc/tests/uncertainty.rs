//! The stated uncertainty is honest: over many seeds of the simulator, each
//! estimate's error divided by its stated sigma has an RMS near 1 (within
//! [0.7, 1.4]) — for the plane's angle and distance, each encoder offset,
//! the mirror cameras' centres and orientations, and a point located through
//! them.
//!
//! `joint` is run on arms whose encoders read true (an offset it cannot
//! model is a bias, not noise, and no covariance covers it);
//! `joint+kinematics` on the `nico` preset's offsets.

use geometry::Camera;
use geometry::sim::{Counts, Dataset, NoiseModel, generate, nico_noise, nico_scene};
use geometry::triangulate::triangulate;
use mirror_proc::calibrate::uncertainty::rms_error_mm;
use mirror_proc::calibrate::{Calibration, Method, calibrate};
use mirror_proc::experiment::rotation_error;

/// Seeds per mirror placement; three placements each.
const SEEDS: u64 = 24;
/// Training poses per calibration.
const TRAIN: usize = 20;

fn dataset(mirror: usize, noise: &NoiseModel, seed: u64) -> Dataset {
    let counts = Counts {
        train: TRAIN,
        test: 5,
        direct: 0,
    };
    generate(&nico_scene(), mirror, noise, counts, seed).unwrap()
}

/// Normalised errors of one quantity, pooled over runs.
#[derive(Default)]
struct Coverage {
    name: String,
    normalised: Vec<f64>,
    sigmas: Vec<f64>,
}

impl Coverage {
    fn push(&mut self, error: f64, sigma: f64) {
        assert!(
            sigma > 0.0 && sigma.is_finite(),
            "{}: sigma {sigma}",
            self.name
        );
        self.normalised.push(error / sigma);
        self.sigmas.push(sigma);
    }

    fn rms(&self) -> f64 {
        (self.normalised.iter().map(|z| z * z).sum::<f64>() / self.normalised.len() as f64).sqrt()
    }

    fn median_sigma(&self) -> f64 {
        let mut s = self.sigmas.clone();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    }
}

struct Table(Vec<Coverage>);

impl Table {
    fn get(&mut self, name: &str) -> &mut Coverage {
        if let Some(i) = self.0.iter().position(|c| c.name == name) {
            return &mut self.0[i];
        }
        self.0.push(Coverage {
            name: name.to_string(),
            ..Coverage::default()
        });
        self.0.last_mut().unwrap()
    }

    fn assert_honest(&self) {
        println!("| quantity | runs | median stated 1-sigma | RMS of error / sigma |");
        println!("|---|---|---|---|");
        for c in &self.0 {
            println!(
                "| {} | {} | {:.4} | {:.2} |",
                c.name,
                c.normalised.len(),
                c.median_sigma(),
                c.rms()
            );
        }
        for c in &self.0 {
            assert!(
                (0.7..=1.4).contains(&c.rms()),
                "{}: RMS of error / sigma {:.2} over {} runs",
                c.name,
                c.rms(),
                c.normalised.len()
            );
        }
    }
}

fn plane_and_cameras(table: &mut Table, method: &str, cal: &Calibration, d: &Dataset) {
    let u = &cal.uncertainty;
    if let Some(plane) = cal.plane {
        let truth = d.truth.mirror.plane;
        let angle = plane.normal.dot(&truth.normal).clamp(-1.0, 1.0).acos();
        table
            .get(&format!("{method}: plane angle (deg)"))
            .push(angle.to_degrees(), u.plane_angle_deg.unwrap());
        table.get(&format!("{method}: plane distance (mm)")).push(
            plane.distance - truth.distance,
            u.plane_distance_mm.unwrap(),
        );
    }
    for (k, side) in ["left", "right"].into_iter().enumerate() {
        let (got, want): (&Camera, &Camera) = (&cal.mirror_cameras[k], &d.truth.mirror_cameras[k]);
        table
            .get(&format!("{method}: {side} mirror camera centre (mm)"))
            .push(
                (got.center - want.center).norm(),
                u.mirror_camera_centers_mm[k],
            );
        table
            .get(&format!("{method}: {side} mirror camera angle (deg)"))
            .push(
                rotation_error(got, want).to_degrees(),
                u.mirror_camera_angles_deg[k],
            );
    }
    // The arm's marker at the test poses, located as any object would be.
    let cams = &cal.mirror_cameras;
    for (s, truth) in d.test.iter().zip(&d.truth.test_points) {
        let p = triangulate([&cams[0], &cams[1]], s.pixels).unwrap();
        let cov = u.located_covariance(cams, &p).unwrap();
        table
            .get(&format!("{method}: located point (mm)"))
            .push((p - truth).norm(), rms_error_mm(&cov));
    }
}

#[test]
fn the_stated_uncertainty_is_honest_over_many_seeds() {
    let true_encoders = NoiseModel {
        joint_offsets: vec![0.0; 4],
        ..nico_noise()
    };
    let mut table = Table(Vec::new());
    for mirror in 0..3 {
        for seed in 0..SEEDS {
            let d = dataset(mirror, &true_encoders, 1000 + seed);
            for method in [Method::Paper, Method::Joint] {
                let cal = calibrate(&d.rig, &d.train, method).unwrap();
                plane_and_cameras(&mut table, method.as_str(), &cal, &d);
            }
            let d = dataset(mirror, &nico_noise(), 2000 + seed);
            let cal = calibrate(&d.rig, &d.train, Method::JointKinematics).unwrap();
            plane_and_cameras(&mut table, "joint+kinematics", &cal, &d);
            let sigmas = cal.uncertainty.joint_offsets_deg.as_ref().unwrap();
            for (j, (got, want)) in cal
                .joint_offsets
                .as_ref()
                .unwrap()
                .iter()
                .zip(&d.truth.joint_offsets)
                .enumerate()
            {
                table
                    .get(&format!("joint+kinematics: encoder offset {} (deg)", j + 1))
                    .push((got - want).to_degrees(), sigmas[j].unwrap());
            }
        }
    }
    table.assert_honest();
}
