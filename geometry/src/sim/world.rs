//! The simulated world the camera renders: the Nico scene in front of one
//! mirror placement, the true encoder offsets, the marker cards (the arm's,
//! a hidden object's and the fiducials) and where the cameras see each
//! card. Pure geometry: the drawing itself, and what the image looks like,
//! is `renderer`'s.

use nalgebra::{Vector2, Vector3};

use super::{Mirror, nico_noise, nico_scene};
use crate::{GeometryError, Rig};

/// Marker side (the black square), mm.
pub const MARKER_SIZE_MM: f64 = 60.0;
/// White margin around it, mm.
pub const MARKER_MARGIN_MM: f64 = 15.0;
/// Id of the arm's marker in the simulated worlds (`DICT_4X4_50`).
pub const ARM_MARKER_ID: u32 = 0;
/// Id of the object placed where only the mirror shows it.
pub const HIDDEN_OBJECT_ID: u32 = 7;
/// Ids of the fiducials: cards fixed in the room, seen directly, one at
/// each top corner of the view (left, right).
pub const FIDUCIAL_IDS: [u32; 2] = [12, 13];

/// The robot's head (around the cameras), neck and torso as boxes: x, y,
/// z extents in the world, mm. The renderer draws them (seen in the glass);
/// the hidden object is placed where they do not hide its reflection.
pub const ROBOT_BODY_MM: [[[f64; 2]; 3]; 3] = [
    [[-75.0, 75.0], [-75.0, 65.0], [-85.0, 12.0]],
    [[-25.0, 25.0], [65.0, 110.0], [-40.0, 10.0]],
    [[-90.0, 90.0], [110.0, 430.0], [-70.0, 50.0]],
];

/// Where the line `o + t d` is inside the box `extent`: the entry and exit
/// parameters `t` and the axis of the entry face (the slab test), or `None`
/// if it misses the box.
pub fn line_through_box(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    extent: &[[f64; 2]; 3],
) -> Option<(f64, f64, usize)> {
    let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        if d[k].abs() < 1e-12 {
            if o[k] < extent[k][0] || o[k] > extent[k][1] {
                return None;
            }
            continue;
        }
        let (p, q) = ((extent[k][0] - o[k]) / d[k], (extent[k][1] - o[k]) / d[k]);
        let (near, far) = if p < q { (p, q) } else { (q, p) };
        if near > t0 {
            t0 = near;
            axis = k;
        }
        t1 = t1.min(far);
    }
    (t0 <= t1).then_some((t0, t1, axis))
}

/// Whether the segment from `a` to `b` passes through the box `extent`.
pub fn segment_meets_box(a: &Vector3<f64>, b: &Vector3<f64>, extent: &[[f64; 2]; 3]) -> bool {
    line_through_box(a, &(b - a), extent).is_some_and(|(t0, t1, _)| t0.max(0.0) <= t1.min(1.0))
}

/// A marked object fixed in the world (not on the arm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixedMarker {
    /// ArUco id (`DICT_4X4_50`).
    pub id: u32,
    /// Centre in the world, mm.
    pub center: Vector3<f64>,
    /// Which way its card is turned.
    pub faces: Facing,
}

/// Everything the simulated camera knows: the true world, not the robot's model.
#[derive(Debug, Clone, PartialEq)]
pub struct SimWorld {
    /// The head's cameras (exact) and arm model (nominal).
    pub rig: Rig,
    /// The mirror, if one is placed.
    pub mirror: Option<Mirror>,
    /// True encoder offsets: true angle = reading + offset.
    pub true_offsets: Vec<f64>,
    /// ArUco id of the arm's marker.
    pub arm_marker: u32,
    /// Other marked objects.
    pub fixed: Vec<FixedMarker>,
}

/// Which way a marker card is turned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Facing {
    /// Towards the head's mirror image, to be read in the mirror.
    Mirror,
    /// Towards the head, to be read directly.
    Head,
}

