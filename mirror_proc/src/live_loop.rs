//! Moves messages between iceoryx2 and the pure [`crate::live::Live`] stage.

use std::ops::ControlFlow;

use anyhow::Result;
use geometry::Rig;
use messages::{Bus, topics};

use crate::live::{Latency, Live, LiveConfig, LiveReport, Output};
use messages::now_ns;

/// Runs the live stage on pipeline `prefix` until the pose plan ends (or a
/// signal stops it); returns the final report.
pub fn run(prefix: &str, rig: Rig, config: LiveConfig) -> Result<LiveReport> {
    let bus = Bus::new(prefix, "mirror_proc")?;
    let joints = bus.subscriber::<topics::JointState>()?;
    let detections = bus.subscriber::<topics::Detections>()?;
    let samples = bus.publisher::<topics::Samples>()?;
    let calibrations = bus.publisher::<topics::Calibration>()?;
    let predictions = bus.publisher::<topics::Predictions>()?;
    let located = bus.publisher::<topics::Located>()?;
    let mut live = Live::new(rig, config);
    // Frame capture (detection stamp) to the moment its sample is published.
    let mut sample_latency_ns = Vec::new();
    let mut stats = messages::stats::StageStats::new("mirror_proc");
    // When each recent frame entered the pipeline, by capture stamp: a
    // sample names its frame by stamp.
    let mut published_by_stamp = std::collections::VecDeque::<(i64, i64)>::new();
    tracing::info!(prefix, "mirror stage running");
    bus.wake()?.run(
        &[joints.listener(), detections.listener()],
        None,
        || -> Result<_> {
            let mut outputs = Vec::new();
            let mut received_ns = Vec::new();
            let mut frames_published_ns = Vec::new();
            while let Some(js) = joints.receive()? {
                outputs.extend(live.push_joint_state(js));
            }
            while let Some(d) = detections.receive()? {
                received_ns.push(now_ns());
                if d.frame_published_ns > 0 {
                    frames_published_ns.push(d.frame_published_ns);
                    if published_by_stamp.len() == 256 {
                        published_by_stamp.pop_front();
                    }
                    published_by_stamp.push_back((d.stamp_ns, d.frame_published_ns));
                }
                let _span = tracing::trace_span!("mirror_step", seq = d.seq).entered();
                outputs.extend(live.push_detections(d));
            }
            for o in outputs {
                match o {
                    Output::Sample(s) => {
                        samples.send(s)?;
                        let latency = now_ns() - s.stamp_ns;
                        sample_latency_ns.push(latency);
                        stats.record("capture_to_sample", latency);
                        if let Some(&(_, published)) =
                            published_by_stamp.iter().find(|(t, _)| *t == s.stamp_ns)
                        {
                            stats.record("frame_to_sample", now_ns() - published);
                        }
                    }
                    Output::Calibration(c) => {
                        tracing::info!(
                            revision = c.revision,
                            samples = c.samples,
                            rms_px = c.train_rms_px,
                            "calibration"
                        );
                        calibrations.send(c)?
                    }
                    Output::Prediction(p) => predictions.send(p)?,
                    Output::Located(l) => located.send(l)?,
                }
            }
            // Each detection from its arrival to the end of this wake's
            // publishing (the wait in the merge for the joint states to
            // pass it shows in capture_to_sample).
            let now = now_ns();
            for r in received_ns {
                stats.record("receive_to_publish", now - r);
            }
            // End to end through the pipeline: from the frame's
            // publication by the camera to the end of this wake.
            for p in frames_published_ns {
                stats.record("frame_to_processed", now - p);
            }
            Ok(if live.finished() {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        },
    )?;
    let mut report = live.report();
    stats.count("detections_rejected", report.counters.rejected);
    stats.count("poses_missed", report.counters.missed);
    stats.count("joint_states_missed", report.counters.joint_states_missed);
    stats.count("detections_missed", report.counters.detections_missed);
    stats.count("source_restarts", report.counters.source_restarts);
    stats.count("poses_repeated", report.counters.poses_repeated);
    stats.finish();
    report.latency_ms = Latency::of(&sample_latency_ns);
    tracing::info!(
        train = report.train_samples,
        test = report.test_samples,
        "pose plan done"
    );
    Ok(report)
}
