//! Has the world changed under a calibration? Every new sample is a fresh
//! test of it: its reprojection error in each camera, over what the
//! calibration expects (the fit's residual noise), is chi-square with 2
//! degrees of freedom while nothing has changed. Four one-sided CUSUMs,
//! one per view (mirror, direct) and camera, add up how far each sample's
//! error exceeds that; one exceeding a threshold is a change. A sample's
//! part is capped, so one wrong pairing cannot raise the alarm on its own.
//!
//! What moved follows from where the errors grew: a moved mirror shows in
//! both cameras' mirror views (and not in direct views); a knocked camera
//! in its own errors only, mirror and direct; both cameras' direct views,
//! the head or the arm as a whole.
//!
//! A change too small for any one sample to show adds up in a second,
//! structured test (`drift::glr`): the samples since a change point, fitted
//! with a moved plane or a turned camera.

mod glr;

use geometry::{Rig, Sample, View};

use crate::calibrate::{Calibration, Seen, camera_errors, model_point};

/// Allowance per sample, in units of the expected error (the mean of
/// chi-square 2 over 2 is 1): a sample must exceed it to add up.
const ALLOWANCE: f64 = 2.0;
/// What the CUSUM must reach to call a change.
const THRESHOLD: f64 = 12.0;
/// Most one sample adds: two consecutive bad samples are needed.
const CAP: f64 = THRESHOLD * 0.75;

/// What a change is put down to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Moved {
    /// The mirror (mirror views grew, direct views did not, or none seen).
    Mirror,
    /// A head camera, by name (its own errors grew, in direct views too).
    Camera(String),
    /// Both cameras' direct views grew: the arm or the whole head.
    Head,
}

/// A change found.
#[derive(Debug, Clone, PartialEq)]
pub struct Drift {
    /// What moved.
    pub moved: Moved,
    /// The pose of the first sample of the run of errors that raised the
    /// alarm: where the change began.
    pub began_at_pose: u64,
    /// The pose at which it was called.
    pub found_at_pose: u64,
}

/// A sample's score from which it is taken for the first of a change:
/// one in 90 of an unchanged world's reaches it.
const CHANGED_FROM: f64 = CAP / 2.0;

/// A sample scored: its place in the order samples came (pose ids need
/// not rise with time) and its pose.
type Scored = (u64, u64);

/// One CUSUM and where its current run began.
#[derive(Debug, Clone, Copy, Default)]
struct Cusum {
    sum: f64,
    /// The first sample of the run, and the first in it scoring
    /// [`CHANGED_FROM`] or more.
    began_at: Option<Scored>,
    changed_at: Option<Scored>,
}

impl Cusum {
    fn push(&mut self, pose: Scored, z: f64) {
        self.sum = (self.sum + z.min(CAP) - ALLOWANCE).max(0.0);
        if self.sum == 0.0 {
            self.began_at = None;
            self.changed_at = None;
            return;
        }
        self.began_at.get_or_insert(pose);
        if z >= CHANGED_FROM {
            self.changed_at.get_or_insert(pose);
        }
    }

    /// Where the change began: a run is often started a sample early by
    /// noise just above the allowance, so its first large score is taken.
    fn change_point(&self) -> Option<Scored> {
        self.changed_at.or(self.began_at)
    }

    fn alarmed(&self) -> bool {
        self.sum >= THRESHOLD
    }
}

/// Watches new samples against one calibration.
#[derive(Debug, Clone)]
pub struct DriftMonitor {
    /// The calibration watched.
    calibration: Calibration,
    /// The rig as the calibration corrected it.
    rig: Rig,
    /// Expected error variance per pixel coordinate, px^2.
    variance: f64,
    /// Mirror-view and direct-view CUSUMs, left and right camera.
    mirror: [Cusum; 2],
    direct: [Cusum; 2],
    /// Samples scored so far.
    scored: u64,
    /// The structured test (a moved plane, a turned camera).
    glr: glr::Glr,
    found: Option<Drift>,
}

