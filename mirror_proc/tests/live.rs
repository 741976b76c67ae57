//! The live stage is deterministic: the same messages in any interleaving
//! of the two input streams give the same outputs.

mod common;

use common::by_stamp;
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use messages::{JointState, Phase, Role, StereoDetections};
use mirror_proc::live::{Live, LiveConfig, Output};

/// Joint states at 100 Hz (move 100 ms, dwell 200 ms per pose) and
/// detections at 30 Hz whose marker centres come from the simulator.
fn streams() -> (Vec<JointState>, Vec<StereoDetections>, usize) {
    streams_with(None)
}

/// The streams, with training pose `wrong.0` read as pose `wrong.1` was
/// (a wrong pairing, which the calibration sets aside).
fn streams_with(wrong: Option<(usize, usize)>) -> (Vec<JointState>, Vec<StereoDetections>, usize) {
    let mut data = generate(
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
    if let Some((victim, donor)) = wrong {
        data.train[victim].joints = data.train[donor].joints.clone();
        data.train[victim].model_point = data.train[donor].model_point;
    }
    let poses: Vec<_> = data
        .train
        .iter()
        .map(|s| (s, Role::Train))
        .chain(data.test.iter().map(|s| (s, Role::Test)))
        .collect();
    let (joints, detections) = common::streams_of(&poses);
    (joints, detections, poses.len())
}

fn run(
    order: &[bool],
    joints: &[JointState],
    detections: &[StereoDetections],
) -> (Vec<Output>, Live) {
    run_with(LiveConfig::default(), order, joints, detections)
}

fn run_with(
    config: LiveConfig,
    order: &[bool],
    joints: &[JointState],
    detections: &[StereoDetections],
) -> (Vec<Output>, Live) {
    let mut live = Live::new(nico_scene().rig, config);
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

fn samples_and_calibrations(out: &[Output]) -> (usize, usize) {
    let samples = out
        .iter()
        .filter(|o| matches!(o, Output::Sample(_)))
        .count();
    let calibrations = out
        .iter()
        .filter(|o| matches!(o, Output::Calibration(_)))
        .count();
    (samples, calibrations)
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
    let (samples, calibrations) = samples_and_calibrations(&out_a);
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

/// With samples handed out first (as the live stage publishes them), each
/// sample comes out alone, before the calibration it sets going, and the
/// outputs, in order, are those of a stage that gives everything at once.
#[test]
fn samples_handed_out_first_come_alone_and_change_nothing_else() {
    let (joints, detections, poses) = streams();
    let order = by_stamp(&joints, &detections);
    let (all_at_once, _) = run(&order, &joints, &detections);
    let mut live = Live::new(nico_scene().rig, LiveConfig::default());
    live.publish_samples_first();
    let (mut j, mut d, mut out, mut alone) = (0, 0, Vec::new(), 0);
    for take_joint in order {
        let batch = if take_joint {
            j += 1;
            live.push_joint_state(joints[j - 1])
        } else {
            d += 1;
            live.push_detections(detections[d - 1])
        };
        if live.holds_sample() {
            // The batch ends with the sample; its calibration is not in it.
            assert!(matches!(batch.last(), Some(Output::Sample(_))), "{batch:?}");
            alone += 1;
        }
        out.extend(batch);
        while live.holds_sample() {
            out.extend(live.after_sample());
        }
    }
    assert!(live.finished());
    assert_eq!(
        alone, poses,
        "every sample handed out before what follows it"
    );
    assert_eq!(out, all_at_once);
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

/// A rogue publisher's messages amid the real ones: each is dropped and
/// counted, and the outputs are exactly those of the clean run (nothing
/// poisoned: not the merge, not the pairing, not the calibration).
#[test]
fn rogue_messages_are_dropped_without_poisoning_the_stage() {
    let (joints, detections, _) = streams();
    let (clean, _) = run(&by_stamp(&joints, &detections), &joints, &detections);
    let mut live = Live::new(nico_scene().rig, LiveConfig::default());
    let mut out = Vec::new();
    let mut rogue = 0;
    let (mut j, mut d) = (0, 0);
    for take_joint in by_stamp(&joints, &detections) {
        if take_joint {
            let real = joints[j];
            j += 1;
            if j % 7 == 3 {
                let bad = [
                    JointState {
                        q: [f64::INFINITY; 8],
                        ..real
                    },
                    JointState { dof: 9, ..real },
                    JointState { dof: 3, ..real },
                    JointState { phase: 7, ..real },
                    JointState { role: 5, ..real },
                    JointState {
                        stamp_ns: real.stamp_ns - 1_000_000_000,
                        ..real
                    },
                    JointState {
                        stamp_ns: i64::MAX,
                        phase: Phase::Done as u32,
                        ..real
                    },
                ];
                for b in bad {
                    out.extend(live.push_joint_state(b));
                    rogue += 1;
                }
            }
            out.extend(live.push_joint_state(real));
            // The same message again: a repeated stamp.
            out.extend(live.push_joint_state(real));
            rogue += 1;
        } else {
            let real = detections[d];
            d += 1;
            let mut nan = real;
            nan.cameras[0].count = 1;
            nan.cameras[0].markers[0].center = [f64::NAN, 1.0];
            let mut overfull = real;
            overfull.cameras[1].count = 99;
            let mut bad_id = real;
            bad_id.cameras[0].count = 1;
            bad_id.cameras[0].markers[0].id = 5000;
            let mut bad_flag = real;
            bad_flag.cameras[1].count = 1;
            bad_flag.cameras[1].markers[0].mirrored = 2;
            let future = StereoDetections {
                stamp_ns: real.stamp_ns + 3_600_000_000_000,
                ..real
            };
            let backwards = StereoDetections {
                stamp_ns: real.stamp_ns - 500_000_000,
                ..real
            };
            // Backwards needs something to go back from.
            let n = if d > 1 { 6 } else { 5 };
            for b in [nan, overfull, bad_id, bad_flag, future, backwards]
                .into_iter()
                .take(n)
            {
                out.extend(live.push_detections(b));
                rogue += 1;
            }
            out.extend(live.push_detections(real));
        }
    }
    assert_eq!(out, clean);
    let counters = live.report().counters;
    assert_eq!(counters.rejected, rogue);
    assert_eq!(counters.source_restarts, 0);
}

/// A restarted pose plan (kinematics restarted): the poses already sampled
/// are skipped and counted, the others are paired when they come round again.
#[test]
fn a_restarted_pose_plan_gives_one_sample_per_pose() {
    let (joints, detections, poses) = streams();
    // The first run of the plan stops a third of the way in (no DONE);
    // the second starts again from pose 0, later on the clock.
    let cut = joints.len() / 3;
    let shift = joints[cut].stamp_ns + 1_000_000;
    let mut all_joints: Vec<JointState> = joints[..cut].to_vec();
    all_joints.extend(joints.iter().map(|js| JointState {
        stamp_ns: js.stamp_ns + shift,
        ..*js
    }));
    let first_cut = detections.partition_point(|d| d.stamp_ns < joints[cut].stamp_ns);
    let mut all_detections: Vec<StereoDetections> = detections[..first_cut].to_vec();
    all_detections.extend(detections.iter().map(|d| StereoDetections {
        stamp_ns: d.stamp_ns + shift,
        seq: d.seq + first_cut as u64,
        ..*d
    }));
    let (out, live) = run(
        &by_stamp(&all_joints, &all_detections),
        &all_joints,
        &all_detections,
    );
    let samples: Vec<u64> = out
        .iter()
        .filter_map(|o| match o {
            Output::Sample(s) => Some(s.pose),
            _ => None,
        })
        .collect();
    let mut unique = samples.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(
        unique.len(),
        samples.len(),
        "a pose sampled twice: {samples:?}"
    );
    assert_eq!(samples.len(), poses, "every pose paired once");
    let c = live.report().counters;
    assert!(c.poses_repeated >= 3, "{c:?}");
    assert_eq!(c.source_restarts, 1, "{c:?}");
    assert!(live.finished());
}

/// A stage started late counts what it never saw.
#[test]
fn a_late_start_counts_the_messages_it_missed() {
    let (joints, detections, _) = streams();
    let (j0, d0) = (40, 12);
    let (_, live) = run(
        &by_stamp(&joints[j0..], &detections[d0..]),
        &joints[j0..],
        &detections[d0..],
    );
    let c = live.report().counters;
    assert_eq!(c.joint_states_missed, j0 as u64);
    assert_eq!(c.detections_missed, d0 as u64);
    assert!(live.finished());
}

/// Bad geometry: the stage says why it cannot calibrate, publishes no
/// calibration, and keeps pairing samples.
#[test]
fn bad_geometry_is_reported_and_nothing_is_published() {
    let (joints, detections, poses) = streams();
    let order = by_stamp(&joints, &detections);

    // Too few samples: 12 calibration poses, 20 needed.
    let config = LiveConfig {
        min_train: 20,
        ..LiveConfig::default()
    };
    let (out, live) = run_with(config, &order, &joints, &detections);
    assert_eq!(samples_and_calibrations(&out), (poses, 0));
    let why = live.report().last_error.unwrap();
    assert!(why.contains("12 of the 20"), "{why}");

    // Poses all alike: every pose is the first one.
    let first = joints
        .iter()
        .find(|js| js.phase == Phase::Settled as u32)
        .unwrap();
    let alike: Vec<JointState> = joints
        .iter()
        .map(|js| JointState {
            q: first.q,
            model_point: first.model_point,
            ..*js
        })
        .collect();
    let pixels = detections
        .iter()
        .find(|d| d.cameras[0].count > 0)
        .unwrap()
        .cameras;
    let alike_detections: Vec<StereoDetections> = detections
        .iter()
        .map(|d| StereoDetections {
            cameras: if d.cameras[0].count > 0 {
                pixels
            } else {
                d.cameras
            },
            ..*d
        })
        .collect();
    let (out, live) = run(&order, &alike, &alike_detections);
    assert_eq!(
        samples_and_calibrations(&out),
        (poses, 0),
        "samples kept, no calibration"
    );
    let report = live.report();
    assert!(report.counters.calibration_failures > 0);
    let why = report.last_error.unwrap();
    assert!(why.contains("nearly all the same"), "{why}");

    // The arm's marker never seen (another marker is).
    let unseen: Vec<StereoDetections> = detections
        .iter()
        .map(|d| {
            let mut d = *d;
            for c in &mut d.cameras {
                for m in c.markers.iter_mut() {
                    m.id = 3;
                }
            }
            d
        })
        .collect();
    let (out, live) = run(&order, &joints, &unseen);
    assert_eq!(samples_and_calibrations(&out), (0, 0));
    let report = live.report();
    assert_eq!(report.counters.missed, poses as u64);
    let why = report.last_error.unwrap();
    assert!(
        why.contains("0 of the 8")
            && why.contains(&format!("{poses} poses without the arm's marker")),
        "{why}"
    );
}

/// A stage killed at some point and resumed from what it had journaled
/// (its samples and calibrations up to then) goes on as if nothing had
/// happened: the calibration it recomputes is the journaled one, bit for
/// bit, and its final calibration is the uninterrupted run's. One training
/// sample is a wrong pairing, so the calibrations set one aside.
#[test]
fn a_stage_resumed_from_its_journal_ends_with_the_uninterrupted_calibration() {
    let (joints, detections, _) = streams_with(Some((1, 6)));
    let order = by_stamp(&joints, &detections);
    let (whole, live) = run(&order, &joints, &detections);
    let last = |out: &[Output]| {
        out.iter()
            .rev()
            .find_map(|o| match o {
                Output::Calibration(c) => Some(**c),
                _ => None,
            })
            .expect("a calibration")
    };
    let final_calibration = last(&whole);
    assert_eq!(final_calibration.uncertainty.rejected_samples, 1);
    let final_file = live.report().calibration;
    assert_eq!(final_file.as_ref().unwrap().rejected_samples[0].pose, 1);
    let calibrations = |out: &[Output]| {
        out.iter()
            .filter(|o| matches!(o, Output::Calibration(_)))
            .count()
    };
    // Crash points: after the third calibration, after the last training
    // sample, and between a training sample and the calibration it caused
    // (journaled the sample, not the calibration).
    let third = (1..=order.len())
        .find(|&m| calibrations(&run(&order[..m], &joints, &detections).0) == 3)
        .unwrap();
    let train_samples = |out: &[Output]| {
        out.iter()
            .filter(|o| matches!(o, Output::Sample(s) if s.role == Role::Train as u32))
            .count()
    };
    let train = train_samples(&whole);
    let last_train = (1..=order.len())
        .find(|&m| train_samples(&run(&order[..m], &joints, &detections).0) == train)
        .unwrap();
    for (crash_after, drop_last_calibration) in [(third, false), (last_train, false), (third, true)]
    {
        let (before, _) = run(&order[..crash_after], &joints, &detections);
        let mut journaled: Vec<Output> = before
            .iter()
            .filter(|o| matches!(o, Output::Sample(_) | Output::Calibration(_)))
            .cloned()
            .collect();
        if drop_last_calibration {
            assert!(matches!(journaled.pop(), Some(Output::Calibration(_))));
        }
        let samples: Vec<_> = journaled
            .iter()
            .filter_map(|o| match o {
                Output::Sample(s) => Some(*s),
                _ => None,
            })
            .collect();
        let calibrations: Vec<_> = journaled
            .iter()
            .filter_map(|o| match o {
                Output::Calibration(c) => Some(**c),
                _ => None,
            })
            .collect();
        let mut resumed = Live::new(nico_scene().rig, LiveConfig::default());
        let pending = resumed.resume(&samples, &calibrations, None);
        let recovery = resumed.report().recovered.unwrap();
        assert_eq!(recovery.samples, samples.len());
        assert_eq!(recovery.calibration_reproduced, Some(true));
        if drop_last_calibration {
            // The calibration the crash prevented is made and published again.
            assert_eq!(pending, vec![Output::Calibration(Box::new(last(&before)))]);
        } else {
            assert!(pending.is_empty());
        }
        let mut after = pending;
        let (mut j, mut d) = (
            order[..crash_after].iter().filter(|t| **t).count(),
            order[..crash_after].iter().filter(|t| !**t).count(),
        );
        for &take_joint in &order[crash_after..] {
            if take_joint {
                after.extend(resumed.push_joint_state(joints[j]));
                j += 1;
            } else {
                after.extend(resumed.push_detections(detections[d]));
                d += 1;
            }
        }
        let end = if after.iter().any(|o| matches!(o, Output::Calibration(_))) {
            last(&after)
        } else {
            *calibrations.last().unwrap()
        };
        assert_eq!(end, final_calibration, "crash after {crash_after}");
        assert_eq!(resumed.report().calibration, final_file);
        assert_eq!(resumed.report().train_samples, train);
        // The dwell in progress at the crash is not a repeated pose.
        assert_eq!(resumed.report().counters.poses_repeated, 0);
    }
}

/// Detections that stop with the plan (the camera stopped when the pose
/// plan ended, as on the robot's side of a split run) leave the plan's
/// end unprocessed; once they are declared ended, it is, and the outputs
/// are those of the full streams.
#[test]
fn detections_that_stop_with_the_plan_end_it_once_declared_ended() {
    let (joints, detections, _) = streams();
    let done = joints
        .iter()
        .find(|j| j.phase == Phase::Done as u32)
        .unwrap()
        .stamp_ns;
    let before: Vec<_> = detections
        .iter()
        .copied()
        .filter(|d| d.stamp_ns < done)
        .collect();
    let (full, full_live) = run(&by_stamp(&joints, &detections), &joints, &detections);
    assert!(full_live.finished());
    let (mut cut, mut live) = run(&by_stamp(&joints, &before), &joints, &before);
    assert!(live.plan_ended() && !live.finished());
    cut.extend(live.end_of_detections());
    assert!(live.finished());
    assert_eq!(
        samples_and_calibrations(&cut),
        samples_and_calibrations(&full)
    );
    assert_eq!(live.report().calibration, full_live.report().calibration);
}
