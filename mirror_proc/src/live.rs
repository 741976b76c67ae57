//! The live mirror stage as a pure state machine: messages in, messages out.
//!
//! Joint states and detections arrive on two topics in any interleaving;
//! [`Live`] merges them strictly by stamp (an event is processed only once
//! the other stream has moved past it, or has ended), so the same input
//! messages always give the same outputs, whatever the timing.
//!
//! Pairing: a pose's window opens at the first `SETTLED` joint state of the
//! pose plus a settle margin and closes at the next state of another pose or
//! phase. The first stereo detection inside the window in which the arm's
//! marker is found in both cameras (mirror-reversed for mirror poses, as
//! printed for direct ones) makes the pose's sample. Each new training sample
//! triggers a calibration once enough exist; test samples get predictions
//! through the newest calibration; other markers seen mirror-reversed in
//! both cameras are located through the mirror cameras.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use formats::evaluation::Evaluation;
use geometry::triangulate::triangulate;
use geometry::{Rig, Sample};
use messages::{
    CalibrationEpoch, CalibrationMsg, CalibrationUncertainty, CameraPose, EpochState, JointState,
    LocatedObject, MAX_JOINTS, MirrorSample, Phase, Prediction, Role, StereoDetections,
    UNDETERMINED,
};
use nalgebra::{Matrix3, Vector2};
use runtime::Rejections;
use serde::{Deserialize, Serialize};

use crate::calibrate::{CalibrateOptions, Calibration, Fit, Method, calibrate_with};
use crate::drift::{Drift, DriftMonitor, Moved};
use crate::epochs::{self, CAMERA_VIEWS, EpochReport};
use crate::evaluate::evaluate;

/// Settings of the live stage.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveConfig {
    /// Calibration method.
    pub method: Method,
    /// ArUco id of the arm's marker.
    pub arm_marker: u32,
    /// Training samples needed before the first calibration.
    pub min_train: usize,
    /// Time after a pose settles before a frame may be paired with it, ns.
    pub settle_margin_ns: i64,
    /// Watch every new sample for a changed world (a moved mirror, a
    /// knocked camera), and calibrate again when one is found.
    pub watch_drift: bool,
}

impl Default for LiveConfig {
    fn default() -> Self {
        Self {
            method: Method::JointKinematics,
            arm_marker: 0,
            min_train: 8,
            settle_margin_ns: 30_000_000,
            watch_drift: true,
        }
    }
}

/// What the stage publishes.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// A new paired sample.
    Sample(MirrorSample),
    /// A new calibration.
    Calibration(Box<CalibrationMsg>),
    /// A test sample's prediction.
    Prediction(Prediction),
    /// A marker located through the mirror.
    Located(LocatedObject),
}

/// Counters for the report.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Counters {
    /// Joint states processed.
    pub joint_states: u64,
    /// Detections processed.
    pub detections: u64,
    /// Poses that got a sample.
    pub paired: u64,
    /// Poses whose window closed without a usable detection.
    pub missed: u64,
    /// Messages dropped as malformed (non-finite values, counts, ids or
    /// codes out of range, stamps repeated, going backwards or far ahead of
    /// the other stream); the reasons are logged as warnings.
    pub rejected: u64,
    /// Joint states that never arrived: gaps in their sequence numbers, and
    /// those published before this stage started.
    #[serde(default)]
    pub joint_states_missed: u64,
    /// Detections that never arrived, counted the same way.
    #[serde(default)]
    pub detections_missed: u64,
    /// Times the joint-state or detection sequence started again (a restarted
    /// kinematics stage or tracker).
    #[serde(default)]
    pub source_restarts: u64,
    /// Settled poses that already had their sample (a restarted pose plan):
    /// ignored, one sample per pose.
    #[serde(default)]
    pub poses_repeated: u64,
    /// Calibrations that failed (too few or degenerate samples so far).
    pub calibration_failures: u64,
}

/// The final account of a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LiveReport {
    /// Method used.
    pub method: String,
    /// Training samples.
    pub train_samples: usize,
    /// Test samples (mirror and direct).
    pub test_samples: usize,
    /// The paper's metrics of the final calibration on the test samples.
    pub evaluation: Option<Evaluation>,
    /// The final calibration (file form).
    pub calibration: Option<formats::calibration::CalibrationFile>,
    /// Last position of each located object: id -> [x, y, z] mm.
    pub located: BTreeMap<u32, [f64; 3]>,
    /// The predicted 1-sigma error of each of those positions, mm (RMS
    /// distance to the true point; see `docs/methods.md`).
    #[serde(default)]
    pub located_sigma_mm: BTreeMap<u32, f64>,
    /// Why the last calibration attempt failed, if it did, or why there is
    /// no calibration at all.
    pub last_error: Option<String>,
    /// Counters.
    pub counters: Counters,
    /// Frame capture to publication of its result in this stage, ms (filled by the I/O loop).
    #[serde(default)]
    pub latency_ms: Option<Latency>,
    /// What this run of the stage took back from its journal, if it
    /// resumed one.
    #[serde(default)]
    pub recovered: Option<Recovery>,
    /// The epochs of the run, first to last: each change of the world
    /// found ends one (one epoch when nothing changed). The evaluation
    /// and the calibration above are the last one's.
    #[serde(default)]
    pub epochs: Vec<EpochReport>,
}

/// What a restarted stage took back from its journal.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Recovery {
    /// Samples taken back (training and test).
    pub samples: usize,
    /// Of which training samples.
    pub train_samples: usize,
    /// The calibration revision it resumed at (0: none yet).
    pub revision: u64,
    /// Whether the calibration computed again from the journaled samples
    /// equals the journaled one, bit for bit.
    pub calibration_reproduced: Option<bool>,
    /// What was dropped from the end of the journal (a record torn by the
    /// crash), if anything.
    pub dropped: Option<String>,
}

