//! A seeded simulator of mirror-calibration datasets with ground truth.
//!
//! The `nico` preset mimics the paper's robot: a 640x480 stereo head with a
//! 60 mm baseline and mild radial distortion, a 4-DOF right arm (shoulder
//! pair, elbow pair, links 130 mm and 127 mm) and three mirror placements in
//! front of it. The robot's own model ([`Scene::rig`]) is exact except for
//! per-joint encoder offsets ([`NoiseModel::joint_offsets`]): the encoders
//! read `q_true - offsets`, so the model misplaces the end-effector unless
//! the offsets are estimated. Detections get i.i.d. Gaussian pixel noise.

mod world;

pub use world::{
    ARM_MARKER_ID, FIDUCIAL_IDS, Facing, FixedMarker, HIDDEN_OBJECT_ID, MARKER_MARGIN_MM,
    MARKER_SIZE_MM, ROBOT_BODY_MM, SeenCard, SimWorld, WorldChange, card_corners, line_through_box,
    segment_meets_box,
};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::f64::consts::FRAC_PI_2;

use crate::{
    Arm, Camera, DhJoint, Distortion, GeometryError, Intrinsics, Plane, Rig, Sample, View,
};

/// A finite planar mirror.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mirror {
    /// The mirror's plane, normal towards the robot.
    pub plane: Plane,
    /// Centre of the reflecting rectangle, mm.
    pub center: Vector3<f64>,
    /// Unit vector along the rectangle's width.
    pub width_axis: Vector3<f64>,
    /// Width and height of the rectangle, mm.
    pub size: Vector2<f64>,
}

impl Mirror {
    /// A mirror centred at `center`, facing the robot with its normal turned
    /// by `yaw` (about the vertical) and `pitch` (about the horizontal) from
    /// straight back at the head.
    pub fn facing(center: Vector3<f64>, yaw: f64, pitch: f64, size: Vector2<f64>) -> Self {
        let turn = Rotation3::from_euler_angles(pitch, yaw, 0.0);
        let normal = turn * Vector3::new(0.0, 0.0, -1.0);
        let plane = Plane::through(&center, normal).expect("unit normal");
        Self {
            plane,
            center,
            width_axis: turn * Vector3::x(),
            size,
        }
    }

    /// This mirror turned by `tilt_deg` about its width axis through its
    /// centre, then moved `shift_mm` along its (turned) normal, towards
    /// the robot: a mirror that was bumped.
    pub fn moved(&self, tilt_deg: f64, shift_mm: f64) -> Self {
        let turn = Rotation3::new(self.width_axis * tilt_deg.to_radians());
        let normal = turn * self.plane.normal.into_inner();
        let center = self.center + normal * shift_mm;
        Self {
            plane: Plane::through(&center, normal).expect("unit normal"),
            center,
            ..*self
        }
    }

    /// Whether `eye` sees the glass behind the point `p` in front of it:
    /// the line of sight through `p` meets the glass farther on.
    pub fn glass_behind(&self, eye: &Vector3<f64>, p: &Vector3<f64>) -> bool {
        // Far enough along the line to be past any glass in the room.
        self.ray_hits_glass(eye, &(eye + (p - eye) * 20.0))
    }

    /// Whether the ray from `eye` to the virtual point `behind` passes through the glass.
    pub fn ray_hits_glass(&self, eye: &Vector3<f64>, behind: &Vector3<f64>) -> bool {
        let (de, db) = (
            self.plane.signed_distance(eye),
            self.plane.signed_distance(behind),
        );
        if !(de > 0.0 && db < 0.0) {
            return false;
        }
        let hit = eye + (behind - eye) * (de / (de - db));
        let height_axis = self.plane.normal.cross(&self.width_axis);
        let off = hit - self.center;
        off.dot(&self.width_axis).abs() <= self.size.x / 2.0
            && off.dot(&height_axis).abs() <= self.size.y / 2.0
    }
}