impl DriftMonitor {
    /// A monitor for `cal` (made with `rig`), whose samples are expected to
    /// fit to its own residual noise, but not below `min_sigma_px` (the
    /// tracker's).
    pub fn new(rig: &Rig, cal: Calibration, min_sigma_px: f64) -> Self {
        let mut monitor = Self {
            rig: rig.clone(),
            calibration: cal,
            variance: 0.0,
            mirror: Default::default(),
            direct: Default::default(),
            scored: 0,
            glr: glr::Glr::default(),
            found: None,
        };
        monitor.watch(rig, monitor.calibration.clone(), min_sigma_px);
        monitor
    }

    /// Watches `cal`, a newer calibration of the same world (made with
    /// `rig`), from the next sample on; what the samples so far have
    /// added up is kept.
    pub fn watch(&mut self, rig: &Rig, cal: Calibration, min_sigma_px: f64) {
        let sigma = cal.uncertainty.residual_px.max(min_sigma_px);
        // A new sample also carries the calibration's own error: on
        // average a share p/m of the noise.
        let residuals = 4 * (cal.samples + cal.direct_samples);
        let share = cal.parameters as f64 / residuals.max(1) as f64;
        self.rig = cal.corrected_rig(rig);
        self.variance = sigma * sigma * (1.0 + share);
        self.calibration = cal;
    }

    /// Scores one new sample (of the calibration's first placement, or a
    /// direct view); returns the change once found (and again for every
    /// later sample). Direct views are scored only against a calibration
    /// that holds some: one made from mirror views alone predicts them to
    /// its encoder offsets' accuracy, not to the tracker's noise.
    pub fn push(&mut self, sample: &Sample) -> Option<&Drift> {
        if self.found.is_some() {
            return self.found.as_ref();
        }
        if sample.view == View::Direct && self.calibration.direct_samples == 0 {
            return None;
        }
        let seen = Seen {
            placement: 0,
            view: sample.view,
            joints: sample.joints.as_deref(),
            model_point: model_point(&self.rig, sample, None).ok(),
            pixels: &sample.pixels,
        };
        // A sample that cannot be scored says nothing.
        let errors = camera_errors(&self.calibration, &self.rig, &seen)?;
        let sums = match sample.view {
            View::Mirror => &mut self.mirror,
            View::Direct => &mut self.direct,
        };
        self.scored += 1;
        let at = (self.scored, sample.pose);
        for (k, e) in errors.iter().enumerate() {
            sums[k].push(at, e / (2.0 * self.variance));
        }
        // A small change that adds up over samples, named by the change
        // that explains it.
        if let Some(found) = self
            .glr
            .push(&self.calibration, &self.rig, &seen, self.variance, at)
        {
            self.found = Some(Drift {
                moved: match found.hypothesis {
                    glr::Hypothesis::Plane => Moved::Mirror,
                    glr::Hypothesis::Camera(k) => Moved::Camera(self.rig.names[k].clone()),
                },
                began_at_pose: found.began_at.1,
                found_at_pose: sample.pose,
            });
            return self.found.as_ref();
        }
        // The first camera whose errors add up: a moved mirror shows in
        // both cameras' mirror views, a knocked camera in its own only.
        let k = (0..2).find(|&k| self.mirror[k].alarmed() || self.direct[k].alarmed())?;
        let other = 1 - k;
        let raised = |c: &Cusum| c.sum > THRESHOLD / 3.0;
        let moved = if self.direct[k].alarmed() && raised(&self.direct[other]) {
            Moved::Head
        } else if self.mirror[k].alarmed() && raised(&self.mirror[other]) {
            Moved::Mirror
        } else {
            Moved::Camera(self.rig.names[k].clone())
        };
        let began_at_pose = self
            .mirror
            .iter()
            .chain(&self.direct)
            .filter(|c| c.alarmed())
            .filter_map(Cusum::change_point)
            .min()
            .map_or(sample.pose, |(_, pose)| pose);
        self.found = Some(Drift {
            moved,
            began_at_pose,
            found_at_pose: sample.pose,
        });
        self.found.as_ref()
    }
}