/// Latency percentiles, ms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    /// Frames measured.
    pub count: usize,
    /// Median.
    pub median: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
}

impl Latency {
    /// Percentiles of `values_ns` (nearest rank), or none if empty.
    pub fn of(values_ns: &[i64]) -> Option<Self> {
        let mut v = values_ns.to_vec();
        v.sort_unstable();
        let rank =
            |q: f64| v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1] as f64 * 1e-6;
        (!v.is_empty()).then(|| Self {
            count: v.len(),
            median: rank(0.5),
            p99: rank(0.99),
            max: rank(1.0),
        })
    }
}

/// The epoch under way: since the last change of the world found.
#[derive(Debug, Clone, Default)]
struct Epoch {
    /// From 1.
    number: u32,
    /// The pose at which it began (0 for the first).
    began_at_pose: u64,
    /// The change that began it (none for the first).
    after: Option<Drift>,
    /// Its first training sample, in `Live::train`.
    train_from: usize,
    /// Its first test sample, in `Live::tests`.
    tests_from: usize,
    /// The plane of the epoch before, where its calibration starts.
    start_plane: Option<geometry::Plane>,
    /// Samples of the calibration it kept from the epoch before (a camera
    /// moved, the mirror did not): it is calibrated from its own samples
    /// once it has as many.
    kept_samples: usize,
    /// The head cameras found again before it began, in force in it.
    head_cameras: Vec<formats::calibration::HeadCameraEntry>,
}

/// A change found and not yet calibrated again.
#[derive(Debug, Clone)]
struct Drifted {
    drift: Drift,
    /// The first training and test samples after the change began.
    train_from: usize,
    tests_from: usize,
    /// The moved cameras have been found again.
    cameras_found: bool,
}

#[derive(Debug, Clone)]
struct Window {
    state: JointState,
    opens_ns: i64,
    done: bool,
}

/// The live stage's state.
pub struct Live {
    rig: Rig,
    config: LiveConfig,
    joints: VecDeque<JointState>,
    detections: VecDeque<StereoDetections>,
    joints_ended: bool,
    /// No detection will come any more (see [`Live::end_of_detections`]).
    detections_ended: bool,
    last_joint_stamp: i64,
    last_detection_stamp: i64,
    window: Option<Window>,
    /// Hand a new sample out before what it sets going (see
    /// [`Live::publish_samples_first`]).
    samples_first: bool,
    /// A sample handed out, with the detections it came from, whose
    /// scoring, calibration and located objects are still to come.
    held: Option<Box<(MirrorSample, StereoDetections)>>,
    train: Vec<MirrorSample>,
    tests: Vec<MirrorSample>,
    calibration: Option<Calibration>,
    revision: u64,
    located: BTreeMap<u32, [f64; 3]>,
    located_sigma_mm: BTreeMap<u32, f64>,
    /// Poses whose rejection by the outlier test has been logged.
    rejections_logged: BTreeSet<u64>,
    /// Whether the current run of poor fits has been logged (once, not per
    /// revision).
    poor_fit_logged: bool,
    last_error: Option<String>,
    counters: Counters,
    finished: bool,
    poses_sampled: BTreeSet<u64>,
    repeated_pose: Option<u64>,
    last_joint_seq: Option<u64>,
    last_detection_seq: Option<u64>,
    rejections: Rejections,
    recovered: Option<Recovery>,
    /// Scores new samples against the calibration (`watch_drift`).
    monitor: Option<DriftMonitor>,
    epoch: Epoch,
    /// Epochs ended by a change.
    past_epochs: Vec<EpochReport>,
    drifted: Option<Drifted>,
    /// Head cameras found again after they moved.
    head_cameras: Vec<formats::calibration::HeadCameraEntry>,
    /// The covariance of each head camera's turn as last found (rad^2),
    /// added to every later calibration's uncertainty.
    turn_covariances: [Option<Matrix3<f64>>; 2],
    /// Where each camera has seen the markers that hold still lately.
    still: crate::still::StillMarkers,
    /// Why calibrating stopped after a change, if it did.
    stopped: Option<String>,
}

/// Fewest training samples in a calibration before new samples are
/// scored against it: fewer leave it too loose to tell a change.
pub const WATCH_FROM_SAMPLES: usize = 15;

/// How far one input stream's stamps may run ahead of the other's before a
/// message is taken to be stamped wrongly: such a message would otherwise
/// hold back the merge, or make every later message look late.
pub const MAX_STREAM_SKEW_NS: i64 = 30_000_000_000;

impl Live {
    /// A stage for `rig`.
    pub fn new(rig: Rig, config: LiveConfig) -> Self {
        Self {
            rig,
            config,
            joints: VecDeque::new(),
            detections: VecDeque::new(),
            joints_ended: false,
            detections_ended: false,
            last_joint_stamp: i64::MIN,
            last_detection_stamp: i64::MIN,
            window: None,
            samples_first: false,
            held: None,
            train: Vec::new(),
            tests: Vec::new(),
            calibration: None,
            revision: 0,
            located: BTreeMap::new(),
            located_sigma_mm: BTreeMap::new(),
            rejections_logged: BTreeSet::new(),
            poor_fit_logged: false,
            last_error: None,
            counters: Counters::default(),
            finished: false,
            poses_sampled: BTreeSet::new(),
            repeated_pose: None,
            last_joint_seq: None,
            last_detection_seq: None,
            rejections: Rejections::default(),
            recovered: None,
            monitor: None,
            epoch: Epoch {
                number: 1,
                ..Epoch::default()
            },
            past_epochs: Vec::new(),
            drifted: None,
            head_cameras: Vec::new(),
            turn_covariances: [None; 2],
            still: crate::still::StillMarkers::new(),
            stopped: None,
        }
    }

