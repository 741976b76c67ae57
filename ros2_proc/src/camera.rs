//! A stereo camera on a ROS 2 graph as our camera stage: two
//! `sensor_msgs/Image` topics, paired by header stamp, each pair written
//! once into a frame in shared memory. Also the camera's `CameraInfo` as a
//! calibration file the rig reads ([`camera_info_yaml`]).

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use messages::{Encoding, FrameHeader, now_ns, topics};
use runtime::BusError;
use runtime::stats::StageStats;
use stages::ros2::Ros2Camera;
use zenoh::sample::Sample;

use crate::clock;
use crate::image::{ImageError, ImageView, Pieces, write_mono};
use crate::msgs::{CameraInfo, Image};
use crate::node::{Node, Refusal, Ros2Error};
use crate::wire::Qos;

/// What stops the camera stage.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The pipeline's bus.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The graph.
    #[error(transparent)]
    Ros2(#[from] Ros2Error),
    /// The images come from a graph we cannot speak to.
    #[error(transparent)]
    Unsupported(Refusal),
}

/// The two image topics and how to pair them.
#[derive(Debug, Clone)]
pub struct CameraOptions {
    /// The pipeline's prefix.
    pub prefix: String,
    /// The left camera's image topic.
    pub left: String,
    /// The right camera's.
    pub right: String,
    /// Two images are a pair when their stamps differ by at most this, ns.
    pub tolerance_ns: i64,
}

/// Left or right.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Eye {
    /// The first camera of the rig.
    Left = 0,
    /// The second.
    Right = 1,
}

/// Pairs left and right items by stamp: an item pairs with the other
/// side's waiting item nearest in time, if within the tolerance; then
/// everything older than the pair on either side can no longer pair and is
/// dropped and counted. Each side keeps at most [`Pairer::WAITING`].
#[derive(Debug)]
pub struct Pairer<T> {
    tolerance_ns: i64,
    waiting: [VecDeque<(i64, T)>; 2],
    unpaired: u64,
}

impl<T> Pairer<T> {
    /// Items a side keeps waiting for their partner.
    pub const WAITING: usize = 4;

    /// A pairer with `tolerance_ns`.
    pub fn new(tolerance_ns: i64) -> Self {
        Pairer {
            tolerance_ns,
            waiting: [VecDeque::new(), VecDeque::new()],
            unpaired: 0,
        }
    }

    /// Takes `item` of `eye` stamped `stamp`; returns a pair (left, right)
    /// and the left's stamp when it completes one.
    pub fn push(&mut self, eye: Eye, stamp: i64, item: T) -> Option<(i64, T, T)> {
        let other = 1 - eye as usize;
        let nearest = self.waiting[other]
            .iter()
            .enumerate()
            .map(|(i, (s, _))| (i, (s - stamp).abs()))
            .min_by_key(|&(_, d)| d)
            .filter(|&(_, d)| d <= self.tolerance_ns);
        let Some((i, _)) = nearest else {
            let mine = &mut self.waiting[eye as usize];
            mine.push_back((stamp, item));
            if mine.len() > Self::WAITING {
                mine.pop_front();
                self.unpaired += 1;
            }
            return None;
        };
        // Older than the partner: their partners have passed.
        self.unpaired += i as u64;
        let (partner_stamp, partner) = self.waiting[other].drain(..=i).last()?;
        let first = stamp.min(partner_stamp);
        let mine = &mut self.waiting[eye as usize];
        let before = mine.len();
        mine.retain(|(s, _)| *s > first);
        self.unpaired += (before - mine.len()) as u64;
        Some(match eye {
            Eye::Left => (stamp, item, partner),
            Eye::Right => (partner_stamp, partner, item),
        })
    }

    /// Items dropped without a partner so far.
    pub fn unpaired(&self) -> u64 {
        self.unpaired
    }

    /// Items waiting now.
    pub fn waiting(&self) -> usize {
        self.waiting[0].len() + self.waiting[1].len()
    }
}

/// A ROS stamp further than this from our receive time is taken for a
/// clock that is not synchronised, and replaced by the receive time.
const MAX_STAMP_SKEW_NS: i64 = 1_000_000_000;

/// Samples waiting between zenoh's receiving thread and ours.
const QUEUE: usize = 8;

/// When the image topics have been silent this long, say so (once).
const SILENT_WARNING: Duration = Duration::from_secs(3);

/// The counters the stage reports.
const COUNTERS: [&str; 9] = [
    "images",
    "pairs",
    "images_unpaired",
    "images_unsupported_encoding",
    "images_wrong_size",
    "images_malformed",
    "images_other_hash",
    "images_dropped_behind",
    "frames_restamped",
];

/// A received image: the sample that holds its payload, and what was read
/// of it on arrival.
struct Arrived {
    sample: Sample,
    received_ns: i64,
}

/// The image in a sample that was read on arrival.
fn view_of(arrived: &Arrived) -> ImageView<'_> {
    ImageView::parse_pieces(Pieces::new(arrived.sample.payload().slices()))
        .expect("read on arrival")
}