/// A robot and the mirrors it can be placed in front of.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The robot's calibrated model (cameras exact, arm nominal).
    pub rig: Rig,
    /// Mirror placements.
    pub mirrors: Vec<Mirror>,
}

/// Errors the model makes about the world.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseModel {
    /// Standard deviation of the detected marker centre, pixels, per axis.
    pub pixel_sigma: f64,
    /// True encoder offsets, rad: the true joint angle is `reading + offset`.
    pub joint_offsets: Vec<f64>,
}

impl NoiseModel {
    /// No noise at all, for `dof` joints.
    pub fn none(dof: usize) -> Self {
        Self {
            pixel_sigma: 0.0,
            joint_offsets: vec![0.0; dof],
        }
    }
}

/// How many samples of each kind to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Counts {
    /// Mirror-view training poses.
    pub train: usize,
    /// Mirror-view test poses.
    pub test: usize,
    /// Direct-view test poses.
    pub direct: usize,
}

impl Counts {
    /// The paper's protocol: 50 training and 100 test poses; 100 direct poses.
    pub const PAPER: Counts = Counts {
        train: 50,
        test: 100,
        direct: 100,
    };
}

/// What the simulator knows and the robot does not.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// The mirror.
    pub mirror: Mirror,
    /// Exact (proper) mirror-perspective cameras, left then right.
    pub mirror_cameras: [Camera; 2],
    /// True encoder offsets.
    pub joint_offsets: Vec<f64>,
    /// True end-effector positions of `train`, `test` and `direct`, in order.
    pub train_points: Vec<Vector3<f64>>,
    /// See `train_points`.
    pub test_points: Vec<Vector3<f64>>,
    /// See `train_points`.
    pub direct_points: Vec<Vector3<f64>>,
}

/// A simulated dataset for one mirror placement.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// The robot's model.
    pub rig: Rig,
    /// Mirror-view training samples.
    pub train: Vec<Sample>,
    /// Mirror-view test samples.
    pub test: Vec<Sample>,
    /// Direct-view test samples.
    pub direct: Vec<Sample>,
    /// Ground truth.
    pub truth: Truth,
}

/// Pixels kept clear of the image border for a sample to count as seen.
const IMAGE_MARGIN_PX: f64 = 15.0;
/// Half the side of the marker card (code and white margin), mm: the whole
/// card must be in view for a pose to count as seen.
pub const CARD_HALF_SIDE_MM: f64 = MARKER_SIZE_MM / 2.0 + MARKER_MARGIN_MM;
/// Closest the marker may come to the glass, mm.
const MIN_MIRROR_CLEARANCE_MM: f64 = 40.0;
/// Pose draws allowed per accepted sample before giving up.
const MAX_DRAWS_PER_SAMPLE: usize = 20_000;