    /// Resumes from what an earlier run of this stage journaled: its samples
    /// in the order they were paired, and its calibrations. Poses already
    /// sampled are not paired again. The samples are taken again in their
    /// order, as they were when paired (the solvers are deterministic, so
    /// every calibration and every change of the world found comes out the
    /// same, bit for bit; the last journaled calibration is checked).
    /// Returns what must be published: calibrations the crash prevented.
    pub fn resume(
        &mut self,
        samples: &[MirrorSample],
        calibrations: &[CalibrationMsg],
        dropped: Option<String>,
    ) -> Vec<Output> {
        let journaled = calibrations.last();
        let mut again = Vec::new();
        for s in samples {
            self.poses_sampled.insert(s.pose);
            self.counters.paired += 1;
            self.take_sample(*s, &mut again);
        }
        // The arm may still hold the last pose sampled before the crash: the
        // rest of its dwell is not a repeated pose.
        self.repeated_pose = samples.last().map(|s| s.pose);
        let published = journaled.map_or(0, |c| c.revision);
        let mut reproduced = None;
        let mut out = Vec::new();
        for o in again {
            if let Output::Calibration(c) = o {
                if c.revision == published {
                    reproduced = journaled.map(|j| *j == *c);
                } else if c.revision > published {
                    out.push(Output::Calibration(c));
                }
            }
        }
        // Revisions published before the crash are never reused, even if
        // the replay made fewer (a plan's end it did not see, say).
        self.revision = self.revision.max(published);
        if self.stopped.is_none()
            && journaled.is_some_and(|c| c.epoch.state == EpochState::Stopped as u32)
        {
            self.stopped = Some(format!(
                "calibrating had stopped before the stage restarted (calibration revision {published})"
            ));
        }
        self.recovered = Some(Recovery {
            samples: samples.len(),
            train_samples: self.train.len(),
            revision: published,
            calibration_reproduced: journaled.map(|_| reproduced.unwrap_or(false)),
            dropped,
        });
        out
    }

    /// Training samples paired so far.
    pub fn train_samples(&self) -> usize {
        self.train.len()
    }

    /// The calibration revision published last (0: none yet).
    pub fn revision(&self) -> u64 {
        self.revision
    }

    /// Counts messages that never arrived, from sequence numbers.
    fn account_seq(last: &mut Option<u64>, seq: u64, missed: &mut u64, restarts: &mut u64) {
        match *last {
            // Published before this stage listened.
            None => *missed += seq,
            Some(l) if seq > l + 1 => *missed += seq - l - 1,
            Some(l) if seq <= l => *restarts += 1,
            Some(_) => {}
        }
        *last = Some(seq);
    }

    fn joint_state_fault(&self, js: &JointState) -> Option<String> {
        js.fault(self.rig.arm.as_ref().map_or(0, |a| a.dof()))
            .or_else(|| {
                self.stamp_fault(
                    js.stamp_ns,
                    self.last_joint_stamp,
                    self.last_detection_stamp,
                )
            })
    }

    fn detections_fault(&self, d: &StereoDetections) -> Option<String> {
        d.fault().or_else(|| {
            self.stamp_fault(d.stamp_ns, self.last_detection_stamp, self.last_joint_stamp)
        })
    }

    fn stamp_fault(&self, stamp: i64, last_own: i64, last_other: i64) -> Option<String> {
        if stamp <= last_own {
            return Some(format!(
                "stamp {stamp} repeats or goes back from {last_own}"
            ));
        }
        if last_other != i64::MIN && stamp.saturating_sub(last_other) > MAX_STREAM_SKEW_NS {
            return Some(format!(
                "stamp {stamp} is {:.0} s ahead of the other stream",
                (stamp - last_other) as f64 * 1e-9
            ));
        }
        None
    }

    /// Hands each new sample out alone, before what it sets going (its
    /// scoring against the calibration, a calibration, the objects located
    /// in its frame), which [`Live::after_sample`] then gives: the live
    /// stage publishes a sample without waiting for a calibration. The
    /// outputs and their order are the same either way.
    pub fn publish_samples_first(&mut self) {
        self.samples_first = true;
    }

    /// Whether a sample was handed out whose consequences are still to
    /// come ([`Live::after_sample`]).
    pub fn holds_sample(&self) -> bool {
        self.held.is_some()
    }

    /// What the last sample handed out sets going, and what became ready
    /// after it; empty when nothing was held. Taking the next joint state
    /// or detection does this first too.
    pub fn after_sample(&mut self) -> Vec<Output> {
        self.drain()
    }

    /// Whether the pose plan has ended and everything before its end is processed.
    pub fn finished(&self) -> bool {
        self.finished
    }

    /// Whether the joint state that ends the pose plan has come (it is
    /// processed once the detections have passed its stamp).
    pub fn plan_ended(&self) -> bool {
        self.joints_ended
    }

    /// The detections have ended: their source stopped after the plan's
    /// end (the robot's side of a split run stops its camera when the plan
    /// is done), so no detection will pass the joint states still queued.
    /// They are processed now, the plan's end among them.
    pub fn end_of_detections(&mut self) -> Vec<Output> {
        self.detections_ended = true;
        self.drain()
    }

    /// Takes a joint state; returns what became ready.
    pub fn push_joint_state(&mut self, js: JointState) -> Vec<Output> {
        if let Some(why) = self.joint_state_fault(&js) {
            self.counters.rejected += 1;
            self.rejections.reject("joint state", js.seq, &why);
            return Vec::new();
        }
        Self::account_seq(
            &mut self.last_joint_seq,
            js.seq,
            &mut self.counters.joint_states_missed,
            &mut self.counters.source_restarts,
        );
        self.last_joint_stamp = js.stamp_ns;
        if js.phase() == Ok(Phase::Done) {
            self.joints_ended = true;
        }
        self.joints.push_back(js);
        self.drain()
    }

