//! A structured test for the changes a mirror rig meets: the mirror's
//! plane moved, or one camera turned. Each such change moves a sample's
//! four pixel coordinates along directions its Jacobian gives, the same
//! change for every sample after it. A generalised likelihood ratio over
//! the samples since a candidate change point fits that change (3
//! parameters) to their errors: `T = b' A^-1 b`, `b = sum J'r`, `A = sum
//! J'J`, whitened by the expected noise, is chi-square 3 while nothing
//! moved, and grows with every sample after a change, in proportion to the
//! change's share of what the samples can see. A small change that the
//! per-sample CUSUM misses (its errors stay near the noise, sample by
//! sample) adds up here, since each sample's error points the same way.
//!
//! One sample cannot raise it: every candidate's statistic is taken with
//! its most telling sample left out (the smallest of the leave-one-out
//! statistics), so a wrong pairing or a misread marker, however far off,
//! counts for nothing alone.

use std::collections::VecDeque;

use geometry::{Camera, Plane, Rig, View};
use nalgebra::{Matrix3, SMatrix, SVector, Unit, UnitQuaternion, Vector2, Vector3};

use super::Scored;
use crate::calibrate::{Calibration, Seen, marker_point};

/// Most recent samples a change point is sought among.
pub const WINDOW: usize = 10;
/// What the statistic must reach to call a change: chi-square 3 exceeds 25
/// once in 70 000, and the test looks at up to `WINDOW - 1` change points,
/// three kinds of change, each with one sample left out.
pub const THRESHOLD: f64 = 25.0;

/// A change the test can name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hypothesis {
    /// The mirror's plane: its normal's two angles and its distance.
    Plane,
    /// Camera `k` turned about its own centre.
    Camera(usize),
}

const HYPOTHESES: [Hypothesis; 3] = [
    Hypothesis::Plane,
    Hypothesis::Camera(0),
    Hypothesis::Camera(1),
];

/// One sample's evidence per hypothesis: `J'r` and `J'J`, whitened.
#[derive(Debug, Clone, Copy)]
struct Evidence {
    at: Scored,
    jr: [Vector3<f64>; 3],
    jj: [Matrix3<f64>; 3],
}

type Jacobian = SMatrix<f64, 4, 3>;

/// The four pixel coordinates (left x, y, right x, y) of `point` as
/// `cameras` see it.
fn pixels(cameras: [Camera; 2], point: &Vector3<f64>) -> Option<SVector<f64, 4>> {
    let l = cameras[0].project(point).ok()?;
    let r = cameras[1].project(point).ok()?;
    Some(SVector::<f64, 4>::new(l.x, l.y, r.x, r.y))
}

/// Central differences of `f` in each of three parameters, steps `h`.
fn jacobian(f: impl Fn(usize, f64) -> Option<SVector<f64, 4>>, h: [f64; 3]) -> Option<Jacobian> {
    let mut j = Jacobian::zeros();
    for (i, h) in h.into_iter().enumerate() {
        let d = (f(i, h)? - f(i, -h)?) / (2.0 * h);
        j.set_column(i, &d);
    }
    Some(j)
}

/// `plane` with its normal turned by `angle` about the `i`th of two axes
/// across it (`i` = 0, 1), or moved by `angle` mm along it (`i` = 2).
fn nudged(plane: &Plane, i: usize, step: f64) -> Plane {
    let n = plane.normal.into_inner();
    let across = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = n.cross(&across).normalize();
    let axes = [u, n.cross(&u)];
    match i {
        0 | 1 => Plane {
            normal: UnitQuaternion::from_axis_angle(&Unit::new_unchecked(axes[i]), step)
                * plane.normal,
            distance: plane.distance,
        },
        _ => Plane {
            normal: plane.normal,
            distance: plane.distance + step,
        },
    }
}