/// A card as the cameras see it: reflected when seen in the mirror.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeenCard {
    /// Seen in the mirror (and so mirror-reversed).
    pub mirrored: bool,
    /// Where the cameras see its centre (behind the glass when mirrored), mm.
    pub center: Vector3<f64>,
    /// Its corners as seen, TL, TR, BR, BL as printed, mm.
    pub corners: [Vector3<f64>; 4],
}

impl SimWorld {
    /// The Nico scene in front of mirror `mirror`, with the preset's encoder
    /// offsets, a marked object beside and behind the head that the
    /// cameras can only see in the mirror, and up to two fiducials
    /// ([`FIDUCIAL_IDS`]) they see directly, at the top corners of their
    /// views where the glass leaves room: still markers far apart in the
    /// image, which pin a knocked camera's turn about its optical axis
    /// (`docs/methods.md`).
    pub fn nico(mirror: usize) -> Result<Self, GeometryError> {
        let scene = nico_scene();
        let glass = *scene
            .mirrors
            .get(mirror)
            .ok_or(GeometryError::NoSuchMirror {
                placement: mirror,
                placements: scene.mirrors.len(),
            })?;
        let hidden = hidden_object_spot(&scene.rig, &glass).map(|center| FixedMarker {
            id: HIDDEN_OBJECT_ID,
            center,
            faces: Facing::Mirror,
        });
        let fiducials = [false, true]
            .into_iter()
            .zip(FIDUCIAL_IDS)
            .map(|(right, id)| {
                fiducial_spot(&scene.rig, &glass, right).map(|center| FixedMarker {
                    id,
                    center,
                    faces: Facing::Head,
                })
            });
        let fixed = std::iter::once(hidden).chain(fiducials).flatten().collect();
        Ok(Self {
            rig: scene.rig,
            mirror: Some(glass),
            true_offsets: nico_noise().joint_offsets,
            arm_marker: ARM_MARKER_ID,
            fixed,
        })
    }

    /// Midway between the cameras.
    fn head(&self) -> Vector3<f64> {
        0.5 * (self.rig.cameras[0].center + self.rig.cameras[1].center)
    }

    /// Where the cameras see a card of side `side` centred at `center`: in
    /// the mirror (reflected) if it is turned to the mirror and in front of
    /// it, else directly, facing the head.
    pub fn seen_card(&self, center: Vector3<f64>, faces: Facing, side: f64) -> SeenCard {
        let head = self.head();
        let mirror = self
            .mirror
            .filter(|m| faces == Facing::Mirror && m.plane.signed_distance(&center) > 0.0);
        match mirror {
            Some(m) => SeenCard {
                mirrored: true,
                center: m.plane.reflect_point(&center),
                corners: card_corners(&center, &m.plane.reflect_point(&head), side)
                    .map(|c| m.plane.reflect_point(&c)),
            },
            None => SeenCard {
                mirrored: false,
                center,
                corners: card_corners(&center, &head, side),
            },
        }
    }
}

/// A change of the simulated world during a run: what a robot's world does
/// to its calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WorldChange {
    /// The mirror is turned `tilt_deg` about its width axis through its
    /// centre, then moved `shift_mm` along its normal towards the robot
    /// ([`Mirror::moved`]).
    Mirror {
        /// Turn, degrees.
        tilt_deg: f64,
        /// Shift, mm.
        shift_mm: f64,
    },
    /// Head camera `camera` (0 left, 1 right) is turned `rotate_deg` about
    /// its own `axis` (0 x: tilt, 1 y: pan, 2 z: about the optical axis),
    /// its centre kept: it was knocked.
    Camera {
        /// Which camera.
        camera: usize,
        /// Turn, degrees.
        rotate_deg: f64,
        /// The camera's axis it turns about.
        axis: usize,
    },
}