    /// Takes a stereo detection; returns what became ready.
    pub fn push_detections(&mut self, d: StereoDetections) -> Vec<Output> {
        if let Some(why) = self.detections_fault(&d) {
            self.counters.rejected += 1;
            self.rejections.reject("detection", d.seq, &why);
            return Vec::new();
        }
        Self::account_seq(
            &mut self.last_detection_seq,
            d.seq,
            &mut self.counters.detections_missed,
            &mut self.counters.source_restarts,
        );
        self.last_detection_stamp = d.stamp_ns;
        self.detections.push_back(d);
        self.drain()
    }

    /// Processes queued events in stamp order as far as both streams allow.
    fn drain(&mut self) -> Vec<Output> {
        let mut out = Vec::new();
        if let Some(held) = self.held.take() {
            let (sample, d) = *held;
            self.take_sample(sample, &mut out);
            self.locate_objects(&d, &mut out);
        }
        loop {
            if self.finished || self.held.is_some() {
                return out;
            }
            enum Next {
                Joint,
                Detection,
                Wait,
            }
            let next = match (self.joints.front(), self.detections.front()) {
                (Some(j), Some(d)) if j.stamp_ns <= d.stamp_ns => Next::Joint,
                (Some(_), Some(_)) => Next::Detection,
                // A joint state is safe once detections have passed it.
                (Some(j), None)
                    if self.last_detection_stamp >= j.stamp_ns || self.detections_ended =>
                {
                    Next::Joint
                }
                // A detection is safe once joint states have passed it, or they ended.
                (None, Some(d)) if self.joints_ended || self.last_joint_stamp > d.stamp_ns => {
                    Next::Detection
                }
                _ => Next::Wait,
            };
            match next {
                Next::Joint => {
                    if let Some(js) = self.joints.pop_front() {
                        let stamp_ns = js.stamp_ns;
                        self.on_joint_state(js);
                        if self.finished {
                            self.on_plan_end(stamp_ns, &mut out);
                        }
                    }
                }
                Next::Detection => {
                    if let Some(d) = self.detections.pop_front() {
                        self.on_detections(&d, &mut out);
                    }
                }
                Next::Wait => return out,
            }
        }
    }

    fn on_joint_state(&mut self, js: JointState) {
        self.counters.joint_states += 1;
        let same_window = self
            .window
            .as_ref()
            .is_some_and(|w| w.state.pose == js.pose && js.phase() == Ok(Phase::Settled));
        if same_window {
            return;
        }
        if let Some(w) = self.window.take()
            && !w.done
        {
            self.counters.missed += 1;
            let n = self.counters.missed;
            if n <= 10 || n.is_multiple_of(100) {
                tracing::warn!(
                    pose = w.state.pose,
                    missed = n,
                    "no sample: the arm's marker {} was not seen{} in both cameras while the pose held",
                    self.config.arm_marker,
                    if w.state.role() == Ok(Role::Direct) {
                        ""
                    } else {
                        " mirror-reversed"
                    }
                );
            }
        }
        match js.phase() {
            // A pose plan started again (a restarted kinematics stage): one
            // sample per pose, so the poses already sampled are skipped.
            Ok(Phase::Settled)
                if self.poses_sampled.contains(&js.pose) && self.repeated_pose != Some(js.pose) =>
            {
                self.counters.poses_repeated += 1;
                self.repeated_pose = Some(js.pose);
            }
            Ok(Phase::Settled) if self.poses_sampled.contains(&js.pose) => {}
            Ok(Phase::Settled) => {
                self.window = Some(Window {
                    opens_ns: js.stamp_ns + self.config.settle_margin_ns,
                    state: js,
                    done: false,
                });
            }
            Ok(Phase::Done) => self.finished = true,
            _ => {}
        }
    }

    fn on_detections(&mut self, d: &StereoDetections, out: &mut Vec<Output>) {
        self.counters.detections += 1;
        self.still.push(d, self.config.arm_marker);
        if let Some(w) = self
            .window
            .as_mut()
            .filter(|w| !w.done && d.stamp_ns >= w.opens_ns)
        {
            let mirrored = w.state.role() != Ok(Role::Direct);
            let found = [
                d.cameras[0].find(self.config.arm_marker, mirrored),
                d.cameras[1].find(self.config.arm_marker, mirrored),
            ];
            if let [Some(l), Some(r)] = found {
                w.done = true;
                let state = w.state;
                self.poses_sampled.insert(state.pose);
                let pixels = [self.marker_pixel(0, l), self.marker_pixel(1, r)];
                let sample = self.add_sample(state, d.stamp_ns, pixels, out);
                if self.samples_first {
                    self.held = Some(Box::new((sample, *d)));
                    return;
                }
                self.take_sample(sample, out);
            }
        }
        self.locate_objects(d, out);
    }

    /// Where the centre of marker `m`, found by camera `k`, lies in the
    /// image: its corners' diagonals crossed through the lens model
    /// (the tracker's crossing of the raw corners is off by up to a pixel
    /// under distortion); the tracker's where that fails.
    fn marker_pixel(&self, k: usize, m: &messages::Marker) -> [f64; 2] {
        let c = m.corners;
        let corners = [0, 1, 2, 3].map(|i| Vector2::new(c[2 * i], c[2 * i + 1]));
        self.rig.cameras[k]
            .intrinsics
            .marker_center(&corners)
            .map_or(m.center, Into::into)
    }

