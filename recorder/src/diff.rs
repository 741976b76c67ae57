//! `replay diff A B`: what differs between two recordings, channel by
//! channel. Messages are paired by their index within a channel (the order
//! they were published in). Frames and other large messages are compared by
//! a hash of their bytes, small ones byte for byte; the typed lossless
//! messages also say which fields differ and by how much (detection centres,
//! samples, calibrations, predictions, located objects, joint readings).

use std::collections::BTreeMap;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::Path;

use nalgebra::Vector3;
use serde::Serialize;

use crate::channels::{Message, TopicId};
use crate::reader::{ReadError, Recording};

/// Messages larger than this are kept as a hash only.
const HASH_ABOVE_BYTES: usize = 64 * 1024;

/// One message as kept for the comparison.
#[derive(Debug, Clone, PartialEq)]
struct Kept {
    log_time: u64,
    /// The bytes, or empty when only the hash is kept.
    bytes: Vec<u8>,
    hash: u64,
}

fn hash(bytes: &[u8]) -> u64 {
    let mut h = DefaultHasher::new();
    bytes.hash(&mut h);
    h.finish()
}

/// How far one numeric quantity moved between paired messages.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Delta {
    /// Pairs compared.
    pub count: usize,
    /// Largest difference.
    pub max: f64,
    /// Median difference.
    pub median: f64,
}

/// The first message pair that differs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FirstDifference {
    /// Its index in the channel.
    pub index: usize,
    /// Its stamp in A (the message stamp for typed messages, else the log time), ns.
    pub stamp_ns: i64,
    /// The fields that differ (`bytes` when the message is not typed).
    pub fields: Vec<String>,
}

/// One channel compared.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelDiff {
    /// Channel (topic) name.
    pub channel: String,
    /// Messages in A.
    pub count_a: usize,
    /// Messages in B.
    pub count_b: usize,
    /// Same count, every pair equal.
    pub identical: bool,
    /// Where they first differ, if they do within the shorter one.
    pub first_difference: Option<FirstDifference>,
    /// Numeric differences of typed messages, by quantity (unit in the name).
    pub deltas: BTreeMap<String, Delta>,
}

/// Why two recordings could not be compared.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DiffError {
    /// A file that cannot be read whole.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// `--channels` named a channel neither recording has.
    #[error("--channels: no channel `{missing}` in either recording (they have: {known})")]
    UnknownChannel {
        /// The channel asked for.
        missing: String,
        /// The channels there are.
        known: String,
    },
}

/// Two recordings compared.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiffReport {
    /// Path of A.
    pub a: String,
    /// Path of B.
    pub b: String,
    /// Every compared channel identical.
    pub identical: bool,
    /// Per channel, in name order.
    pub channels: Vec<ChannelDiff>,
    /// How each recording's calibrations went through the epochs of a
    /// changing world, A then B (empty where nothing changed).
    pub epochs: [Vec<EpochStep>; 2],
}

/// A calibration that changed the epoch or its state: where a change of
/// the world was found, where it was calibrated again, where it stopped.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpochStep {
    /// The calibration revision.
    pub revision: u64,
    /// Its epoch.
    pub epoch: u32,
    /// `calibrated`, `drifted` or `stopped`.
    pub state: String,
    /// What moved (`mirror`, `camera 0`, `camera 1`, `head`).
    pub moved: String,
    /// Where the change began (drifted) or the epoch began.
    pub began_at_pose: u64,
    /// Where the change was found.
    pub found_at_pose: u64,
}

/// The epoch steps of a recording's calibrations.
fn epoch_steps(calibrations: &[Kept]) -> Vec<EpochStep> {
    let mut steps: Vec<EpochStep> = Vec::new();
    let mut last = None;
    for k in calibrations {
        let Some(Message::Calibration(c)) = decode(Some(TopicId::Calibration), k) else {
            continue;
        };
        let e = c.epoch;
        if last == Some((e.epoch, e.state)) {
            continue;
        }
        last = Some((e.epoch, e.state));
        // The first epoch's calibrations, as every one before epochs were stated.
        if e.moved().is_none_or(|m| m == messages::Moved::Nothing) {
            continue;
        }
        steps.push(EpochStep {
            revision: c.revision,
            epoch: e.epoch,
            state: match e.state() {
                Some(messages::EpochState::Calibrated) => "calibrated",
                Some(messages::EpochState::Drifted) => "drifted",
                Some(messages::EpochState::Stopped) => "stopped",
                None => "unknown",
            }
            .into(),
            moved: match e.moved() {
                Some(messages::Moved::Mirror) => "mirror".into(),
                Some(messages::Moved::Camera) => format!("camera {}", e.camera),
                Some(messages::Moved::Head) => "head".into(),
                _ => String::new(),
            },
            began_at_pose: e.began_at_pose,
            found_at_pose: e.found_at_pose,
        });
    }
    steps
}