impl SimWorld {
    /// This world after `change`. The marked objects stay where they are.
    pub fn changed(&self, change: &WorldChange) -> Result<Self, GeometryError> {
        let mut world = self.clone();
        match *change {
            WorldChange::Mirror { tilt_deg, shift_mm } => {
                let mirror = world.mirror.as_mut().ok_or_else(|| {
                    GeometryError::Degenerate("no mirror to move in this world".into())
                })?;
                *mirror = mirror.moved(tilt_deg, shift_mm);
            }
            WorldChange::Camera {
                camera,
                rotate_deg,
                axis,
            } => {
                if camera > 1 || axis > 2 {
                    return Err(GeometryError::Degenerate(format!(
                        "camera {camera}, axis {axis}: expected camera 0 or 1 and axis 0, 1 or 2"
                    )));
                }
                let w = Vector3::ith(axis, rotate_deg.to_radians());
                world.rig.cameras[camera] = world.rig.cameras[camera].turned(&w);
            }
        }
        Ok(world)
    }
}

/// A spot behind the head (never in direct view) whose card reflection both
/// cameras see whole through the glass, not hidden by the robot's body: the
/// first of a fixed grid, nearest the head first.
fn hidden_object_spot(rig: &Rig, mirror: &Mirror) -> Option<Vector3<f64>> {
    let mut candidates = Vec::new();
    for z in [-60.0, -100.0, -140.0] {
        for y in (-4..=8).map(|i| f64::from(i) * 25.0) {
            for x in (-8..=8).map(|i| f64::from(i) * 25.0) {
                candidates.push(Vector3::new(x, y, z));
            }
        }
    }
    candidates.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
    let side = MARKER_SIZE_MM + 2.0 * MARKER_MARGIN_MM;
    let head = 0.5 * (rig.cameras[0].center + rig.cameras[1].center);
    candidates.into_iter().find(|c| {
        let corners = card_corners(c, &mirror.plane.reflect_point(&head), side)
            .map(|p| mirror.plane.reflect_point(&p));
        let real = card_corners(c, &mirror.plane.reflect_point(&head), side);
        rig.cameras.iter().all(|cam| {
            corners.iter().zip(&real).all(|(v, r)| {
                // The light's path from the card to the glass passes no part of the robot.
                let (de, dv) = (
                    mirror.plane.signed_distance(&cam.center),
                    mirror.plane.signed_distance(v),
                );
                let glass = cam.center + (v - cam.center) * (de / (de - dv));
                mirror.ray_hits_glass(&cam.center, v)
                    && !ROBOT_BODY_MM
                        .iter()
                        .any(|b| segment_meets_box(r, &glass, b))
                    && cam.depth(v) > 0.0
                    && cam
                        .project(v)
                        .is_ok_and(|px| cam.intrinsics.contains(&px, 20.0))
            })
        })
    })
}

/// How far the fiducials stand in front of the glass at least, mm: clear
/// of a mirror bumped towards the robot by a centimetre or two.
const FIDUCIAL_CLEARANCE_MM: f64 = 60.0;
/// The fiducials' cards lie above this image row in both cameras, px: the
/// top of the view, over the wall and the mirror's frame, where the arm's
/// card is never seen.
const FIDUCIAL_BAND_PX: f64 = 175.0;