    /// Makes the sample of a pose and hands it out.
    fn add_sample(
        &mut self,
        state: JointState,
        stamp_ns: i64,
        pixels: [[f64; 2]; 2],
        out: &mut Vec<Output>,
    ) -> MirrorSample {
        let triangulated = triangulate(self.rig.camera_refs(), pixels.map(Vector2::from))
            .map_or([f64::NAN; 3], Into::into);
        let sample = MirrorSample {
            pose: state.pose,
            stamp_ns,
            role: state.role,
            dof: state.dof,
            q: state.q,
            model_point: state.model_point,
            pixels,
            triangulated,
        };
        self.counters.paired += 1;
        out.push(Output::Sample(sample));
        sample
    }

    /// What a new sample does: it is scored against the calibration for a
    /// changed world, then trains the calibration or tests it.
    fn take_sample(&mut self, sample: MirrorSample, out: &mut Vec<Output>) {
        self.watch(&sample, out);
        let stamp_ns = sample.stamp_ns;
        if sample.role == Role::Train as u32 {
            self.train.push(sample);
        } else {
            self.tests.push(sample);
        }
        let train = sample.role == Role::Train as u32;
        if self.stopped.is_some() {
            // Nothing is calibrated or predicted any more.
        } else if self.drifted.is_some() {
            self.recover(train, stamp_ns, out);
        } else if !train {
            self.predict(&sample, out);
        } else if self.train.len() - self.epoch.train_from
            >= self.config.min_train.max(self.epoch.kept_samples)
        {
            self.recalibrate(stamp_ns, out);
        }
    }

    /// Scores `sample` against the calibration; a change found ends the
    /// epoch: the calibration is published once more, drifted.
    fn watch(&mut self, sample: &MirrorSample, out: &mut Vec<Output>) {
        if self.drifted.is_some() || self.stopped.is_some() {
            return;
        }
        let Some(drift) = self
            .monitor
            .as_mut()
            .and_then(|m| m.push(&sample.to_sample()))
            .cloned()
        else {
            return;
        };
        self.monitor = None;
        // The change began at `began_at_pose`: the samples from it on
        // belong to the world as it is now.
        let began_ns = self
            .train
            .iter()
            .chain(&self.tests)
            .chain([sample])
            .find(|s| s.pose == drift.began_at_pose)
            .map_or(sample.stamp_ns, |s| s.stamp_ns);
        let from = |samples: &[MirrorSample]| {
            samples
                .iter()
                .position(|s| s.stamp_ns >= began_ns)
                .unwrap_or(samples.len())
        };
        let (train_from, tests_from) = (from(&self.train), from(&self.tests));
        let set_aside = train_from - self.epoch.train_from;
        tracing::warn!(
            began_at_pose = drift.began_at_pose,
            found_at_pose = drift.found_at_pose,
            "the world changed: the {} moved; the calibration no longer holds: its {set_aside} calibration samples are set aside, and it is calibrated again from the samples that follow",
            epochs::describe(&drift.moved)
        );
        self.drifted = Some(Drifted {
            drift,
            train_from,
            tests_from,
            cameras_found: false,
        });
        if let Some(cal) = &self.calibration {
            self.revision += 1;
            let msg = self.calibration_msg(cal, sample.stamp_ns, self.revision);
            out.push(Output::Calibration(Box::new(msg)));
        }
    }

    /// The frames on either side of the change `d` (by stamp), where the
    /// still markers are compared: from the epoch's first sample to the
    /// last before the change, and from the first after it on. `None`
    /// without samples on both sides.
    fn still_sides(&self, d: &Drifted) -> Option<(std::ops::RangeInclusive<i64>, i64)> {
        let stamps = |train: std::ops::Range<usize>, tests: std::ops::Range<usize>| {
            self.train[train]
                .iter()
                .chain(&self.tests[tests])
                .map(|s| s.stamp_ns)
                .collect::<Vec<_>>()
        };
        let before = stamps(
            self.epoch.train_from..d.train_from,
            self.epoch.tests_from..d.tests_from,
        );
        let after = stamps(
            d.train_from..self.train.len(),
            d.tests_from..self.tests.len(),
        );
        // The first epoch holds every frame from the start.
        let from = if self.epoch.number == 1 {
            i64::MIN
        } else {
            *before.iter().min()?
        };
        Some((from..=*before.iter().max()?, *after.iter().min()?))
    }

