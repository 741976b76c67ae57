//! Markers that hold still (every marker but the arm's): where each camera
//! sees their corners, frame by frame.
//!
//! A knocked camera turns about its centre, and a turn moves every still
//! point in its image alike whatever its depth: the corners of a still
//! marker before and after the knock give the turn with no need to know
//! where the marker is. The arm's views give the turn from ten or so
//! points, each as far off as the arm's kinematics; a still marker's
//! corners are averaged over the hundreds of frames on either side of the
//! knock, and pin the turn about the optical axis, which the arm's views
//! leave loosest (`docs/methods.md`, "When the world changes").

use std::collections::{BTreeMap, VecDeque};

use messages::StereoDetections;
use nalgebra::Vector2;

/// Sightings kept per camera (a marker in a frame is one): at 30 fps and
/// three still markers (the simulated room's), two minutes.
pub const KEPT: usize = 12_000;

/// Frames a marker must be seen in on each side of a change to count.
pub const MIN_FRAMES: usize = 10;

/// What a still corner's move is known to at best, px per coordinate,
/// however many frames are averaged: the tracker reads a marker with an
/// error of its own at each placement on the pixel grid, and a turn moves
/// it to another. 0.03 px on renders (`docs/methods.md`, "When the world
/// changes").
pub const CORNER_FLOOR_PX: f64 = 0.03;

/// One still marker seen by one camera in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sighting {
    stamp_ns: i64,
    key: (u32, bool),
    corners: [f64; 8],
}

/// A still marker's corners in one camera before and after a change.
#[derive(Debug, Clone, PartialEq)]
pub struct StillPair {
    /// Its id.
    pub id: u32,
    /// Seen in the mirror.
    pub mirrored: bool,
    /// Its corners before (medians over the frames), px.
    pub before: [Vector2<f64>; 4],
    /// Its corners after, px.
    pub after: [Vector2<f64>; 4],
    /// The 1-sigma of each corner coordinate's move from before to after,
    /// px: the frames' scatter over their number, on both sides, and
    /// [`CORNER_FLOOR_PX`] in quadrature.
    pub sigma_px: f64,
    /// Frames before and after.
    pub frames: (usize, usize),
}

/// The still markers each camera has seen lately.
#[derive(Debug, Clone, Default)]
pub struct StillMarkers {
    seen: [VecDeque<Sighting>; 2],
}

impl StillMarkers {
    /// Nothing seen yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes the markers of a frame but the arm's (`arm_marker`).
    pub fn push(&mut self, d: &StereoDetections, arm_marker: u32) {
        for (k, seen) in self.seen.iter_mut().enumerate() {
            for m in d.cameras[k].iter().filter(|m| m.id != arm_marker) {
                if m.corners.iter().any(|c| !c.is_finite()) {
                    continue;
                }
                if seen.len() == KEPT {
                    seen.pop_front();
                }
                seen.push_back(Sighting {
                    stamp_ns: d.stamp_ns,
                    key: (m.id, m.mirrored != 0),
                    corners: m.corners,
                });
            }
        }
    }

    /// Forgets what camera `k` saw: it moved, and its earlier views no
    /// longer show the world as it sees it now.
    pub fn forget(&mut self, k: usize) {
        self.seen[k].clear();
    }

    /// Each still marker camera `k` saw in at least [`MIN_FRAMES`] frames
    /// stamped within `before` and as many from `after_ns` on: its corners
    /// on either side (medians, robust to a frame the arm's card crossed
    /// and to a few taken on the wrong side of the change).
    pub fn pairs(
        &self,
        k: usize,
        before: std::ops::RangeInclusive<i64>,
        after_ns: i64,
    ) -> Vec<StillPair> {
        let mut sides: BTreeMap<(u32, bool), [Vec<[f64; 8]>; 2]> = BTreeMap::new();
        for s in &self.seen[k] {
            let side = if before.contains(&s.stamp_ns) {
                0
            } else if s.stamp_ns >= after_ns {
                1
            } else {
                continue;
            };
            sides.entry(s.key).or_default()[side].push(s.corners);
        }
        sides
            .into_iter()
            .filter(|(_, [b, a])| b.len() >= MIN_FRAMES && a.len() >= MIN_FRAMES)
            .map(|((id, mirrored), [b, a])| {
                let (before, spread_b) = medians(&b);
                let (after, spread_a) = medians(&a);
                // The median of n draws scatters 1.2533 / sqrt(n) times as
                // much as one draw.
                let averaged = 1.2533
                    * (spread_b.powi(2) / b.len() as f64 + spread_a.powi(2) / a.len() as f64)
                        .sqrt();
                let sigma_px = averaged.hypot(CORNER_FLOOR_PX);
                StillPair {
                    id,
                    mirrored,
                    before,
                    after,
                    sigma_px,
                    frames: (b.len(), a.len()),
                }
            })
            .collect()
    }
}