/// A spot for a fiducial facing the head at the top left (or `right`) of
/// both cameras' views: in front of the glass by
/// [`FIDUCIAL_CLEARANCE_MM`], its card whole in both images within the
/// top band and nowhere over the glass (what is seen in the glass is drawn
/// over the still image with no depth test), and as far from the image
/// centres as that allows (the farther out, the better it shows a turn
/// about the optical axis).
fn fiducial_spot(rig: &Rig, mirror: &Mirror, right: bool) -> Option<Vector3<f64>> {
    let head = 0.5 * (rig.cameras[0].center + rig.cameras[1].center);
    let side = MARKER_SIZE_MM + 2.0 * MARKER_MARGIN_MM;
    let sign = if right { 1.0 } else { -1.0 };
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for z in (0..=8).map(|i| 300.0 + 25.0 * f64::from(i)) {
        for y in (0..=16).map(|i| -100.0 - 12.5 * f64::from(i)) {
            for x in (4..=40).map(|i| sign * 12.5 * f64::from(i)) {
                let c = Vector3::new(x, y, z);
                let corners = card_corners(&c, &head, side);
                if !corners
                    .iter()
                    .all(|p| mirror.plane.signed_distance(p) > FIDUCIAL_CLEARANCE_MM)
                {
                    continue;
                }
                // Its outline (corners and edge midpoints), none against the glass.
                let outline: Vec<Vector3<f64>> = (0..4)
                    .flat_map(|i| [corners[i], 0.5 * (corners[i] + corners[(i + 1) % 4])])
                    .collect();
                let mut reach = f64::INFINITY;
                let seen = rig.cameras.iter().all(|cam| {
                    if outline.iter().any(|p| mirror.glass_behind(&cam.center, p)) {
                        return false;
                    }
                    let centre = Vector2::new(cam.intrinsics.cx, cam.intrinsics.cy);
                    let ok = corners.iter().chain([&c]).all(|p| {
                        cam.depth(p) > 0.0
                            && cam.project(p).is_ok_and(|px| {
                                cam.intrinsics.contains(&px, 15.0)
                                    && px.y < FIDUCIAL_BAND_PX
                                    && sign * (px.x - centre.x) > 0.0
                            })
                    });
                    if let Ok(px) = cam.project(&c) {
                        reach = reach.min((px - centre).norm());
                    }
                    ok
                });
                if seen && best.is_none_or(|(r, _)| reach > r) {
                    best = Some((reach, c));
                }
            }
        }
    }
    best.map(|(_, c)| c)
}

