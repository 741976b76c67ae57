//! Moves messages between iceoryx2 and the pure [`crate::live::Live`]
//! stage, journaling what it must not lose before publishing it.

use std::collections::VecDeque;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use geometry::Rig;
use messages::now_ns;
use messages::topics::{self, Topic};
use runtime::journal::{Durability, Journal, JournalError, Recovered};
use runtime::stats::StageStats;
use runtime::{BusError, Publisher};

use crate::live::{Latency, Live, LiveConfig, LiveReport, Output};

/// How long after the plan's end the stage waits for a detection to pass
/// it before it takes the detections to have ended (their camera stopped
/// with the plan: the robot's side of a split run).
const DETECTIONS_QUIET: Duration = Duration::from_secs(1);

/// How often the stage looks whether the detections have gone quiet.
const QUIET_CHECK_EVERY: Duration = Duration::from_millis(100);

/// The topics the stage journals: what a restart must not lose.
pub const JOURNALED: [topics::TopicId; 2] = [topics::Samples::ID, topics::Calibration::ID];

/// Why the live stage stopped or could not start ([`run`]).
#[derive(Debug, thiserror::Error)]
pub enum LiveLoopError {
    /// The shared-memory bus failed (opening a port, receiving, publishing).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The journal of an earlier run could not be opened or read.
    #[error("resuming from the journal {}", path.display())]
    Resume {
        /// The journal.
        path: PathBuf,
        /// Why it could not be opened.
        #[source]
        source: JournalError,
    },
    /// A sample or a calibration could not be journaled.
    #[error(transparent)]
    Journal(#[from] JournalError),
}

/// Where the stage's outputs go: the journal first (samples and
/// calibrations), then the bus.
struct Outputs {
    journal: Option<Journal>,
    samples: Publisher<topics::Samples>,
    calibrations: Publisher<topics::Calibration>,
    predictions: Publisher<topics::Predictions>,
    located: Publisher<topics::Located>,
    /// Frame capture (detection stamp) to the moment its sample is published.
    sample_latency_ns: Vec<i64>,
    /// When each recent frame entered the pipeline, by capture stamp: a
    /// sample names its frame by stamp.
    published_by_stamp: VecDeque<(i64, i64)>,
}

impl Outputs {
    fn publish(&mut self, output: Output, stats: &mut StageStats) -> Result<(), LiveLoopError> {
        match output {
            Output::Sample(s) => {
                if let Some(journal) = &mut self.journal {
                    let began = now_ns();
                    journal.append::<topics::Samples>(&s)?;
                    stats.record("journal_append", now_ns() - began);
                }
                self.samples.send(s)?;
                let latency = now_ns() - s.stamp_ns;
                self.sample_latency_ns.push(latency);
                stats.record("capture_to_sample", latency);
                if let Some(&(_, published)) = self
                    .published_by_stamp
                    .iter()
                    .find(|(t, _)| *t == s.stamp_ns)
                {
                    stats.record("frame_to_sample", now_ns() - published);
                }
            }
            Output::Calibration(c) => {
                tracing::info!(
                    revision = c.revision,
                    epoch = c.epoch.epoch,
                    state = ?c.epoch.state(),
                    samples = c.samples,
                    rms_px = c.train_rms_px,
                    plane_sigma_deg = c.uncertainty.plane_angle_deg,
                    plane_sigma_mm = c.uncertainty.plane_distance_mm,
                    "calibration"
                );
                if let Some(journal) = &mut self.journal {
                    journal.append::<topics::Calibration>(&c)?;
                }
                self.calibrations.send(*c)?
            }
            Output::Prediction(p) => self.predictions.send(p)?,
            Output::Located(l) => self.located.send(l)?,
        }
        Ok(())
    }
}

/// Opens `path` and resumes `live` from what it holds; returns the journal
/// and what must be published.
fn resume(live: &mut Live, path: &Path) -> Result<(Journal, Vec<Output>), JournalError> {
    // Synced behind: the append is on the path from frame to sample, and a
    // sync can wait tens of ms while the recorder fills the disk's cache.
    let (journal, recovered) = Journal::open_with(path, &JOURNALED, Durability::SyncedBehind)?;
    if recovered == Recovered::default() {
        // A new journal: nothing to resume.
        return Ok((journal, Vec::new()));
    }
    if let Some(why) = &recovered.dropped {
        tracing::warn!(
            "{}: dropped an incomplete record at its end ({why}); everything before it is kept",
            path.display()
        );
    }
    let samples: Vec<_> = recovered.messages::<topics::Samples>().collect();
    let calibrations: Vec<_> = recovered.messages::<topics::Calibration>().collect();
    let outputs = live.resume(&samples, &calibrations, recovered.dropped.clone());
    let reproduced = live
        .report()
        .recovered
        .and_then(|r| r.calibration_reproduced);
    tracing::info!(
        samples = samples.len(),
        train = live.train_samples(),
        revision = live.revision(),
        ?reproduced,
        "resumed from the journal {}",
        path.display()
    );
    Ok((journal, outputs))
}

/// Runs the live stage on pipeline `prefix` until the pose plan ends (or a
/// signal stops it); returns the final report. With `journal`, every
/// sample and calibration is journaled there before it is published, and a
/// journal left by an earlier run of the stage is resumed; one that cannot
/// be opened is a [`LiveLoopError::Resume`].
pub fn run(
    prefix: &str,
    rig: Rig,
    config: LiveConfig,
    journal: Option<&Path>,
) -> Result<LiveReport, LiveLoopError> {
    let began = now_ns();
    let mut live = Live::new(rig, config);
    let (journal, pending) = match journal {
        Some(path) => {
            let (journal, pending) =
                resume(&mut live, path).map_err(|source| LiveLoopError::Resume {
                    path: path.to_path_buf(),
                    source,
                })?;
            (Some(journal), pending)
        }
        None => (None, Vec::new()),
    };
    live.publish_samples_first();
    let bus = stages::bus_of::<stages::mirror::Mirror>(prefix)?;
    let joints = bus.subscriber::<topics::JointState>()?;
    let detections = bus.subscriber::<topics::Detections>()?;
    let mut outputs = Outputs {
        journal,
        samples: bus.publisher::<topics::Samples>()?,
        calibrations: bus.publisher::<topics::Calibration>()?,
        predictions: bus.publisher::<topics::Predictions>()?,
        located: bus.publisher::<topics::Located>()?,
        sample_latency_ns: Vec::new(),
        published_by_stamp: VecDeque::new(),
    };
    let mut stats = StageStats::new("mirror_proc");
    if let Some(r) = live.report().recovered {
        // From the start of this process to its state recovered and its
        // ports open: when a restarted stage can pair again.
        stats.record("start_to_resumed", now_ns() - began);
        // Written at once, so the launcher's report shows this restart's
        // recovery even if this process is killed in turn.
        stats.count("recovered_samples", r.samples as u64);
        stats.count("recovered_revision", r.revision);
        stats.count("recovered_dropped_records", u64::from(r.dropped.is_some()));
        stats.finish();
    }
    for o in pending {
        outputs.publish(o, &mut stats)?;
    }
    tracing::info!(prefix, "mirror stage running");
    let mut last_detection = Instant::now();
    bus.wake()?.run(
        &[joints.listener(), detections.listener()],
        Some(QUIET_CHECK_EVERY),
        || -> Result<_, LiveLoopError> {
            let cpu = runtime::stats::StepStart::now();
            let mut ready = Vec::new();
            let mut received_ns = Vec::new();
            let mut frames_published_ns = Vec::new();
            let mut took = false;
            while let Some(js) = joints.receive()? {
                took = true;
                ready.extend(live.push_joint_state(js));
            }
            while let Some(d) = detections.receive()? {
                received_ns.push(now_ns());
                if d.frame_published_ns > 0 {
                    frames_published_ns.push(d.frame_published_ns);
                    let recent = &mut outputs.published_by_stamp;
                    if recent.len() == 256 {
                        recent.pop_front();
                    }
                    recent.push_back((d.stamp_ns, d.frame_published_ns));
                }
                let _span = tracing::trace_span!("mirror_step", seq = d.seq).entered();
                ready.extend(live.push_detections(d));
                last_detection = Instant::now();
            }
            if live.plan_ended() && !live.finished() && last_detection.elapsed() > DETECTIONS_QUIET
            {
                tracing::info!(
                    "no detection for {:.1} s after the plan's end: finishing",
                    DETECTIONS_QUIET.as_secs_f64()
                );
                ready.extend(live.end_of_detections());
            }
            for o in ready {
                outputs.publish(o, &mut stats)?;
            }
            // A sample goes out before the calibration it sets going.
            while live.holds_sample() {
                for o in live.after_sample() {
                    outputs.publish(o, &mut stats)?;
                }
            }
            // Each detection from its arrival to the end of this wake's
            // publishing (the wait in the merge for the joint states to
            // pass it shows in capture_to_sample).
            let now = now_ns();
            took |= !received_ns.is_empty();
            for r in received_ns {
                stats.record("receive_to_publish", now - r);
            }
            // End to end through the pipeline: from the frame's
            // publication by the camera to the end of this wake.
            for p in frames_published_ns {
                stats.record("frame_to_processed", now - p);
            }
            // A step: one wake that had messages to take.
            if took {
                stats.cpu_step(cpu);
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
    report.latency_ms = Latency::of(&outputs.sample_latency_ns);
    tracing::info!(
        train = report.train_samples,
        test = report.test_samples,
        "pose plan done"
    );
    Ok(report)
}