/// The Nico-like scene: stereo head, right arm, three mirror placements.
pub fn nico_scene() -> Scene {
    let intrinsics = |cx: f64, cy: f64, fx: f64| Intrinsics {
        width: 640,
        height: 480,
        fx,
        fy: fx * 0.998,
        skew: 0.0,
        cx,
        cy,
        dist: Distortion::radial(-0.21, 0.045),
    };
    // Slight toe-in and a small vertical misalignment, as on a real head.
    let left_r = *Rotation3::from_euler_angles(0.004, 0.035, 0.002).matrix();
    let right_r = *Rotation3::from_euler_angles(-0.003, -0.035, -0.001).matrix();
    let cameras = [
        Camera::new(
            intrinsics(322.0, 238.0, 548.0),
            left_r,
            Vector3::new(-30.0, 0.0, 0.0),
        ),
        Camera::new(
            intrinsics(317.5, 243.0, 552.0),
            right_r,
            Vector3::new(30.0, 0.0, 0.0),
        ),
    ];
    // Arm base at the right shoulder, 170 mm below and 100 mm right of the
    // head; base x points down, y forward, z along the shoulder (lateral) axis.
    let base_rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        Vector3::y(),
        Vector3::z(),
        Vector3::x(),
    ]));
    let world_from_base = Isometry3::from_parts(
        Translation3::new(100.0, 170.0, 30.0),
        UnitQuaternion::from_rotation_matrix(&base_rotation),
    );
    let joint = |a, alpha, d, theta_offset, min, max| DhJoint {
        a,
        alpha,
        d,
        theta_offset,
        min,
        max,
    };
    let arm = Arm::dh(
        world_from_base,
        vec![
            joint(0.0, FRAC_PI_2, 0.0, 0.0, 0.2, 2.2), // shoulder flexion
            joint(0.0, FRAC_PI_2, 0.0, FRAC_PI_2, -0.9, 0.7), // shoulder abduction
            joint(0.0, -FRAC_PI_2, 130.0, 0.0, -1.2, 1.2), // upper-arm rotation
            joint(127.0, 0.0, 0.0, 0.0, -1.4, 1.1),    // elbow
        ],
        Vector3::zeros(),
    );
    let size = Vector2::new(700.0, 500.0);
    let mirrors = vec![
        Mirror::facing(Vector3::new(20.0, 150.0, 520.0), 0.05, -0.12, size),
        Mirror::facing(Vector3::new(160.0, 140.0, 480.0), -0.35, -0.08, size),
        Mirror::facing(Vector3::new(-110.0, 190.0, 560.0), 0.28, 0.10, size),
    ];
    Scene {
        rig: Rig {
            names: ["left".into(), "right".into()],
            cameras,
            arm: Some(arm),
            pixel_sigma: None,
        },
        mirrors,
    }
}

/// The `nico` noise preset. Chosen once, on direct views only, so that the
/// direct-view errors of the nominal model land near the paper's 5.12 mm and
/// 5.66 px (see `mirror_proc`'s `fit_nico_noise` example); never tuned on
/// mirror figures.
pub fn nico_noise() -> NoiseModel {
    nico_noise_scaled(NICO_PIXEL_SIGMA, NICO_OFFSET_SCALE)
}

/// Pixel noise of the `nico` preset.
pub const NICO_PIXEL_SIGMA: f64 = 2.6;
/// Encoder offset scale (rad) of the `nico` preset.
pub const NICO_OFFSET_SCALE: f64 = 0.007;

/// The preset's shape of encoder offsets, scaled: used to fit the preset.
pub fn nico_noise_scaled(pixel_sigma: f64, offset_scale: f64) -> NoiseModel {
    nico_noise_shaped(pixel_sigma, offset_scale, 4)
}

/// The `nico` preset's noise for an arm of `dof` joints: its pixel noise,
/// and its encoder offset pattern repeated over the joints.
pub fn nico_noise_for(dof: usize) -> NoiseModel {
    nico_noise_shaped(NICO_PIXEL_SIGMA, NICO_OFFSET_SCALE, dof)
}

fn nico_noise_shaped(pixel_sigma: f64, offset_scale: f64, dof: usize) -> NoiseModel {
    NoiseModel {
        pixel_sigma,
        joint_offsets: [1.0, -0.8, 0.6, -1.0]
            .iter()
            .cycle()
            .take(dof)
            .map(|w| w * offset_scale)
            .collect(),
    }
}

/// The joint values of `count` training poses for mirror `mirror_index`
/// of the `nico` scene (seeded): poses to drive the simulated arm
/// through, for tests and benchmarks of what the cameras see.
pub fn nico_train_poses(
    mirror_index: usize,
    count: usize,
    seed: u64,
) -> Result<Vec<Vec<f64>>, GeometryError> {
    let counts = Counts {
        train: count,
        test: 0,
        direct: 0,
    };
    let data = generate(&nico_scene(), mirror_index, &nico_noise(), counts, seed)?;
    data.train
        .into_iter()
        .map(|s| {
            s.joints
                .ok_or_else(|| GeometryError::Degenerate("a training pose without joints".into()))
        })
        .collect()
}