/// Runs until SIGINT/SIGTERM: pairs the two topics' images and publishes
/// each pair as a mono8 frame. The first pair sets the frame size; an image
/// of another size, an unsupported encoding or a malformed payload is
/// counted and named once, and the stage goes on.
pub fn run(node: &Node, options: &CameraOptions) -> Result<(), CameraError> {
    let (tx, rx) = crossbeam_channel::bounded::<(Eye, Sample)>(QUEUE);
    let dropped = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    // Camera drivers publish images best effort (`SensorDataQoS`).
    let qos = Qos {
        reliable: false,
        transient_local: false,
        depth: 5,
    };
    let mut subscriptions = Vec::new();
    for (eye, topic) in [(Eye::Left, &options.left), (Eye::Right, &options.right)] {
        let tx = tx.clone();
        let dropped = dropped.clone();
        subscriptions.push(node.subscribe_raw::<Image>(topic, qos, move |sample| {
            if tx.try_send((eye, sample)).is_err() {
                dropped.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
        })?);
    }
    drop(tx);
    let admissions = [subscriptions[0].1.clone(), subscriptions[1].1.clone()];

    let bus = stages::bus_of::<Ros2Camera>(&options.prefix)?;
    let mut frames = None;
    let mut size: Option<(u32, u32)> = None;
    let mut pairer = Pairer::<Arrived>::new(options.tolerance_ns);
    let mut counts: BTreeMap<&'static str, u64> = COUNTERS.iter().map(|&k| (k, 0)).collect();
    let mut named: BTreeSet<String> = BTreeSet::new();
    let mut warn_once = |line: String| {
        if named.insert(line.clone()) {
            tracing::warn!("{line}");
        }
    };
    let mut stats = StageStats::new("ros2_camera");
    let (mut seq, mut last_heard, started) = (0u64, None::<Instant>, Instant::now());
    let mut warned_silent = false;
    loop {
        if !bus.sleep(Duration::ZERO) {
            break;
        }
        let (eye, sample) = match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(got) => got,
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                if !warned_silent && last_heard.unwrap_or(started).elapsed() > SILENT_WARNING {
                    warned_silent = true;
                    tracing::warn!(
                        "no images on {} and {} from {} for {} s; still waiting (is the camera driver running on rmw_zenoh in the same domain?)",
                        admissions[0].topic(),
                        admissions[1].topic(),
                        node.endpoint(),
                        SILENT_WARNING.as_secs()
                    );
                }
                continue;
            }
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        };
        let received_ns = now_ns();
        last_heard = Some(Instant::now());
        let admission = &admissions[eye as usize];
        let count = |counts: &mut BTreeMap<&'static str, u64>, key| {
            *counts.get_mut(key).expect("counter") += 1
        };
        count(&mut counts, "images");
        let stamp = match admission.check(&sample) {
            Ok(_) => match ImageView::parse_pieces(Pieces::new(sample.payload().slices())) {
                Ok(view) => view.header.stamp.ns(),
                Err(e) => {
                    count(&mut counts, "images_malformed");
                    warn_once(format!("{}: {e}", admission.topic()));
                    continue;
                }
            },
            Err(refusal @ Refusal::Humble { .. }) => return Err(CameraError::Unsupported(refusal)),
            Err(refusal @ Refusal::OtherHash { .. }) => {
                count(&mut counts, "images_other_hash");
                warn_once(refusal.to_string());
                continue;
            }
            Err(refusal @ Refusal::Wire { .. }) => {
                count(&mut counts, "images_malformed");
                warn_once(refusal.to_string());
                continue;
            }
        };
        let Some((stamp, left, right)) = pairer.push(
            eye,
            stamp,
            Arrived {
                sample,
                received_ns,
            },
        ) else {
            continue;
        };
        let (lv, rv) = (view_of(&left), view_of(&right));
        let checked = lv.format().and_then(|lf| {
            let rf = rv.format()?;
            let (w, h) = *size.get_or_insert((lv.width, lv.height));
            for v in [&lv, &rv] {
                if (v.width, v.height) != (w, h) {
                    return Err(ImageError::Size {
                        width: v.width,
                        height: v.height,
                        frame_width: w,
                        frame_height: h,
                    });
                }
            }
            Ok((lf, rf, w, h))
        });
        let (lf, rf, w, h) = match checked {
            Ok(ok) => ok,
            Err(e) => {
                count(
                    &mut counts,
                    match e {
                        ImageError::Encoding(_) => "images_unsupported_encoding",
                        ImageError::Size { .. } => "images_wrong_size",
                        ImageError::Bytes { .. } => "images_malformed",
                    },
                );
                warn_once(format!(
                    "{} / {}: {e}; such pairs are counted and dropped",
                    admissions[0].topic(),
                    admissions[1].topic()
                ));
                continue;
            }
        };
        let frames = match &mut frames {
            Some(f) => f,
            None => {
                tracing::info!(width = w, height = h, "first pair: publishing frames");
                frames.insert(bus.frame_publisher::<topics::Frames>(2 * (w * h) as usize)?)
            }
        };
        let mapped = clock::to_monotonic(stamp);
        let stamp_ns = if stamp == 0 || (mapped - left.received_ns).abs() > MAX_STAMP_SKEW_NS {
            count(&mut counts, "frames_restamped");
            warn_once(format!(
                "{}: image stamps are zero or more than 1 s from this host's clock; the receive time is used (synchronise the clocks)",
                admissions[0].topic()
            ));
            left.received_ns.min(right.received_ns)
        } else {
            mapped
        };
        let header = FrameHeader {
            seq,
            stamp_ns,
            published_ns: 0,
            width: w,
            height: h,
            stride: w,
            encoding: Encoding::Mono8 as u32,
        };
        let cpu = runtime::stats::StepStart::now();
        frames
            .publish(header, |l, r| {
                write_mono(&lv, lf, l);
                write_mono(&rv, rf, r);
                Ok::<_, std::convert::Infallible>(true)
            })?
            .unwrap_or_else(|never| match never {});
        stats.cpu_step(cpu);
        stats.record(
            "receive_to_publish",
            now_ns() - right.received_ns.max(left.received_ns),
        );
        count(&mut counts, "pairs");
        seq += 1;
    }
    counts.insert(
        "images_unpaired",
        pairer.unpaired() + pairer.waiting() as u64,
    );
    counts.insert(
        "images_dropped_behind",
        dropped.load(std::sync::atomic::Ordering::Relaxed),
    );
    for (name, n) in counts {
        stats.count(name, n);
    }
    stats.finish();
    tracing::info!(frames = seq, "stopped");
    Ok(())
}