fn read_all(path: &Path) -> Result<BTreeMap<String, Vec<Kept>>, ReadError> {
    let recording = Recording::open(path)?;
    if let Some(d) = &recording.contents().damage {
        return Err(ReadError::new(
            path,
            format!(
                "damaged after {} messages ({}); a diff needs whole files",
                d.after_messages, d.error
            ),
        ));
    }
    let mut out: BTreeMap<String, Vec<Kept>> = BTreeMap::new();
    recording.for_each_raw(|topic, log_time, data| {
        let bytes = if data.len() > HASH_ABOVE_BYTES {
            Vec::new()
        } else {
            data.to_vec()
        };
        out.entry(topic.to_string()).or_default().push(Kept {
            log_time,
            bytes,
            hash: hash(data),
        });
    })?;
    Ok(out)
}

/// Compares the recordings at `a` and `b`, on `channels` only if given
/// (each must be in one of them at least).
pub fn diff(a: &Path, b: &Path, channels: Option<&[String]>) -> Result<DiffReport, DiffError> {
    let (ra, rb) = (read_all(a)?, read_all(b)?);
    let mut names: Vec<String> = ra.keys().chain(rb.keys()).cloned().collect();
    names.sort();
    names.dedup();
    if let Some(wanted) = channels {
        if let Some(missing) = wanted.iter().find(|w| !names.contains(w)) {
            return Err(DiffError::UnknownChannel {
                missing: missing.clone(),
                known: names.join(", "),
            });
        }
        names.retain(|n| wanted.contains(n));
    }
    let empty = Vec::new();
    let channels: Vec<ChannelDiff> = names
        .iter()
        .map(|name| {
            compare(
                name,
                ra.get(name).unwrap_or(&empty),
                rb.get(name).unwrap_or(&empty),
            )
        })
        .collect();
    let steps = |r: &BTreeMap<String, Vec<Kept>>| {
        epoch_steps(r.get(TopicId::Calibration.name()).unwrap_or(&empty))
    };
    Ok(DiffReport {
        a: a.display().to_string(),
        b: b.display().to_string(),
        identical: channels.iter().all(|c| c.identical),
        channels,
        epochs: [steps(&ra), steps(&rb)],
    })
}

fn decode(topic: Option<TopicId>, k: &Kept) -> Option<Message<'_>> {
    topic
        .filter(|_| !k.bytes.is_empty())
        .and_then(|t| Message::decode(t, &k.bytes).ok())
}

fn compare(name: &str, a: &[Kept], b: &[Kept]) -> ChannelDiff {
    let topic = TopicId::from_name(name);
    let mut first_difference = None;
    let mut deltas = Deltas::default();
    for (index, (x, y)) in a.iter().zip(b).enumerate() {
        let equal = x.hash == y.hash && x.bytes == y.bytes;
        let (mx, my) = (decode(topic, x), decode(topic, y));
        if let (Some(mx), Some(my)) = (&mx, &my) {
            deltas.add(mx, my);
        }
        if !equal && first_difference.is_none() {
            let fields = match (&mx, &my) {
                (Some(mx), Some(my)) => differing_fields(mx, my),
                _ => vec!["bytes".to_string()],
            };
            first_difference = Some(FirstDifference {
                index,
                stamp_ns: mx.map_or(x.log_time as i64, |m| m.stamp_ns()),
                fields,
            });
        }
    }
    ChannelDiff {
        channel: name.to_string(),
        count_a: a.len(),
        count_b: b.len(),
        identical: a.len() == b.len() && first_difference.is_none(),
        first_difference,
        deltas: deltas.summaries(),
    }
}