/// Card corners (TL, TR, BR, BL as the viewer at `eye` sees them) of a card
/// of side `side` centred at `center` and facing `eye`.
pub fn card_corners(center: &Vector3<f64>, eye: &Vector3<f64>, side: f64) -> [Vector3<f64>; 4] {
    let n = (eye - center).normalize();
    let world_up = Vector3::new(0.0, -1.0, 0.0);
    let up = (world_up - n * world_up.dot(&n))
        .try_normalize(1e-9)
        .unwrap_or_else(Vector3::x);
    let right = up.cross(&n);
    let h = side / 2.0;
    [
        center - right * h + up * h,
        center + right * h + up * h,
        center + right * h - up * h,
        center - right * h - up * h,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hidden_object_is_seen_only_in_the_mirror() {
        for placement in 0..3 {
            let world = SimWorld::nico(placement).unwrap();
            let hidden = world.fixed.first().expect("a hidden object");
            assert_eq!(hidden.id, HIDDEN_OBJECT_ID);
            assert_eq!(hidden.faces, Facing::Mirror);
            let seen = world.seen_card(hidden.center, hidden.faces, MARKER_SIZE_MM);
            assert!(seen.mirrored);
            for cam in &world.rig.cameras {
                assert!(cam.depth(&hidden.center) < 0.0, "behind the head");
                assert!(cam.depth(&seen.center) > 0.0, "its reflection in view");
            }
        }
        assert!(matches!(
            SimWorld::nico(3),
            Err(GeometryError::NoSuchMirror { placement: 3, .. })
        ));
    }

    /// Each placement's fiducials are seen directly by both cameras, whole,
    /// at the top left and top right of the view, far from its centre, and
    /// stay in front of a mirror bumped 2 deg and 20 mm towards the robot.
    /// Placement 1's glass, turned towards the robot, leaves no room for
    /// them.
    #[test]
    fn the_fiducials_are_seen_directly_at_the_top_corners() {
        let table: [(usize, &[u32]); 3] = [(0, &FIDUCIAL_IDS), (1, &[]), (2, &FIDUCIAL_IDS)];
        for (placement, expected) in table {
            let world = SimWorld::nico(placement).unwrap();
            let bumped = world.mirror.unwrap().moved(2.0, 20.0);
            let ids: Vec<u32> = world.fixed.iter().map(|f| f.id).collect();
            assert_eq!(ids[0], HIDDEN_OBJECT_ID);
            assert_eq!(ids[1..], *expected, "placement {placement}");
            for f in &world.fixed[1..] {
                let sign = if f.id == FIDUCIAL_IDS[0] { -1.0 } else { 1.0 };
                assert_eq!(f.faces, Facing::Head);
                let seen =
                    world.seen_card(f.center, f.faces, MARKER_SIZE_MM + 2.0 * MARKER_MARGIN_MM);
                assert!(!seen.mirrored);
                for p in seen.corners {
                    assert!(
                        bumped.plane.signed_distance(&p) > 0.0,
                        "placement {placement}"
                    );
                }
                for cam in &world.rig.cameras {
                    for p in seen.corners {
                        // Not over the glass, even the bumped glass.
                        assert!(
                            !bumped.glass_behind(&cam.center, &p),
                            "placement {placement}"
                        );
                    }
                    let centre = Vector2::new(cam.intrinsics.cx, cam.intrinsics.cy);
                    let px = cam.project(&f.center).unwrap();
                    assert!((px - centre).norm() > 150.0, "placement {placement}: {px}");
                    assert!(
                        sign * (px.x - centre.x) > 0.0 && px.y < centre.y,
                        "placement {placement}: {px}"
                    );
                    for c in seen.corners {
                        let c = cam.project(&c).unwrap();
                        assert!(
                            cam.intrinsics.contains(&c, 10.0),
                            "placement {placement}: {c}"
                        );
                    }
                }
            }
        }
    }

    /// The arm's card seen in the glass, over the mirror poses the
    /// simulator draws (the paper's counts, three seeds), never comes near
    /// a fiducial in either image, nor near the reflection of a fiducial's
    /// back: the renderer draws what is seen in the glass over the still
    /// image with no depth test. (A direct view's card is in front of
    /// everything, and drawn so.) A sample of the poses: the card, not the
    /// links or the card's back.
    #[test]
    fn the_arms_card_never_meets_a_fiducial_or_its_reflected_back() {
        use crate::sim::{Counts, generate, nico_noise, nico_scene};
        let side = MARKER_SIZE_MM + 2.0 * MARKER_MARGIN_MM;
        let boxed = |cam: &crate::Camera, corners: &[Vector3<f64>; 4]| {
            let px: Vec<Vector2<f64>> = corners.iter().map(|c| cam.project(c).unwrap()).collect();
            let lo = px
                .iter()
                .fold(Vector2::repeat(f64::INFINITY), |a, p| a.inf(p));
            let hi = px
                .iter()
                .fold(Vector2::repeat(f64::NEG_INFINITY), |a, p| a.sup(p));
            (lo, hi)
        };
        let apart = |a: (Vector2<f64>, Vector2<f64>), b: (Vector2<f64>, Vector2<f64>)| {
            let margin = 5.0;
            a.1.x + margin < b.0.x
                || b.1.x + margin < a.0.x
                || a.1.y + margin < b.0.y
                || b.1.y + margin < a.0.y
        };
        for placement in 0..3 {
            let world = SimWorld::nico(placement).unwrap();
            let mirror = world.mirror.unwrap();
            let arm = world.rig.arm.as_ref().unwrap();
            let mut keep_clear = Vec::new();
            for f in world.fixed.iter().filter(|f| FIDUCIAL_IDS.contains(&f.id)) {
                let card = world.seen_card(f.center, f.faces, side);
                keep_clear.push(card.corners);
                keep_clear.push(card.corners.map(|c| mirror.plane.reflect_point(&c)));
            }
            for seed in 1..=3 {
                let data =
                    generate(&nico_scene(), placement, &nico_noise(), Counts::PAPER, seed).unwrap();
                for s in data.train.iter().chain(&data.test) {
                    let q = s.joints.as_ref().unwrap();
                    let at = arm.end_effector(q, &world.true_offsets).unwrap();
                    let card = world.seen_card(at, Facing::Mirror, side);
                    for cam in &world.rig.cameras {
                        for clear in &keep_clear {
                            assert!(
                                apart(boxed(cam, &card.corners), boxed(cam, clear)),
                                "placement {placement}, seed {seed}, pose {}",
                                s.pose
                            );
                        }
                    }
                }
            }
        }
    }
}