    /// After a change: finds the moved cameras again once enough direct
    /// views have come, and calibrates the new epoch once enough training
    /// samples have (tried again on each new one, `train`, while it fails).
    fn recover(&mut self, train: bool, stamp_ns: i64, out: &mut Vec<Output>) {
        let (Some(d), Some(old)) = (self.drifted.clone(), self.calibration.clone()) else {
            return;
        };
        let moved = epochs::cameras_moved(&self.rig, &d.drift.moved);
        let new_train = self.train.len() - d.train_from;
        let mut fresh = train;
        if !moved.is_empty() && !d.cameras_found {
            let direct = self.tests[d.tests_from..]
                .iter()
                .filter(|s| s.role == Role::Direct as u32)
                .count();
            if direct < CAMERA_VIEWS {
                return;
            }
            let since: Vec<Sample> = self.train[d.train_from..]
                .iter()
                .chain(&self.tests[d.tests_from..])
                .map(MirrorSample::to_sample)
                .collect();
            let sigma = CalibrateOptions::default().pixel_sigma_for(&self.rig);
            let other_still = moved.len() == 1;
            let sides = self.still_sides(&d);
            for &k in &moved {
                let still = sides
                    .as_ref()
                    .map(|(before, after)| self.still.pairs(k, before.clone(), *after))
                    .unwrap_or_default();
                let found = epochs::find_camera(
                    &self.rig,
                    &old,
                    &since,
                    &still,
                    k,
                    other_still,
                    sigma,
                    d.drift.began_at_pose,
                );
                match found {
                    Ok(found) => {
                        let entry = found.entry;
                        tracing::info!(
                            camera = entry.name,
                            turn_deg = entry.turn_deg,
                            sigma_deg = ?entry.sigma_deg,
                            views = entry.views,
                            still_markers = still.len(),
                            "camera found again"
                        );
                        self.still.forget(k);
                        self.rig.cameras[k].camera_from_world =
                            Matrix3::from_row_slice(&entry.camera_from_world);
                        self.turn_covariances[found.index] = Some(found.turn_covariance);
                        self.head_cameras.retain(|c| c.name != entry.name);
                        self.head_cameras.push(entry);
                    }
                    Err(why) => {
                        self.stop(why, stamp_ns, out);
                        return;
                    }
                }
            }
            if let Some(d) = self.drifted.as_mut() {
                d.cameras_found = true;
            }
            fresh = true;
            // The mirror did not move: its plane gives the moved camera's
            // mirror camera at once (the old calibration's uncertainty holds
            // the turns of cameras found before). The old calibration, on
            // more samples than the few since, is kept until the new epoch
            // has as many of its own.
            if let Some(cal) = epochs::reflected_anew(&old, &self.rig) {
                let cal = self.with_found_turns(cal, &moved);
                let kept = cal.samples;
                self.begin_epoch(cal, stamp_ns, out);
                self.epoch.kept_samples = kept;
                return;
            }
        }
        if new_train < self.config.min_train || !fresh {
            return;
        }
        let samples: Vec<Sample> = self.train[d.train_from..]
            .iter()
            .map(MirrorSample::to_sample)
            .collect();
        let options = CalibrateOptions {
            start_plane: old.plane,
            ..CalibrateOptions::default()
        };
        match calibrate_with(&self.rig, &samples, self.config.method, options) {
            Ok(cal) => {
                let cal = self.with_found_turns(cal, &[0, 1]);
                self.begin_epoch(cal, stamp_ns, out);
            }
            Err(e) => {
                self.counters.calibration_failures += 1;
                self.last_error = Some(e.to_string());
            }
        }
    }

    /// Ends the epoch under way at the change found, and begins the next
    /// with `cal`.
    fn begin_epoch(&mut self, cal: Calibration, stamp_ns: i64, out: &mut Vec<Output>) {
        let Some(d) = self.drifted.take() else { return };
        let ended = self.epoch_report(Some(d.drift.began_at_pose), d.train_from, d.tests_from);
        self.past_epochs.push(ended);
        self.epoch = Epoch {
            number: self.epoch.number + 1,
            began_at_pose: d.drift.began_at_pose,
            after: Some(d.drift),
            train_from: d.train_from,
            tests_from: d.tests_from,
            start_plane: self.calibration.as_ref().and_then(|c| c.plane),
            head_cameras: self.head_cameras.clone(),
            kept_samples: 0,
        };
        tracing::info!(
            epoch = self.epoch.number,
            began_at_pose = self.epoch.began_at_pose,
            samples = cal.samples,
            "calibrated again after the change"
        );
        self.last_error = None;
        self.publish_calibration(cal, stamp_ns, out);
    }

    /// Calibrating cannot go on after the change: says why, once. The
    /// change stays on record: the epoch it ended ends there.
    fn stop(&mut self, why: String, stamp_ns: i64, out: &mut Vec<Output>) {
        tracing::warn!("calibration stopped: {why}");
        self.stopped = Some(why.clone());
        self.last_error = Some(why);
        if let Some(cal) = &self.calibration {
            self.revision += 1;
            let msg = self.calibration_msg(cal, stamp_ns, self.revision);
            out.push(Output::Calibration(Box::new(msg)));
        }
    }

    /// At the plan's end (stamped `stamp_ns`, the joint state's that
    /// ended it, so that a replay stamps it alike): a change not yet
    /// calibrated again stops the calibration, with the reason.
    fn on_plan_end(&mut self, stamp_ns: i64, out: &mut Vec<Output>) {
        let Some(d) = self.drifted.clone().filter(|_| self.stopped.is_none()) else {
            return;
        };
        let what = epochs::describe(&d.drift.moved);
        let why = if !epochs::cameras_moved(&self.rig, &d.drift.moved).is_empty()
            && !d.cameras_found
        {
            let direct = self.tests[d.tests_from..]
                .iter()
                .filter(|s| s.role == Role::Direct as u32)
                .count();
            format!(
                "the {what} moved at pose {} (found at pose {}), and {direct} direct views came after it, of the {CAMERA_VIEWS} needed to find its pose again; the plan needs direct views after the change",
                d.drift.began_at_pose, d.drift.found_at_pose
            )
        } else {
            format!(
                "the {what} moved at pose {} (found at pose {}), and {} calibration samples came after it, of the {} needed to calibrate again{}",
                d.drift.began_at_pose,
                d.drift.found_at_pose,
                self.train.len() - d.train_from,
                self.config.min_train,
                self.last_error
                    .as_ref()
                    .map_or(String::new(), |e| format!(" ({e})"))
            )
        };
        self.stop(why, stamp_ns, out);
    }