/// Named numeric fields of a typed message, for saying which differ.
fn fields(m: &Message<'_>) -> Vec<(&'static str, Vec<f64>)> {
    let f = |v: &[f64]| v.to_vec();
    let u = |v: u64| vec![v as f64];
    let i = |v: i64| vec![v as f64];
    match m {
        Message::Frames(h, pixels) => vec![
            ("seq", u(h.seq)),
            ("stamp_ns", i(h.stamp_ns)),
            ("published_ns", i(h.published_ns)),
            (
                "size",
                vec![f64::from(h.width), f64::from(h.height), f64::from(h.stride)],
            ),
            ("encoding", u(u64::from(h.encoding))),
            ("pixels", u(hash(pixels))),
        ],
        Message::Detections(d) => {
            let mut out = vec![
                ("seq", u(d.seq)),
                ("stamp_ns", i(d.stamp_ns)),
                ("frame_published_ns", i(d.frame_published_ns)),
            ];
            const SIDES: [[&str; 3]; 2] = [
                ["left.markers", "left.centres", "left.corners"],
                ["right.markers", "right.centres", "right.corners"],
            ];
            for (c, [markers, centres_name, corners_name]) in d.cameras.iter().zip(SIDES) {
                let ids: Vec<f64> = c
                    .iter()
                    .flat_map(|m| [f64::from(m.id), f64::from(m.mirrored)])
                    .collect();
                let centres: Vec<f64> = c.iter().flat_map(|m| m.center).collect();
                let corners: Vec<f64> = c.iter().flat_map(|m| m.corners).collect();
                out.extend([
                    (markers, ids),
                    (centres_name, centres),
                    (corners_name, corners),
                ]);
            }
            out
        }
        Message::JointState(j) => vec![
            ("seq", u(j.seq)),
            ("stamp_ns", i(j.stamp_ns)),
            ("pose", u(j.pose)),
            ("phase", u(u64::from(j.phase))),
            ("role", u(u64::from(j.role))),
            ("q", f(j.joints())),
            ("model_point", f(&j.model_point)),
        ],
        Message::Samples(s) => vec![
            ("pose", u(s.pose)),
            ("stamp_ns", i(s.stamp_ns)),
            ("role", u(u64::from(s.role))),
            ("q", f(&s.q[..(s.dof as usize).min(s.q.len())])),
            ("model_point", f(&s.model_point)),
            ("pixels", s.pixels.iter().flatten().copied().collect()),
            ("triangulated", f(&s.triangulated)),
        ],
        Message::Calibration(c) => vec![
            ("stamp_ns", i(c.stamp_ns)),
            ("revision", u(c.revision)),
            ("method", u(u64::from(c.method))),
            ("samples", u(u64::from(c.samples))),
            (
                "plane",
                if c.has_plane != 0 {
                    f(&c.plane)
                } else {
                    vec![]
                },
            ),
            (
                "cameras",
                c.cameras
                    .iter()
                    .flat_map(|p| p.camera_from_world.into_iter().chain(p.center))
                    .collect(),
            ),
            (
                "joint_offsets",
                f(&c.joint_offsets[..(c.dof as usize).min(c.joint_offsets.len())]),
            ),
            ("train_rms_px", vec![c.train_rms_px]),
            ("epoch", {
                let e = &c.epoch;
                vec![
                    f64::from(e.epoch),
                    f64::from(e.state),
                    f64::from(e.moved),
                    f64::from(e.camera),
                    e.began_at_pose as f64,
                    e.found_at_pose as f64,
                ]
            }),
            ("uncertainty", {
                let u = &c.uncertainty;
                let mut v = vec![u.residual_px, u.plane_angle_deg, u.plane_distance_mm];
                v.extend_from_slice(
                    &u.joint_offsets_deg[..(u.dof as usize).min(u.joint_offsets_deg.len())],
                );
                v.extend(u.mirror_camera_centers_mm);
                v.extend(u.mirror_camera_angles_deg);
                v
            }),
        ],
        Message::Predictions(p) => vec![
            ("pose", u(p.pose)),
            ("stamp_ns", i(p.stamp_ns)),
            ("revision", u(p.revision)),
            ("model_point", f(&p.model_point)),
            ("reconstructed", f(&p.reconstructed)),
            (
                "predicted_pixels",
                p.predicted_pixels.iter().flatten().copied().collect(),
            ),
            ("error_mm", vec![p.error_mm]),
            ("error_px", vec![p.error_px]),
        ],
        Message::Located(l) => vec![
            ("stamp_ns", i(l.stamp_ns)),
            ("revision", u(l.revision)),
            ("id", u(u64::from(l.id))),
            ("position", f(&l.position)),
            ("covariance_mm2", f(&l.covariance_mm2)),
        ],
        Message::JointPositions(p) => vec![
            ("seq", u(p.seq)),
            ("stamp_ns", i(p.stamp_ns)),
            ("q", f(p.joints())),
        ],
        Message::PoseGoal(g) => vec![
            ("seq", u(g.seq)),
            ("stamp_ns", i(g.stamp_ns)),
            ("pose", u(g.pose)),
            ("role", u(u64::from(g.role))),
            ("flags", u(u64::from(g.flags))),
            ("q", f(g.joints())),
        ],
        // A topic given no named fields here is still compared, as a whole:
        // adding a topic to the table needs no arm in this match.
        #[allow(unreachable_patterns)]
        other => vec![("bytes", u(hash(&other.to_bytes())))],
    }
}