/// Each corner's median over the frames, and the frames' scatter about
/// them (1.4826 median absolute deviations, pooled over the 8
/// coordinates; at least 0.01 px, the detections' rounding).
fn medians(frames: &[[f64; 8]]) -> ([Vector2<f64>; 4], f64) {
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    let mut m = [0.0; 8];
    let mut deviations = Vec::with_capacity(8 * frames.len());
    for (i, mi) in m.iter_mut().enumerate() {
        let mut v: Vec<f64> = frames.iter().map(|f| f[i]).collect();
        *mi = median(&mut v);
        deviations.extend(frames.iter().map(|f| (f[i] - *mi).abs()));
    }
    let spread = (1.4826 * median(&mut deviations)).max(0.01);
    (
        [0, 1, 2, 3].map(|c| Vector2::new(m[2 * c], m[2 * c + 1])),
        spread,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::{CameraMarkers, Marker};

    fn frame(stamp_ns: i64, corners: [f64; 8], arm: bool) -> StereoDetections {
        let mut d = StereoDetections {
            stamp_ns,
            ..StereoDetections::default()
        };
        for k in 0..2 {
            let mut cam = CameraMarkers::default();
            cam.push(Marker {
                id: 7,
                mirrored: 1,
                corners,
                center: [0.0; 2],
            });
            if arm {
                cam.push(Marker {
                    id: 0,
                    mirrored: 1,
                    corners: [1.0; 8],
                    center: [0.0; 2],
                });
            }
            d.cameras[k] = cam;
        }
        d
    }

    /// The corners on either side of a change are their medians, a frame
    /// far off (the arm's card across the marker) does not move them, the
    /// arm's own marker is not taken, and frames between the sides count
    /// on neither.
    #[test]
    fn still_corners_either_side_of_a_change_are_their_medians() {
        let mut still = StillMarkers::new();
        let base = [10.0, 20.0, 30.0, 20.0, 30.0, 40.0, 10.0, 40.0];
        // -0.1, 0 and 0.1 px in turn: the medians are the base, and the
        // median absolute deviation 0.1 px.
        let wobble = |i: i64| 0.1 * ((i % 3) as f64 - 1.0);
        for i in 0..30i64 {
            let mut c = base.map(|v| v + wobble(i));
            if i == 7 {
                c = [500.0; 8];
            }
            still.push(&frame(i, c, true), 0);
        }
        for i in 30..35i64 {
            still.push(&frame(i, [900.0; 8], false), 0);
        }
        for i in 35..65i64 {
            still.push(&frame(i, base.map(|v| v + 2.0 + wobble(i)), false), 0);
        }
        let pairs = still.pairs(0, 0..=29, 35);
        assert_eq!(pairs.len(), 1, "{pairs:?}");
        let p = &pairs[0];
        assert_eq!((p.id, p.mirrored, p.frames), (7, true, (30, 30)));
        for c in 0..4 {
            let b = Vector2::new(base[2 * c], base[2 * c + 1]);
            assert!((p.before[c] - b).norm() < 1e-9, "{p:?}");
            assert!(
                (p.after[c] - b - Vector2::repeat(2.0)).norm() < 1e-9,
                "{p:?}"
            );
        }
        // Over 30 frames on each side: 1.2533 * 1.4826 * 0.1 * sqrt(2 / 30),
        // with the floor.
        let expected = (1.2533 * 1.4826 * 0.1 * (2.0f64 / 30.0).sqrt()).hypot(CORNER_FLOOR_PX);
        assert!((p.sigma_px / expected - 1.0).abs() < 1e-9, "{p:?}");
        still.forget(0);
        assert!(still.pairs(0, 0..=29, 35).is_empty());
        assert_eq!(still.pairs(1, 0..=29, 35).len(), 1);
    }
}
