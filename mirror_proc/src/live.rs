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
    CalibrationMsg, CalibrationUncertainty, CameraPose, JointState, LocatedObject, MAX_JOINTS,
    MirrorSample, Phase, Prediction, Role, StereoDetections, UNDETERMINED,
};
use nalgebra::{Matrix3, Vector2};
use runtime::Rejections;
use serde::{Deserialize, Serialize};

use crate::calibrate::{Calibration, Fit, Method, calibrate};
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
}

impl Default for LiveConfig {
    fn default() -> Self {
        Self {
            method: Method::JointKinematics,
            arm_marker: 0,
            min_train: 8,
            settle_margin_ns: 30_000_000,
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
}

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
        }
    }

    /// Resumes from what an earlier run of this stage journaled: its samples
    /// in the order they were paired, and its calibrations. Poses already
    /// sampled are not paired again. The last calibration is computed again
    /// from the training samples it used (the solvers are deterministic, so
    /// it comes out the same, bit for bit, which is checked); training
    /// samples journaled after it are calibrated on as they would have been.
    /// Returns what must be published: a calibration the crash prevented.
    pub fn resume(
        &mut self,
        samples: &[MirrorSample],
        calibrations: &[CalibrationMsg],
        dropped: Option<String>,
    ) -> Vec<Output> {
        for s in samples {
            self.poses_sampled.insert(s.pose);
            self.counters.paired += 1;
            if s.role == Role::Train as u32 {
                self.train.push(*s);
            } else {
                self.tests.push(*s);
            }
        }
        // The arm may still hold the last pose sampled before the crash: the
        // rest of its dwell is not a repeated pose.
        self.repeated_pose = samples.last().map(|s| s.pose);
        let mut recovery = Recovery {
            samples: samples.len(),
            train_samples: self.train.len(),
            dropped,
            ..Default::default()
        };
        let mut out = Vec::new();
        let last = calibrations.last();
        if let Some(journaled) = last {
            let used = samples_considered(journaled).min(self.train.len());
            let train: Vec<Sample> = self.train[..used]
                .iter()
                .map(MirrorSample::to_sample)
                .collect();
            self.revision = journaled.revision;
            recovery.revision = journaled.revision;
            match calibrate(&self.rig, &train, self.config.method) {
                Ok(cal) => {
                    let again = self.calibration_msg(&cal, journaled.stamp_ns, journaled.revision);
                    recovery.calibration_reproduced = Some(again == *journaled);
                    self.calibration = Some(cal);
                }
                Err(e) => {
                    recovery.calibration_reproduced = Some(false);
                    self.last_error = Some(e.to_string());
                }
            }
        }
        let calibrated = last.map_or(0, samples_considered);
        if self.train.len() > calibrated && self.train.len() >= self.config.min_train {
            let stamp = self.train.last().map_or(0, |s| s.stamp_ns);
            self.recalibrate(stamp, &mut out);
        }
        self.recovered = Some(recovery);
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
        loop {
            if self.finished {
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
                        self.on_joint_state(js);
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
                self.add_sample(state, d.stamp_ns, pixels, out);
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

    fn add_sample(
        &mut self,
        state: JointState,
        stamp_ns: i64,
        pixels: [[f64; 2]; 2],
        out: &mut Vec<Output>,
    ) {
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
        if state.role() == Ok(Role::Train) {
            self.train.push(sample);
            if self.train.len() >= self.config.min_train {
                self.recalibrate(stamp_ns, out);
            }
        } else {
            self.tests.push(sample);
            self.predict(&sample, out);
        }
    }

    fn recalibrate(&mut self, stamp_ns: i64, out: &mut Vec<Output>) {
        let _span = tracing::trace_span!("calibrate", samples = self.train.len()).entered();
        let samples: Vec<Sample> = self.train.iter().map(MirrorSample::to_sample).collect();
        match calibrate(&self.rig, &samples, self.config.method) {
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
                self.revision += 1;
                self.last_error = None;
                let msg = self.calibration_msg(&cal, stamp_ns, self.revision);
                self.calibration = Some(cal);
                out.push(Output::Calibration(Box::new(msg)));
            }
            Err(e) => {
                // Keep collecting: a later sample may make the problem well
                // posed. Nothing is published; the reason is logged when it
                // changes and kept for the report.
                self.counters.calibration_failures += 1;
                let why = e.to_string();
                if self.last_error.as_ref() != Some(&why) {
                    tracing::warn!(
                        samples = self.train.len(),
                        "cannot calibrate yet: {why}; collecting more samples"
                    );
                }
                self.last_error = Some(why);
            }
        }
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
        msg
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

    /// The final report: the final calibration evaluated on all test samples.
    pub fn report(&self) -> LiveReport {
        let tests: Vec<Sample> = self.tests.iter().map(MirrorSample::to_sample).collect();
        let evaluation = self.calibration.as_ref().and_then(|cal| {
            evaluate(
                &self.rig,
                &cal.mirror_cameras,
                cal.joint_offsets.as_deref(),
                &tests,
            )
            .ok()
            .map(|e| e.summary())
        });
        LiveReport {
            method: self.config.method.to_string(),
            train_samples: self.train.len(),
            test_samples: self.tests.len(),
            evaluation,
            calibration: self.calibration.as_ref().map(|c| c.to_file(&self.rig)),
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

/// The training samples a calibration was computed from: those it kept and
/// those its outlier test set aside (the first ones of the stage's list).
fn samples_considered(c: &CalibrationMsg) -> usize {
    c.samples as usize + c.uncertainty.rejected_samples as usize
}
