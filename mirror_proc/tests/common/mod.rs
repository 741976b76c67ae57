//! The live stage's input streams made from simulated samples.

#![allow(dead_code)]

use geometry::Sample;
use geometry::sim::{Counts, Dataset, NoiseModel, Scene, generate, nico_noise_scaled};
use messages::{CalibrationMsg, CameraMarkers, JointState, Marker, Phase, Role, StereoDetections};
use mirror_proc::live::{Live, LiveConfig, Output};

/// Time per pose: the arm moves for the first 100 ms, then holds.
pub const POSE_PERIOD_NS: i64 = 300_000_000;

/// Joint states at 100 Hz (move 100 ms, dwell 200 ms per pose) and
/// detections at 30 Hz whose marker centres are the samples' pixels (as
/// the tracker reads them: mirror-reversed unless the pose is direct).
pub fn streams_of(poses: &[(&Sample, Role)]) -> (Vec<JointState>, Vec<StereoDetections>) {
    let period = POSE_PERIOD_NS;
    let mut joints = Vec::new();
    for t in (0..poses.len() as i64 * period + 50_000_000).step_by(10_000_000) {
        let i = (t / period) as usize;
        let mut js = JointState {
            seq: joints.len() as u64,
            stamp_ns: t,
            ..Default::default()
        };
        if let Some((s, r)) = poses.get(i) {
            let q = s.joints.as_ref().expect("joint readings");
            js.dof = q.len() as u32;
            js.pose = s.pose;
            js.role = *r as u32;
            js.phase = if t - i as i64 * period >= 100_000_000 {
                Phase::Settled as u32
            } else {
                Phase::Moving as u32
            };
            js.q[..q.len()].copy_from_slice(q);
            js.model_point = s.model_point.expect("model point").into();
        } else {
            js.dof = poses
                .first()
                .map_or(0, |(s, _)| s.joints.as_ref().map_or(0, Vec::len))
                as u32;
            js.phase = Phase::Done as u32;
        }
        joints.push(js);
    }
    let mut detections = Vec::new();
    for (n, t) in (0..poses.len() as i64 * period + 100_000_000)
        .step_by(33_333_333)
        .enumerate()
    {
        let i = (t / period) as usize;
        let mut d = StereoDetections {
            seq: n as u64,
            stamp_ns: t + 1,
            ..Default::default()
        };
        // The marker is only where the pose holds still.
        if let Some((s, role)) = poses
            .get(i)
            .filter(|_| t - i as i64 * period >= 100_000_000)
        {
            for k in 0..2 {
                let mut cam = CameraMarkers::default();
                cam.push(Marker {
                    id: 0,
                    mirrored: u32::from(*role != Role::Direct),
                    corners: [0.0; 8],
                    center: s.pixels[k].into(),
                });
                d.cameras[k] = cam;
            }
        }
        detections.push(d);
    }
    (joints, detections)
}

/// The streams interleaved by stamp, as they arrive live.
pub fn by_stamp(joints: &[JointState], detections: &[StereoDetections]) -> Vec<bool> {
    let (mut j, mut d, mut order) = (0, 0, Vec::new());
    while j < joints.len() || d < detections.len() {
        let take_joint = d == detections.len()
            || (j < joints.len() && joints[j].stamp_ns <= detections[d].stamp_ns);
        if take_joint {
            j += 1
        } else {
            d += 1
        }
        order.push(take_joint);
    }
    order
}

/// Feeds `live` the streams by stamp; returns its outputs.
pub fn run_by_stamp(
    live: &mut Live,
    joints: &[JointState],
    detections: &[StereoDetections],
) -> Vec<Output> {
    let (mut j, mut d, mut out) = (0, 0, Vec::new());
    for take_joint in by_stamp(joints, detections) {
        if take_joint {
            out.extend(live.push_joint_state(joints[j]));
            j += 1;
        } else {
            out.extend(live.push_detections(detections[d]));
            d += 1;
        }
    }
    out
}

/// The detections' noise of the drift tests, px.
pub const PIXEL_SIGMA: f64 = 0.2;

pub fn noise() -> NoiseModel {
    nico_noise_scaled(PIXEL_SIGMA, 0.007)
}

/// Pose ids of the world after the change start here (each pose is
/// sampled once).
pub const AFTER_IDS: u64 = 1000;

/// Simulated samples of `scene`'s placement `mirror` at the drift tests'
/// noise, their pose ids from `first_id`.
pub fn data(scene: &Scene, mirror: usize, counts: Counts, seed: u64, first_id: u64) -> Dataset {
    let mut d = generate(scene, mirror, &noise(), counts, seed).unwrap();
    for s in d.train.iter_mut().chain(&mut d.test).chain(&mut d.direct) {
        s.pose += first_id;
    }
    d
}

/// `a` and `b` taking turns, `per` of `a` to one of `b`.
pub fn interleave<'a>(
    a: impl IntoIterator<Item = (&'a Sample, Role)>,
    b: impl IntoIterator<Item = (&'a Sample, Role)>,
    per: usize,
) -> Vec<(&'a Sample, Role)> {
    let (a, mut b): (Vec<_>, Vec<_>) = (a.into_iter().collect(), b.into_iter().collect());
    b.reverse();
    let mut out = Vec::new();
    for (i, x) in a.into_iter().enumerate() {
        out.push(x);
        if (i + 1) % per == 0
            && let Some(y) = b.pop()
        {
            out.push(y);
        }
    }
    b.reverse();
    out.extend(b);
    out
}

pub fn roled(samples: &[Sample], role: Role) -> impl Iterator<Item = (&Sample, Role)> {
    samples.iter().map(move |s| (s, role))
}

/// What the stage did with a run of `poses`.
pub struct Run {
    /// Its calibrations, in order.
    pub calibrations: Vec<CalibrationMsg>,
    /// The stage at the end.
    pub live: Live,
}

/// Feeds the stage the poses' streams by stamp; what it did.
pub fn run(scene: &Scene, poses: &[(&Sample, Role)]) -> Run {
    let (joints, detections) = streams_of(poses);
    let mut live = Live::new(scene.rig.clone(), LiveConfig::default());
    let out = run_by_stamp(&mut live, &joints, &detections);
    assert!(live.finished());
    let calibrations = out
        .iter()
        .filter_map(|o| match o {
            Output::Calibration(c) => Some(**c),
            _ => None,
        })
        .collect();
    Run { calibrations, live }
}