/// The arm's frames going through `poses` as a camera at `fps` sees it:
/// from each pose to the next in `move_frames` frames at constant joint
/// speed, then still for `dwell_frames`. Per frame: joint values and joint
/// speeds (rad/s).
pub fn sweep(
    poses: &[Vec<f64>],
    move_frames: usize,
    dwell_frames: usize,
    fps: f64,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut frames = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        if let (Some(prev), true) = (i.checked_sub(1).map(|j| &poses[j]), move_frames > 0) {
            let seconds = move_frames as f64 / fps;
            let speed: Vec<f64> = pose
                .iter()
                .zip(prev)
                .map(|(b, a)| (b - a) / seconds)
                .collect();
            for f in 1..=move_frames {
                let t = f as f64 / move_frames as f64;
                let q = prev
                    .iter()
                    .zip(pose)
                    .map(|(a, b)| a + (b - a) * t)
                    .collect();
                frames.push((q, speed.clone()));
            }
        }
        for _ in 0..dwell_frames {
            frames.push((pose.clone(), vec![0.0; pose.len()]));
        }
    }
    frames
}

/// Offsets from a card's centre that stand for its extent in any
/// orientation: the centre and half a side along x and y.
const CARD_EXTENT: [Vector3<f64>; 5] = [
    Vector3::new(0.0, 0.0, 0.0),
    Vector3::new(CARD_HALF_SIDE_MM, 0.0, 0.0),
    Vector3::new(-CARD_HALF_SIDE_MM, 0.0, 0.0),
    Vector3::new(0.0, CARD_HALF_SIDE_MM, 0.0),
    Vector3::new(0.0, -CARD_HALF_SIDE_MM, 0.0),
];

/// Whether a card of half side [`CARD_HALF_SIDE_MM`] centred at `p` (any
/// orientation) projects inside the image with [`IMAGE_MARGIN_PX`] to spare,
/// and, for a virtual point `p` behind `glass`, is seen through the glass.
fn card_in_view(cam: &Camera, p: &Vector3<f64>, glass: Option<&Mirror>) -> bool {
    CARD_EXTENT.iter().all(|o| {
        let q = p + o;
        cam.depth(&q) > 0.0
            && cam
                .project(&q)
                .is_ok_and(|px| cam.intrinsics.contains(&px, IMAGE_MARGIN_PX))
            && glass.is_none_or(|m| m.ray_hits_glass(&cam.center, &q))
    })
}

