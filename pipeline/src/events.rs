//! Changes of the simulated world during a run (`[[event]]` in
//! `pipeline.toml`): the mirror bumped, a head camera knocked. The camera
//! stage renders the changed world from the event's pose on, the plan is
//! extended so that every change is followed by enough poses to find it and
//! calibrate again, and the truth the run is scored against follows it.
//!
//! ```toml
//! [[event]]
//! at_pose = 40                                   # the plan's 41st pose, counting from 0
//! mirror = { tilt_deg = 1.0, shift_mm = 5.0 }    # turned about its width axis, moved towards the robot
//!
//! [[event]]
//! at_pose = 70
//! camera = { name = "left", rotate_deg = 0.3 }   # about its pan axis; axis = "tilt" or "roll" for others
//! placement = 0                                  # only in this placement (absent: every one)
//! ```

use std::path::Path;

use anyhow::{Result, bail};
use formats::plan::PlannedPose;
use geometry::Role;
use geometry::sim::{Counts, SimWorld, WorldChange, generate, nico_noise, nico_scene};
use serde::{Deserialize, Serialize};
use stages::camera::{CameraAxis, Change, ChangeAt};

/// Calibration poses after each change: enough to calibrate the moved
/// mirror again (the drift watch needs a few, the new epoch 15).
pub const TRAIN_AFTER: usize = 20;
/// Direct views after each change: enough to find a knocked camera again.
pub const DIRECT_AFTER: usize = mirror_proc::epochs::CAMERA_VIEWS;

/// Pose ids of the poses the plan is extended with: calibration poses
/// from the first, direct views from the second (the simulator numbers
/// its own from 0, 10000 and 20000).
const EXTRA_IDS: [u64; 2] = [30_000, 40_000];

/// One change of the world.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Event {
    /// The plan's pose (counting from 0) from whose goal on the world is
    /// changed.
    pub at_pose: usize,
    /// Only in this mirror placement; absent: in every one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placement: Option<usize>,
    /// The mirror turns and moves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mirror: Option<MirrorEvent>,
    /// A head camera is knocked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraEvent>,
}

/// The mirror turns about its width axis, then moves along its normal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MirrorEvent {
    /// Turn, degrees.
    #[serde(default)]
    pub tilt_deg: f64,
    /// Shift towards the robot, mm (negative: away).
    #[serde(default)]
    pub shift_mm: f64,
}

/// A head camera turns about one of its own axes, its centre kept.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraEvent {
    /// The rig's name of the camera.
    pub name: String,
    /// Turn, degrees.
    pub rotate_deg: f64,
    /// `pan` (default), `tilt` or `roll`.
    #[serde(default)]
    pub axis: CameraAxis,
}

impl Event {
    fn change(&self, names: &[String; 2]) -> Option<Change> {
        match (&self.mirror, &self.camera) {
            (Some(m), None) => Some(Change::Mirror {
                tilt_deg: m.tilt_deg,
                shift_mm: m.shift_mm,
            }),
            (None, Some(c)) => Some(Change::Camera {
                camera: names.iter().position(|n| *n == c.name)?,
                rotate_deg: c.rotate_deg,
                axis: c.axis,
            }),
            _ => None,
        }
    }

    fn applies_to(&self, placement: usize) -> bool {
        self.placement.is_none_or(|p| p == placement)
    }
}

/// The rig's camera names in the simulated scene.
fn camera_names() -> [String; 2] {
    nico_scene().rig.names
}

/// Checks `events` from the config at `path`: each one change, a camera
/// the rig has, in plan order, finite.
pub fn check(path: &Path, events: &[Event], placements: usize) -> Result<()> {
    let names = camera_names();
    let mut last = 0;
    for (i, e) in events.iter().enumerate() {
        let key = format!(
            "{}: event {} (at_pose {})",
            path.display(),
            i + 1,
            e.at_pose
        );
        match (&e.mirror, &e.camera) {
            (Some(_), Some(_)) | (None, None) => {
                bail!("{key}: give one of mirror = {{ ... }} or camera = {{ ... }}")
            }
            (Some(m), None) if !(m.tilt_deg.is_finite() && m.shift_mm.is_finite()) => {
                bail!("{key}: mirror tilt_deg and shift_mm must be finite")
            }
            (None, Some(c)) if !names.contains(&c.name) => bail!(
                "{key}: camera {:?} is not one of the rig's ({} and {})",
                c.name,
                names[0],
                names[1]
            ),
            (None, Some(c)) if !c.rotate_deg.is_finite() => {
                bail!("{key}: camera rotate_deg must be finite")
            }
            _ => {}
        }
        if e.at_pose == 0 {
            bail!("{key}: at_pose 0 changes the world before anything is calibrated in it");
        }
        if e.at_pose < last {
            bail!("{key}: events go in plan order (the one before is at pose {last})");
        }
        if let Some(p) = e.placement.filter(|p| *p >= placements) {
            bail!(
                "{key}: placement {p} does not exist (0..={})",
                placements - 1
            );
        }
        last = e.at_pose;
    }
    Ok(())
}

/// The events of `placement`.
pub fn of_placement(events: &[Event], placement: usize) -> Vec<&Event> {
    events.iter().filter(|e| e.applies_to(placement)).collect()
}