    fn recalibrate(&mut self, stamp_ns: i64, out: &mut Vec<Output>) {
        let samples: Vec<Sample> = self.train[self.epoch.train_from..]
            .iter()
            .map(MirrorSample::to_sample)
            .collect();
        let _span = tracing::trace_span!("calibrate", samples = samples.len()).entered();
        let options = CalibrateOptions {
            start_plane: self.epoch.start_plane,
            ..CalibrateOptions::default()
        };
        match calibrate_with(&self.rig, &samples, self.config.method, options) {
            Ok(cal) => {
                for r in &cal.rejected {
                    if self.rejections_logged.insert(r.pose) {
                        tracing::warn!(
                            pose = r.pose,
                            residual_px = r.residual_px,
                            "sample set aside: it does not fit the others (a wrong pairing or a misread marker?)"
                        );
                    }
                }
                match &cal.fit {
                    Fit::Poor { cause } if !self.poor_fit_logged => {
                        tracing::warn!("poor fit: {cause}");
                        self.poor_fit_logged = true;
                    }
                    Fit::Poor { .. } => {}
                    _ => self.poor_fit_logged = false,
                }
                self.last_error = None;
                let cal = self.with_found_turns(cal, &[0, 1]);
                self.publish_calibration(cal, stamp_ns, out);
            }
            Err(e) => {
                // Keep collecting: a later sample may make the problem well
                // posed. Nothing is published; the reason is logged when it
                // changes and kept for the report.
                self.counters.calibration_failures += 1;
                let why = e.to_string();
                if self.last_error.as_ref() != Some(&why) {
                    tracing::warn!(
                        samples = samples.len(),
                        "cannot calibrate yet: {why}; collecting more samples"
                    );
                }
                self.last_error = Some(why);
            }
        }
    }

    /// `cal`, made with the rig as it is now, with the uncertainty of the
    /// turns of `cameras` where they were found again: a calibration takes
    /// a found camera as exact, but it is known only to its turn's
    /// accuracy.
    fn with_found_turns(&self, mut cal: Calibration, cameras: &[usize]) -> Calibration {
        if let Some(plane) = cal.plane {
            for &k in cameras {
                if let Some(turn) = &self.turn_covariances[k] {
                    cal.uncertainty
                        .add_head_camera_turn(&self.rig.cameras[k], k, &plane, turn);
                }
            }
        }
        cal
    }

    /// Publishes `cal` as the next revision and watches the samples that
    /// follow against it.
    fn publish_calibration(&mut self, cal: Calibration, stamp_ns: i64, out: &mut Vec<Output>) {
        self.revision += 1;
        let msg = self.calibration_msg(&cal, stamp_ns, self.revision);
        if self.config.watch_drift && cal.samples >= WATCH_FROM_SAMPLES {
            let sigma = CalibrateOptions::default().pixel_sigma_for(&self.rig);
            match &mut self.monitor {
                Some(m) => m.watch(&self.rig, cal.clone(), sigma),
                None => self.monitor = Some(DriftMonitor::new(&self.rig, cal.clone(), sigma)),
            }
        }
        self.calibration = Some(cal);
        out.push(Output::Calibration(Box::new(msg)));
    }

    /// The message of calibration `cal`.
    fn calibration_msg(&self, cal: &Calibration, stamp_ns: i64, revision: u64) -> CalibrationMsg {
        let mut msg = CalibrationMsg {
            stamp_ns,
            revision,
            method: cal.method as u32,
            samples: cal.samples as u32,
            train_rms_px: cal.train_rms_px,
            ..Default::default()
        };
        if let Some(p) = cal.plane {
            msg.has_plane = 1;
            msg.plane = [p.normal.x, p.normal.y, p.normal.z, p.distance];
        }
        msg.cameras = [
            CameraPose::from_camera(&cal.mirror_cameras[0]),
            CameraPose::from_camera(&cal.mirror_cameras[1]),
        ];
        if let Some(o) = &cal.joint_offsets {
            msg.dof = o.len().min(MAX_JOINTS) as u32;
            msg.joint_offsets[..msg.dof as usize].copy_from_slice(&o[..msg.dof as usize]);
        }
        msg.uncertainty = uncertainty_msg(cal);
        msg.epoch = self.epoch_msg();
        msg
    }

    /// The state of the calibration as the message states it.
    fn epoch_msg(&self) -> CalibrationEpoch {
        let moved = |m: &Moved| match m {
            Moved::Mirror => (messages::Moved::Mirror, 0),
            Moved::Camera(name) => (
                messages::Moved::Camera,
                self.rig.names.iter().position(|n| n == name).unwrap_or(0) as u32,
            ),
            Moved::Head => (messages::Moved::Head, 0),
        };
        let mut msg = CalibrationEpoch {
            epoch: self.epoch.number,
            began_at_pose: self.epoch.began_at_pose,
            ..Default::default()
        };
        let change = match (&self.drifted, &self.epoch.after) {
            (Some(d), _) => {
                msg.state = EpochState::Drifted as u32;
                msg.began_at_pose = d.drift.began_at_pose;
                Some(&d.drift)
            }
            (None, after) => after.as_ref(),
        };
        if self.stopped.is_some() {
            msg.state = EpochState::Stopped as u32;
        }
        if let Some(c) = change {
            let (what, camera) = moved(&c.moved);
            msg.moved = what as u32;
            msg.camera = camera;
            msg.found_at_pose = c.found_at_pose;
        }
        msg
    }

    /// The report of the epoch under way, ended where a change began at
    /// `ended_at_pose` (its samples before `train_to`, `tests_to`).
    fn epoch_report(
        &self,
        ended_at_pose: Option<u64>,
        train_to: usize,
        tests_to: usize,
    ) -> EpochReport {
        EpochReport {
            epoch: self.epoch.number,
            began_at_pose: self.epoch.began_at_pose,
            after: self
                .epoch
                .after
                .as_ref()
                .map(|d| epochs::describe(&d.moved)),
            found_at_pose: self.epoch.after.as_ref().map(|d| d.found_at_pose),
            ended_at_pose,
            train_samples: train_to - self.epoch.train_from,
            test_samples: tests_to - self.epoch.tests_from,
            calibration: self.calibration.as_ref().map(|c| self.calibration_file(c)),
        }
    }

    /// The file form of `cal`, a calibration of the epoch under way, with
    /// the head cameras found again before it.
    fn calibration_file(&self, cal: &Calibration) -> formats::calibration::CalibrationFile {
        cal.to_file(&self.rig)
            .with_head_cameras(self.epoch.head_cameras.clone())
    }