/// Whether the card at `p` (any orientation) stands in the way of the
/// camera's view of its own reflection: a ray from the camera to the glass
/// towards the reflected card (centre and the card's extent around it)
/// passes within the card's half diagonal of `p`.
fn card_blocks_its_reflection(cam: &Camera, p: &Vector3<f64>, mirror: &Mirror) -> bool {
    let virt = mirror.plane.reflect_point(p);
    let reach = CARD_HALF_SIDE_MM * std::f64::consts::SQRT_2;
    CARD_EXTENT.iter().any(|o| {
        let target = virt + o;
        let (de, dt) = (
            mirror.plane.signed_distance(&cam.center),
            mirror.plane.signed_distance(&target),
        );
        if de - dt <= 0.0 {
            return false;
        }
        let glass = cam.center + (target - cam.center) * (de / (de - dt));
        // Distance from p to the segment camera -> glass.
        let d = glass - cam.center;
        let t = ((p - cam.center).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
        (cam.center + d * t - p).norm() < reach
    })
}

/// Draws a dataset for mirror `mirror_index` of `scene`. Deterministic in `seed`.
pub fn generate(
    scene: &Scene,
    mirror_index: usize,
    noise: &NoiseModel,
    counts: Counts,
    seed: u64,
) -> Result<Dataset, GeometryError> {
    let mirror = *scene.mirrors.get(mirror_index).ok_or_else(|| {
        GeometryError::Degenerate(format!(
            "mirror {mirror_index} does not exist (the scene has {})",
            scene.mirrors.len()
        ))
    })?;
    let arm = scene
        .rig
        .arm
        .as_ref()
        .ok_or_else(|| GeometryError::Degenerate("the scene has no arm".into()))?;
    if noise.joint_offsets.len() != arm.dof() {
        return Err(GeometryError::Degenerate(format!(
            "{} joint offsets for an arm with {} joints",
            noise.joint_offsets.len(),
            arm.dof()
        )));
    }
    if !(noise.pixel_sigma >= 0.0 && noise.pixel_sigma.is_finite()) {
        return Err(GeometryError::NonFinite("pixel sigma"));
    }
    let cams = &scene.rig.cameras;
    let mirror_cameras = [
        mirror.plane.mirror_camera(&cams[0]),
        mirror.plane.mirror_camera(&cams[1]),
    ];
    let pixel_noise =
        Normal::new(0.0, noise.pixel_sigma).map_err(|_| GeometryError::NonFinite("pixel sigma"))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ ((mirror_index as u64) << 32));

    let seen_in_mirror = |p: &Vector3<f64>| -> Option<[Vector2<f64>; 2]> {
        if mirror.plane.signed_distance(p) < MIN_MIRROR_CLEARANCE_MM {
            return None;
        }
        let virt = mirror.plane.reflect_point(p);
        let mut px = [Vector2::zeros(); 2];
        for k in 0..2 {
            if cams[k].depth(&virt) <= 0.0 {
                return None;
            }
            px[k] = cams[k].project(&virt).ok()?;
            if !card_in_view(&cams[k], &virt, Some(&mirror))
                || card_blocks_its_reflection(&cams[k], p, &mirror)
            {
                return None;
            }
        }
        Some(px)
    };
    let seen_directly = |p: &Vector3<f64>| -> Option<[Vector2<f64>; 2]> {
        let mut px = [Vector2::zeros(); 2];
        for k in 0..2 {
            // In front of the head by a margin, and in front of the mirror.
            if cams[k].depth(p) < 100.0 || mirror.plane.signed_distance(p) < MIN_MIRROR_CLEARANCE_MM
            {
                return None;
            }
            px[k] = cams[k].project(p).ok()?;
            if !card_in_view(&cams[k], p, None) {
                return None;
            }
        }
        Some(px)
    };

    let draw = |count: usize,
                view: View,
                first_pose: u64,
                rng: &mut ChaCha8Rng|
     -> Result<(Vec<Sample>, Vec<Vector3<f64>>), GeometryError> {
        let mut samples = Vec::with_capacity(count);
        let mut points = Vec::with_capacity(count);
        let mut draws = 0usize;
        while samples.len() < count {
            draws += 1;
            if draws > MAX_DRAWS_PER_SAMPLE * count.max(1) {
                return Err(GeometryError::Degenerate(format!(
                    "could not find {count} {} poses for mirror {mirror_index}",
                    view.as_str()
                )));
            }
            let q_true: Vec<f64> = arm
                .limits()
                .into_iter()
                .map(|(min, max)| rng.random_range(min..=max))
                .collect();
            let p = arm.end_effector(&q_true, &[])?;
            let seen = match view {
                View::Mirror => seen_in_mirror(&p),
                View::Direct => seen_directly(&p),
            };
            let Some(px) = seen else { continue };
            let reading: Vec<f64> = q_true
                .iter()
                .zip(&noise.joint_offsets)
                .map(|(q, o)| q - o)
                .collect();
            let model_point = arm.end_effector(&reading, &[])?;
            let pixels =
                px.map(|p| p + Vector2::new(pixel_noise.sample(rng), pixel_noise.sample(rng)));
            samples.push(Sample {
                pose: first_pose + samples.len() as u64,
                view,
                joints: Some(reading),
                model_point: Some(model_point),
                pixels,
            });
            points.push(p);
        }
        Ok((samples, points))
    };
    let (train, train_points) = draw(counts.train, View::Mirror, 0, &mut rng)?;
    let (test, test_points) = draw(counts.test, View::Mirror, 10_000, &mut rng)?;
    let (direct, direct_points) = draw(counts.direct, View::Direct, 20_000, &mut rng)?;
    Ok(Dataset {
        // The detections carry the noise drawn here, and the rig says so.
        rig: Rig {
            pixel_sigma: (noise.pixel_sigma > 0.0).then_some(noise.pixel_sigma),
            ..scene.rig.clone()
        },
        train,
        test,
        direct,
        truth: Truth {
            mirror,
            mirror_cameras,
            joint_offsets: noise.joint_offsets.clone(),
            train_points,
            test_points,
            direct_points,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nico_scene_yields_every_mirror_and_is_deterministic() {
        let scene = nico_scene();
        for m in 0..scene.mirrors.len() {
            let a = generate(&scene, m, &nico_noise(), Counts::PAPER, 7).unwrap();
            let b = generate(&scene, m, &nico_noise(), Counts::PAPER, 7).unwrap();
            assert_eq!(a, b);
            assert_eq!(a.train.len(), 50);
            assert_eq!(a.direct.len(), 100);
        }
        let c = generate(&scene, 0, &nico_noise(), Counts::PAPER, 8).unwrap();
        assert_ne!(
            c.train,
            generate(&scene, 0, &nico_noise(), Counts::PAPER, 7)
                .unwrap()
                .train
        );
    }

    #[test]
    fn a_sweep_moves_at_constant_speed_then_dwells() {
        let frames = sweep(&[vec![0.0, 1.0], vec![1.0, 0.0]], 4, 2, 40.0);
        assert_eq!(frames.len(), 2 + 4 + 2);
        assert_eq!(frames[1], (vec![0.0, 1.0], vec![0.0, 0.0]));
        assert!((frames[3].0[0] - 0.5).abs() < 1e-12);
        assert!((frames[3].1[0] - 10.0).abs() < 1e-12, "1 rad in 0.1 s");
        assert_eq!(frames[7], (vec![1.0, 0.0], vec![0.0, 0.0]));
    }

    #[test]
    fn noiseless_samples_are_exact_reflections() {
        let scene = nico_scene();
        let d = generate(
            &scene,
            1,
            &NoiseModel::none(4),
            Counts {
                train: 20,
                test: 0,
                direct: 5,
            },
            1,
        )
        .unwrap();
        for (s, p) in d.train.iter().zip(&d.truth.train_points) {
            let virt = d.truth.mirror.plane.reflect_point(p);
            for k in 0..2 {
                let px = scene.rig.cameras[k].project(&virt).unwrap();
                assert!((px - s.pixels[k]).norm() < 1e-9);
                // and the mirror camera sees the real point at the same pixel
                assert!((d.truth.mirror_cameras[k].project(p).unwrap() - px).norm() < 1e-9);
            }
            assert!((s.model_point.unwrap() - p).norm() < 1e-9);
        }
    }

    #[test]
    fn encoder_offsets_bias_the_model_point() {
        let scene = nico_scene();
        let d = generate(
            &scene,
            0,
            &nico_noise(),
            Counts {
                train: 10,
                test: 0,
                direct: 0,
            },
            3,
        )
        .unwrap();
        let arm = scene.rig.arm.as_ref().unwrap();
        for (s, p) in d.train.iter().zip(&d.truth.train_points) {
            let q = s.joints.as_ref().unwrap();
            let corrected = arm.end_effector(q, &d.truth.joint_offsets).unwrap();
            assert!((corrected - p).norm() < 1e-9);
            assert!((s.model_point.unwrap() - p).norm() > 0.1);
        }
    }
}