/// Extends `plan` (of placement `mirror`, seeded `seed`) so that every
/// event of it is followed by [`TRAIN_AFTER`] calibration poses and
/// [`DIRECT_AFTER`] direct views, two calibration poses to one direct view.
pub fn extend_plan(
    plan: &mut Vec<PlannedPose>,
    events: &[&Event],
    mirror: usize,
    seed: u64,
) -> Result<()> {
    let Some(last) = events.iter().map(|e| e.at_pose).max() else {
        return Ok(());
    };
    let enough = |plan: &[PlannedPose]| {
        let after = plan.get(last..).unwrap_or_default();
        let count = |role| after.iter().filter(|p| p.role == role).count();
        count(Role::Train) >= TRAIN_AFTER && count(Role::Direct) >= DIRECT_AFTER
    };
    if enough(plan) {
        return Ok(());
    }
    // At most: up to the last event, then what follows it.
    let most = last.saturating_sub(plan.len()) + TRAIN_AFTER + DIRECT_AFTER;
    let counts = Counts {
        train: most,
        test: 0,
        direct: most,
    };
    // Drawn apart from the plan's own poses, which stay as they were.
    let extra = generate(
        &nico_scene(),
        mirror,
        &nico_noise(),
        counts,
        seed.wrapping_add(0x5eed),
    )?;
    let planned = |s: &geometry::Sample, role: Role, ids: u64| PlannedPose {
        pose: ids + s.pose % 10_000,
        role,
        q: s.joints.clone().unwrap_or_default(),
    };
    let mut train = extra
        .train
        .iter()
        .map(|s| planned(s, Role::Train, EXTRA_IDS[0]));
    let mut direct = extra
        .direct
        .iter()
        .map(|s| planned(s, Role::Direct, EXTRA_IDS[1]));
    while !enough(plan) {
        let next = if plan.len() % 3 == 2 {
            direct.next()
        } else {
            train.next()
        };
        match next {
            Some(p) => plan.push(p),
            None => bail!("could not extend the plan of mirror {mirror} for its events"),
        }
    }
    Ok(())
}

/// The camera stage's changes for `events` on `plan`.
pub fn changes(events: &[&Event], plan: &[PlannedPose]) -> Vec<ChangeAt> {
    let names = camera_names();
    events
        .iter()
        .filter_map(|e| {
            Some(ChangeAt {
                pose: plan.get(e.at_pose)?.pose,
                change: e.change(&names)?,
            })
        })
        .collect()
}

/// The world of `mirror` as it is from each event on: `(first pose id,
/// world)`, the unchanged world first (from pose id `None`).
pub fn worlds(
    events: &[&Event],
    plan: &[PlannedPose],
    mirror: usize,
) -> Result<Vec<(Option<u64>, SimWorld)>> {
    let mut worlds = vec![(None, SimWorld::nico(mirror)?)];
    for c in changes(events, plan) {
        let change = WorldChange::from(c.change);
        let next = worlds[worlds.len() - 1].1.changed(&change)?;
        worlds.push((Some(c.pose), next));
    }
    Ok(worlds)
}

/// Each epoch of `report` against the world of its time: the world in
/// force where the change that began it was found (the first's: the
/// world at the start). A change made within an epoch that no later epoch
/// began from went unnoticed: it is named in that epoch's truth.
pub fn epoch_truths(
    report: &mirror_proc::live::LiveReport,
    worlds: &[(Option<u64>, SimWorld)],
    plan: &[PlannedPose],
) -> Vec<crate::report::EpochTruth> {
    let index = |id: u64| plan.iter().position(|p| p.pose == id);
    let mut truths: Vec<crate::report::EpochTruth> = report
        .epochs
        .iter()
        .map(|e| {
            let at = e
                .found_at_pose
                .unwrap_or(plan.first().map_or(0, |p| p.pose));
            let (changed_at_pose, world) = worlds
                .iter()
                .rev()
                .find(|(from, _)| {
                    from.is_none_or(|f| index(f).zip(index(at)).is_some_and(|(f, a)| f <= a))
                })
                .map_or((None, &worlds[0].1), |(from, w)| (*from, w));
            let found_after_poses = e
                .found_at_pose
                .and_then(index)
                .zip(changed_at_pose.and_then(index))
                .map(|(found, changed)| found + 1 - changed.min(found));
            crate::report::EpochTruth {
                epoch: e.epoch,
                changed_at_pose,
                after: e.after.clone(),
                began_at_pose: e.began_at_pose,
                found_at_pose: e.found_at_pose,
                found_after_poses,
                unnoticed_changes: Vec::new(),
                truth: crate::report::TruthErrors::of_calibration(e.calibration.as_ref(), world),
            }
        })
        .collect();
    let claimed: Vec<u64> = truths.iter().filter_map(|t| t.changed_at_pose).collect();
    let starts: Vec<usize> = truths
        .iter()
        .map(|t| t.changed_at_pose.and_then(index).unwrap_or(0))
        .collect();
    for (i, t) in truths.iter_mut().enumerate() {
        let end = starts.get(i + 1).copied().unwrap_or(plan.len());
        t.unnoticed_changes = worlds
            .iter()
            .filter_map(|(from, _)| *from)
            .filter(|f| !claimed.contains(f))
            .filter(|&f| index(f).is_some_and(|at| at > starts[i] && at < end))
            .collect();
    }
    truths
}