/// A `CameraInfo` as the ROS `camera_info` YAML that `camera_calibration`
/// writes and the rig's `calibration = FILE` reads (`K`, `D`, `R`, `P`,
/// size, model; binning and ROI are not part of that file).
pub fn camera_info_yaml(name: &str, info: &CameraInfo) -> String {
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!(
        "image_width: {}\nimage_height: {}\ncamera_name: {name}\n\
         camera_matrix:\n  rows: 3\n  cols: 3\n  data: [{}]\n\
         distortion_model: {}\n\
         distortion_coefficients:\n  rows: 1\n  cols: {}\n  data: [{}]\n\
         rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [{}]\n\
         projection_matrix:\n  rows: 3\n  cols: 4\n  data: [{}]\n",
        info.width,
        info.height,
        list(&info.k),
        info.distortion_model,
        info.d.len(),
        list(&info.d),
        list(&info.r),
        list(&info.p),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_form_by_nearest_stamp_within_the_tolerance() {
        let mut p = Pairer::new(5);
        assert_eq!(p.push(Eye::Left, 100, "l100"), None);
        assert_eq!(p.push(Eye::Right, 103, "r103"), Some((100, "l100", "r103")));
        // A right with no left near it waits, then is passed by later pairs.
        assert_eq!(p.push(Eye::Right, 133, "r133"), None);
        assert_eq!(p.push(Eye::Left, 166, "l166"), None);
        assert_eq!(p.push(Eye::Right, 167, "r167"), Some((166, "l166", "r167")));
        assert_eq!((p.unpaired(), p.waiting()), (1, 0));
        // The nearest of several waiting partners is taken; the older one
        // is dropped.
        assert_eq!(p.push(Eye::Left, 200, "l200"), None);
        assert_eq!(p.push(Eye::Left, 204, "l204"), None);
        assert_eq!(p.push(Eye::Right, 205, "r205"), Some((204, "l204", "r205")));
        assert_eq!((p.unpaired(), p.waiting()), (2, 0));
    }

    #[test]
    fn a_side_without_partners_keeps_only_the_latest() {
        let mut p = Pairer::new(1);
        for t in 0..10 {
            assert_eq!(p.push(Eye::Left, t * 33, t), None);
        }
        assert_eq!(p.waiting(), Pairer::<i64>::WAITING);
        assert_eq!(p.unpaired(), 10 - Pairer::<i64>::WAITING as u64);
        assert_eq!(p.push(Eye::Right, 9 * 33, 99), Some((297, 9, 99)));
        assert_eq!(p.unpaired(), 9);
    }

    #[test]
    fn a_camera_info_becomes_the_calibration_file_the_rig_reads() {
        let info = CameraInfo {
            width: 640,
            height: 480,
            distortion_model: "plumb_bob".into(),
            d: vec![-0.2, 0.04, -0.001, 0.0009, 0.006],
            k: [552.0, 0.0, 317.5, 0.0, 550.9, 243.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                552.0, 0.0, 317.5, 0.0, 0.0, 550.9, 243.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            ..Default::default()
        };
        let yaml = camera_info_yaml("left", &info);
        let (k, kind) = formats::camera_file::parse("left.yaml".as_ref(), &yaml).unwrap();
        assert_eq!(kind, formats::camera_file::CameraFileKind::RosCameraInfo);
        assert_eq!(
            (k.width, k.height, k.fx, k.fy, k.cx, k.cy),
            (640, 480, 552.0, 550.9, 317.5, 243.0)
        );
        assert_eq!(k.dist.coefficients(), info.d);
    }
}