/// The whitened evidence of one sample (`seen`, scored `at`) against
/// `cal`, with `corrected` its rig and `variance` the expected error per
/// pixel coordinate. `None` where the calibration holds no plane (the
/// paper's free mirror cameras: the CUSUM alone watches it), or the point
/// does not project.
fn evidence(
    cal: &Calibration,
    corrected: &Rig,
    seen: &Seen<'_>,
    variance: f64,
    at: Scored,
) -> Option<Evidence> {
    let plane = cal.plane?;
    let point = marker_point(cal, corrected, seen)?;
    let cams = corrected.cameras;
    let through = |plane: &Plane, cams: [Camera; 2]| match seen.view {
        View::Mirror => cams.map(|c| plane.mirror_camera(&c)),
        View::Direct => cams,
    };
    let predicted = match seen.view {
        View::Mirror => cal.placements.get(seen.placement)?.mirror_cameras,
        View::Direct => cams,
    };
    let seen_px = {
        let [l, r]: [Vector2<f64>; 2] = *seen.pixels;
        SVector::<f64, 4>::new(l.x, l.y, r.x, r.y)
    };
    let r = seen_px - pixels(predicted, &point)?;
    // Steps of about a tenth of a pixel's effect.
    const TURN: f64 = 1e-4;
    const SHIFT_MM: f64 = 0.05;
    let camera_turned = |k: usize| {
        jacobian(
            |i, h| {
                let mut turned = cams;
                turned[k] = cams[k].turned(&(Vector3::ith(i, h)));
                pixels(through(&plane, turned), &point)
            },
            [TURN; 3],
        )
    };
    let js = [
        match seen.view {
            View::Mirror => jacobian(
                |i, h| pixels(through(&nudged(&plane, i, h), cams), &point),
                [TURN, TURN, SHIFT_MM],
            )?,
            View::Direct => Jacobian::zeros(),
        },
        camera_turned(0)?,
        camera_turned(1)?,
    ];
    Some(Evidence {
        at,
        jr: js.map(|j| j.transpose() * r / variance),
        jj: js.map(|j| j.transpose() * j / variance),
    })
}

/// `b' A^-1 b`, for `A` that may be singular (a change a few samples
/// cannot see all of): what `A` does not determine counts for nothing.
fn statistic(b: &Vector3<f64>, a: &Matrix3<f64>) -> f64 {
    let ridge = 1e-9 * a.trace().max(1e-300);
    (a + Matrix3::identity() * ridge)
        .cholesky()
        .map_or(0.0, |c| b.dot(&c.solve(b)))
}

/// A change the test found: what, where it began, and its statistic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Found {
    /// What moved.
    pub hypothesis: Hypothesis,
    /// The first sample after the change point.
    pub began_at: Scored,
    /// Its statistic, its most telling sample left out.
    pub statistic: f64,
}

/// The test over the last [`WINDOW`] samples.
#[derive(Debug, Clone, Default)]
pub struct Glr {
    window: VecDeque<Evidence>,
}

impl Glr {
    /// Scores one sample (see [`evidence`]); returns the strongest change
    /// that reaches [`THRESHOLD`] with its most telling sample left out.
    pub fn push(
        &mut self,
        cal: &Calibration,
        corrected: &Rig,
        seen: &Seen<'_>,
        variance: f64,
        at: Scored,
    ) -> Option<Found> {
        let e = evidence(cal, corrected, seen, variance, at)?;
        if self.window.len() == WINDOW {
            self.window.pop_front();
        }
        self.window.push_back(e);
        let mut best: Option<Found> = None;
        for from in 0..self.window.len().saturating_sub(1) {
            let since = self.window.range(from..);
            for (h, hypothesis) in HYPOTHESES.iter().enumerate() {
                let (b, a) = since
                    .clone()
                    .fold((Vector3::zeros(), Matrix3::zeros()), |(b, a), e| {
                        (b + e.jr[h], a + e.jj[h])
                    });
                let t = since
                    .clone()
                    .map(|e| statistic(&(b - e.jr[h]), &(a - e.jj[h])))
                    .fold(f64::INFINITY, f64::min);
                if t >= THRESHOLD && best.is_none_or(|f| t > f.statistic) {
                    best = Some(Found {
                        hypothesis: *hypothesis,
                        began_at: self.window[from].at,
                        statistic: t,
                    });
                }
            }
        }
        best
    }
}