fn differing_fields(a: &Message<'_>, b: &Message<'_>) -> Vec<String> {
    let (fa, fb) = (fields(a), fields(b));
    let named: Vec<String> = fa
        .iter()
        .zip(&fb)
        // Compared bit for bit, so that NaN equals NaN and -0 differs from 0.
        .filter(|((_, x), (_, y))| {
            x.len() != y.len() || x.iter().zip(y).any(|(p, q)| p.to_bits() != q.to_bits())
        })
        .map(|((name, _), _)| name.to_string())
        .collect();
    if named.is_empty() {
        // Only bytes no field names (padding, an unused tail of an array).
        vec!["unnamed bytes".into()]
    } else {
        named
    }
}

/// The numeric differences collected over a channel's pairs.
#[derive(Default)]
struct Deltas(BTreeMap<&'static str, Vec<f64>>);

impl Deltas {
    fn push(&mut self, name: &'static str, d: f64) {
        if d.is_finite() {
            self.0.entry(name).or_default().push(d);
        }
    }

    fn add(&mut self, a: &Message<'_>, b: &Message<'_>) {
        let v3 = |p: &[f64; 3]| Vector3::from(*p);
        let px =
            |p: &[f64; 2], q: &[f64; 2]| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
        match (a, b) {
            (Message::Detections(x), Message::Detections(y)) => {
                for k in 0..2 {
                    for m in x.cameras[k].iter() {
                        if let Some(n) = y.cameras[k].find(m.id, m.mirrored != 0) {
                            self.push("centre_px", px(&m.center, &n.center));
                        }
                    }
                }
            }
            (Message::Samples(x), Message::Samples(y)) => {
                for k in 0..2 {
                    self.push("pixels_px", px(&x.pixels[k], &y.pixels[k]));
                }
                self.push(
                    "triangulated_mm",
                    (v3(&x.triangulated) - v3(&y.triangulated)).norm(),
                );
                self.push(
                    "model_point_mm",
                    (v3(&x.model_point) - v3(&y.model_point)).norm(),
                );
            }
            (Message::Calibration(x), Message::Calibration(y)) => {
                if x.has_plane != 0 && y.has_plane != 0 {
                    let (n, m) = (
                        Vector3::new(x.plane[0], x.plane[1], x.plane[2]),
                        Vector3::new(y.plane[0], y.plane[1], y.plane[2]),
                    );
                    self.push("plane_angle_deg", n.angle(&m).to_degrees());
                    self.push("plane_distance_mm", (x.plane[3] - y.plane[3]).abs());
                }
                for k in 0..2 {
                    self.push(
                        "mirror_camera_centre_mm",
                        (v3(&x.cameras[k].center) - v3(&y.cameras[k].center)).norm(),
                    );
                }
                self.push("train_rms_px", (x.train_rms_px - y.train_rms_px).abs());
                let (a, b) = (x.uncertainty, y.uncertainty);
                if a.stated != 0 && b.stated != 0 {
                    self.push(
                        "sigma_plane_angle_deg",
                        (a.plane_angle_deg - b.plane_angle_deg).abs(),
                    );
                }
            }
            (Message::Predictions(x), Message::Predictions(y)) => {
                self.push(
                    "reconstructed_mm",
                    (v3(&x.reconstructed) - v3(&y.reconstructed)).norm(),
                );
                self.push(
                    "model_point_mm",
                    (v3(&x.model_point) - v3(&y.model_point)).norm(),
                );
                for k in 0..2 {
                    self.push(
                        "predicted_px",
                        px(&x.predicted_pixels[k], &y.predicted_pixels[k]),
                    );
                }
            }
            (Message::Located(x), Message::Located(y)) => {
                self.push("position_mm", (v3(&x.position) - v3(&y.position)).norm());
                self.push("sigma_mm", (x.sigma_mm() - y.sigma_mm()).abs());
            }
            (Message::JointState(x), Message::JointState(y)) => {
                let dq = x
                    .joints()
                    .iter()
                    .zip(y.joints())
                    .map(|(p, q)| (p - q).abs())
                    .fold(0.0, f64::max);
                self.push("q", dq);
                self.push(
                    "model_point_mm",
                    (v3(&x.model_point) - v3(&y.model_point)).norm(),
                );
            }
            _ => {}
        }
    }

    fn summaries(self) -> BTreeMap<String, Delta> {
        self.0
            .into_iter()
            .map(|(name, mut v)| {
                v.sort_by(f64::total_cmp);
                let delta = Delta {
                    count: v.len(),
                    max: v.last().copied().unwrap_or(0.0),
                    median: v[v.len() / 2],
                };
                (name.to_string(), delta)
            })
            .collect()
    }
}

/// The report as a table, one line per channel.
pub fn table(report: &DiffReport) -> String {
    let mut s = format!("A: {}\nB: {}\n", report.a, report.b);
    s += &format!("{:<28} {:>8} {:>8}  result\n", "channel", "A", "B");
    for c in &report.channels {
        let result = match (&c.first_difference, c.identical) {
            (_, true) => "identical".to_string(),
            (None, false) => "counts differ; the common messages are equal".to_string(),
            (Some(d), false) => format!(
                "message {} (stamp {} ns) differs in: {}",
                d.index,
                d.stamp_ns,
                d.fields.join(", ")
            ),
        };
        s += &format!(
            "{:<28} {:>8} {:>8}  {result}\n",
            c.channel, c.count_a, c.count_b
        );
        if !c.identical {
            for (name, d) in &c.deltas {
                if d.max > 0.0 {
                    s += &format!(
                        "{:<28} {:>8} {:>8}    {name}: max {:.6}, median {:.6} over {} pairs\n",
                        "", "", "", d.max, d.median, d.count
                    );
                }
            }
        }
    }
    for (name, steps) in ["A", "B"].iter().zip(&report.epochs) {
        for e in steps {
            let what = match e.state.as_str() {
                "drifted" => format!(
                    "the world changed: the {} moved from pose {} (found at pose {})",
                    e.moved, e.began_at_pose, e.found_at_pose
                ),
                "stopped" => format!("calibration stopped after the {} moved", e.moved),
                _ => format!(
                    "epoch {} calibrated, from pose {} (after the {} moved)",
                    e.epoch, e.began_at_pose, e.moved
                ),
            };
            s += &format!("epochs {name}: revision {}: {what}\n", e.revision);
        }
    }
    if report.epochs[0] != report.epochs[1] {
        s += "epochs differ between A and B\n";
    }
    let differing = report.channels.iter().filter(|c| !c.identical).count();
    s += &if differing == 0 {
        format!("identical: {} channels\n", report.channels.len())
    } else {
        format!("{differing} of {} channels differ\n", report.channels.len())
    };
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::{CalibrationMsg, CameraMarkers, Marker, StereoDetections};

    fn detections(x: f64) -> StereoDetections {
        let mut c = CameraMarkers::default();
        c.push(Marker {
            id: 3,
            mirrored: 1,
            corners: [0.0; 8],
            center: [x, 20.0],
        });
        StereoDetections {
            seq: 1,
            stamp_ns: 5,
            frame_published_ns: 6,
            cameras: [c, CameraMarkers::default()],
        }
    }

    #[test]
    fn fields_and_deltas_name_what_moved_and_by_how_much() {
        let (a, b) = (detections(10.0), detections(10.5));
        let (ma, mb) = (Message::Detections(a), Message::Detections(b));
        assert_eq!(differing_fields(&ma, &mb), ["left.centres"]);
        let mut d = Deltas::default();
        d.add(&ma, &mb);
        assert_eq!(d.summaries()["centre_px"].max, 0.5);

        let plane = |nz: f64, dist: f64| CalibrationMsg {
            has_plane: 1,
            plane: [0.0, (1.0 - nz * nz).sqrt(), nz, dist],
            ..Default::default()
        };
        let (ca, cb) = (plane(1.0, 500.0), plane(0.5f64.to_radians().cos(), 502.0));
        let (ma, mb) = (Message::Calibration(ca), Message::Calibration(cb));
        assert_eq!(differing_fields(&ma, &mb), ["plane"]);
        let mut d = Deltas::default();
        d.add(&ma, &mb);
        let s = d.summaries();
        assert!((s["plane_angle_deg"].max - 0.5).abs() < 1e-9, "{s:?}");
        assert_eq!(s["plane_distance_mm"].max, 2.0);
        assert_eq!(s["mirror_camera_centre_mm"].max, 0.0);
    }
}