    fn predict(&self, sample: &MirrorSample, out: &mut Vec<Output>) {
        let Some(cal) = &self.calibration else { return };
        let s = sample.to_sample();
        let direct = sample.role == Role::Direct as u32;
        let cams = if direct {
            self.rig.cameras
        } else {
            cal.mirror_cameras
        };
        let Ok(model) = crate::calibrate::model_point(&self.rig, &s, cal.joint_offsets.as_deref())
        else {
            return;
        };
        let refs = [&cams[0], &cams[1]];
        let (Ok(reconstructed), Ok(l), Ok(r)) = (
            triangulate(refs, s.pixels),
            cams[0].project(&model),
            cams[1].project(&model),
        ) else {
            return;
        };
        out.push(Output::Prediction(Prediction {
            pose: sample.pose,
            stamp_ns: sample.stamp_ns,
            revision: self.revision,
            role: sample.role,
            reserved: 0,
            model_point: model.into(),
            reconstructed: reconstructed.into(),
            predicted_pixels: [l.into(), r.into()],
            error_mm: (reconstructed - model).norm(),
            error_px: 0.5 * ((l - s.pixels[0]).norm() + (r - s.pixels[1]).norm()),
        }));
    }

    fn locate_objects(&mut self, d: &StereoDetections, out: &mut Vec<Output>) {
        // Not through a calibration the world has changed under.
        if self.drifted.is_some() || self.stopped.is_some() {
            return;
        }
        let Some(cal) = &self.calibration else { return };
        for m in d.cameras[0]
            .iter()
            .filter(|m| m.mirrored == 1 && m.id != self.config.arm_marker)
        {
            let Some(r) = d.cameras[1].find(m.id, true) else {
                continue;
            };
            let refs = [&cal.mirror_cameras[0], &cal.mirror_cameras[1]];
            let pixels = [self.marker_pixel(0, m), self.marker_pixel(1, r)].map(Vector2::from);
            if let Ok(p) = triangulate(refs, pixels) {
                self.located.insert(m.id, p.into());
                // Zero where it cannot be stated (as in a v1 recording).
                let covariance = cal.uncertainty.located_covariance(&cal.mirror_cameras, &p);
                match &covariance {
                    Some(c) => self
                        .located_sigma_mm
                        .insert(m.id, crate::calibrate::uncertainty::rms_error_mm(c)),
                    None => self.located_sigma_mm.remove(&m.id),
                };
                let c = covariance.unwrap_or_else(Matrix3::zeros);
                out.push(Output::Located(LocatedObject {
                    stamp_ns: d.stamp_ns,
                    revision: self.revision,
                    id: m.id,
                    reserved: 0,
                    position: p.into(),
                    covariance_mm2: [c.m11, c.m12, c.m13, c.m22, c.m23, c.m33],
                }));
            }
        }
    }

    /// The final report: the final calibration evaluated on the test
    /// samples of its epoch.
    pub fn report(&self) -> LiveReport {
        let tests: Vec<Sample> = self.tests[self.epoch.tests_from..]
            .iter()
            .map(MirrorSample::to_sample)
            .collect();
        let usable = self.drifted.is_none() && self.stopped.is_none();
        let evaluation = self
            .calibration
            .as_ref()
            .filter(|_| usable)
            .and_then(|cal| {
                evaluate(
                    &self.rig,
                    &cal.mirror_cameras,
                    cal.joint_offsets.as_deref(),
                    &tests,
                )
                .ok()
                .map(|e| e.summary())
            });
        let (ended, train_to, tests_to) = match &self.drifted {
            Some(d) => (Some(d.drift.began_at_pose), d.train_from, d.tests_from),
            None => (None, self.train.len(), self.tests.len()),
        };
        let mut epochs = self.past_epochs.clone();
        epochs.push(self.epoch_report(ended, train_to, tests_to));
        LiveReport {
            method: self.config.method.to_string(),
            train_samples: self.train.len(),
            test_samples: self.tests.len(),
            evaluation,
            calibration: self.calibration.as_ref().map(|c| self.calibration_file(c)),
            located: self.located.clone(),
            located_sigma_mm: self.located_sigma_mm.clone(),
            last_error: self.last_error.clone().or_else(|| {
                self.calibration.is_none().then(|| {
                    format!(
                        "{} of the {} calibration samples needed so far; {} poses without the arm's marker {} in both cameras",
                        self.train.len(),
                        self.config.min_train,
                        self.counters.missed,
                        self.config.arm_marker
                    )
                })
            }),
            counters: self.counters.clone(),
            latency_ms: None,
            recovered: self.recovered.clone(),
            epochs,
        }
    }
}

/// The message form of a calibration's uncertainty.
fn uncertainty_msg(cal: &Calibration) -> CalibrationUncertainty {
    let u = &cal.uncertainty;
    let plane_sigma = |sigma: Option<f64>| match (cal.plane, sigma) {
        (None, _) => 0.0,
        (Some(_), sigma) => sigma.unwrap_or(UNDETERMINED),
    };
    let mut msg = CalibrationUncertainty {
        stated: u32::from(u.stated),
        rejected_samples: cal.rejected.len() as u32,
        residual_px: u.residual_px,
        plane_angle_deg: plane_sigma(u.plane_angle_deg),
        plane_distance_mm: plane_sigma(u.plane_distance_mm),
        mirror_camera_centers_mm: u.mirror_camera_centers_mm,
        mirror_camera_angles_deg: u.mirror_camera_angles_deg,
        ..Default::default()
    };
    if let Some(o) = &u.joint_offsets_deg {
        msg.dof = o.len().min(MAX_JOINTS) as u32;
        for (slot, sigma) in msg.joint_offsets_deg.iter_mut().zip(o) {
            *slot = sigma.unwrap_or(UNDETERMINED);
        }
    }
    msg
}
