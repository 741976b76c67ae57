//! The live stage is deterministic: the same messages in any interleaving
//! of the two input streams give the same outputs.

use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use messages::{CameraMarkers, JointState, Marker, StereoDetections, phase, role};
use mirror_proc::live::{Live, LiveConfig, Output};

/// Joint states at 100 Hz (move 100 ms, dwell 200 ms per pose) and
/// detections at 30 Hz whose marker centres come from the simulator.
fn streams() -> (Vec<JointState>, Vec<StereoDetections>, usize) {
    let data = generate(
        &nico_scene(),
        0,
        &nico_noise(),
        Counts {
            train: 12,
            test: 4,
            direct: 0,
        },
        9,
    )
    .unwrap();
    let poses: Vec<_> = data
        .train
        .iter()
        .map(|s| (s, role::TRAIN))
        .chain(data.test.iter().map(|s| (s, role::TEST)))
        .collect();
    let period = 300_000_000i64;
    let mut joints = Vec::new();
    for t in (0..poses.len() as i64 * period + 50_000_000).step_by(10_000_000) {
        let i = (t / period) as usize;
        let mut js = JointState {
            seq: joints.len() as u64,
            stamp_ns: t,
            dof: 4,
            ..Default::default()
        };
        if let Some((s, r)) = poses.get(i) {
            js.pose = s.pose;
            js.role = *r;
            js.phase = if t - i as i64 * period >= 100_000_000 {
                phase::SETTLED
            } else {
                phase::MOVING
            };
            js.q[..4].copy_from_slice(s.joints.as_ref().unwrap());
            js.model_point = s.model_point.unwrap().into();
        } else {
            js.phase = phase::DONE;
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
        if let Some((s, _)) = poses
            .get(i)
            .filter(|_| t - i as i64 * period >= 100_000_000)
        {
            for k in 0..2 {
                let mut cam = CameraMarkers::default();
                cam.push(Marker {
                    id: 0,
                    mirrored: 1,
                    corners: [0.0; 8],
                    center: s.pixels[k].into(),
                });
                d.cameras[k] = cam;
            }
        }
        detections.push(d);
    }
    (joints, detections, poses.len())
}

fn run(
    order: &[bool],
    joints: &[JointState],
    detections: &[StereoDetections],
) -> (Vec<Output>, Live) {
    let mut live = Live::new(nico_scene().rig, LiveConfig::default());
    let (mut j, mut d, mut out) = (0, 0, Vec::new());
    for &take_joint in order {
        if take_joint {
            out.extend(live.push_joint_state(joints[j]));
            j += 1;
        } else {
            out.extend(live.push_detections(detections[d]));
            d += 1;
        }
    }
    (out, live)
}

#[test]
fn any_interleaving_gives_the_same_outputs() {
    let (joints, detections, poses) = streams();
    // Interleaving A: all joint states first; B: all detections first; C: pseudo-random.
    let a: Vec<bool> = joints
        .iter()
        .map(|_| true)
        .chain(detections.iter().map(|_| false))
        .collect();
    let b: Vec<bool> = detections
        .iter()
        .map(|_| false)
        .chain(joints.iter().map(|_| true))
        .collect();
    let (mut c, mut jl, mut dl, mut x) = (Vec::new(), joints.len(), detections.len(), 12345u64);
    while jl + dl > 0 {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let take_joint = dl == 0 || (jl > 0 && (x >> 33) % 3 != 0);
        if take_joint {
            jl -= 1
        } else {
            dl -= 1
        }
        c.push(take_joint);
    }
    let (out_a, live_a) = run(&a, &joints, &detections);
    let (out_b, _) = run(&b, &joints, &detections);
    let (out_c, _) = run(&c, &joints, &detections);
    assert!(live_a.finished());
    assert_eq!(out_a, out_b);
    assert_eq!(out_a, out_c);
    let samples = out_a
        .iter()
        .filter(|o| matches!(o, Output::Sample(_)))
        .count();
    let calibrations = out_a
        .iter()
        .filter(|o| matches!(o, Output::Calibration(_)))
        .count();
    let predictions = out_a
        .iter()
        .filter(|o| matches!(o, Output::Prediction(_)))
        .count();
    assert_eq!(samples, poses, "every pose paired once");
    assert_eq!(
        calibrations,
        12 - 8 + 1,
        "one calibration per training sample from the 8th on"
    );
    assert_eq!(predictions, 4, "every test pose predicted");
    let report = live_a.report();
    assert_eq!(report.counters.missed, 0);
    // The pixels came from the simulator: the live calibration sits near the truth.
    assert!(report.evaluation.unwrap().mirror_2d_px.unwrap() < 6.0);
}

#[test]
fn malformed_messages_are_dropped_and_counted() {
    let (joints, detections, _) = streams();
    let mut live = Live::new(nico_scene().rig, LiveConfig::default());
    let mut bad = joints[5];
    bad.q[0] = f64::NAN;
    assert!(live.push_joint_state(joints[10]).is_empty());
    live.push_joint_state(bad);
    live.push_joint_state(joints[3]); // stamp going backwards
    let mut nan = detections[2];
    nan.cameras[0].count = 1;
    nan.cameras[0].markers[0].center = [f64::NAN, 1.0];
    live.push_detections(nan);
    let mut overfull = detections[3];
    overfull.cameras[1].count = 99;
    live.push_detections(overfull);
    assert_eq!(live.report().counters.rejected, 4);
}
