//! Rendering what the simulated head sees, with real ArUco marker images.
//!
//! What stays still is traced once per camera ([`crate::room`]): the room,
//! the mirror's glass and frame, the robot's head and body; blurred by the
//! lens and darkened towards the corners, it is each frame's starting
//! image. What moves is drawn over it each frame, only in the regions it
//! covers: the marker cards (60 mm of black-bordered code inside a 15 mm
//! white margin; the arm's is centred on the end-effector as placed by the
//! arm's *true* kinematics), their plain backs, and the arm's links. A card
//! seen in the mirror is drawn at its reflected corners (which is what
//! mirror-reverses it), only where the pixel's ray meets the glass, dimmed
//! by the mirror's reflectance and doubled by a faint ghost from the
//! glass's front surface. The wrist keeps the arm's card facing the head's
//! mirror image (so it reads in the mirror), or the head itself for direct
//! views.
//!
//! Each card is sampled straight through the lens model: every pixel's
//! undistorted ray, precomputed, goes through the card's homography into its
//! texture. A moving arm is drawn at several poses over the exposure and
//! averaged (motion blur); each region is blurred by the defocus at its
//! depth; sensor noise and optional JPEG compression follow
//! ([`crate::sensor`]). The still scene's noise is made once, in a few
//! copies that take turns from frame to frame; only the pixels drawn over
//! it, and the fixed markers' cards, get noise of their own each frame
//! (noising every pixel took about a sixth of a frame's time). A still
//! marker is thus seen through fresh noise every frame, as a real camera
//! sees it: its corners averaged over frames settle as they would (over a
//! few shared copies they settled on the copies' own errors). What the
//! image looks like is a [`Look`].

use std::collections::HashMap;

use crate::{RenderError, Result};
use geometry::Camera;
use geometry::sim::{Facing, MARKER_MARGIN_MM, MARKER_SIZE_MM, SimWorld, card_corners};
use nalgebra::{Matrix3, Vector2, Vector3};
use opencv::core::{self, Mat, Point, Point2f, Scalar, Size, Vector};
use opencv::prelude::*;
use opencv::{aruco, imgproc};

use crate::look::Look;
use crate::room::{Picture, Room, irradiance};
use crate::sensor::{Noise, vignetting};

/// Texture pixels per marker module side.
const TEXTURE_MARKER_PX: i32 = 120;
/// Radii of the arm's links from the shoulder out, mm (the last repeats).
const LIMB_RADII_MM: [f64; 2] = [24.0, 19.0];
/// Reflectance of the arm's links and of the cards' backs.
const LIMB_ALBEDO: f64 = 0.55;
const CARD_BACK_ALBEDO: f64 = 0.25;
/// Typical distance of the room seen around the arm, for its defocus, mm.
const ROOM_DEPTH_MM: f64 = 2000.0;
/// The poses a moving arm's card is drawn at over one exposure
/// ([`Renderer::motion_steps`]).
const MOTION_SAMPLING: MotionSampling = MotionSampling {
    step_sigmas: 1.25,
    step_px: 1.5,
    max_steps: 6,
};
/// Noisy copies of each camera's still image: a frame's background is one
/// of them (they take turns), and only what is drawn over it each frame
/// gets noise of its own.
const NOISY_STILLS: usize = 8;

/// A marker as drawn: id, mirror-reversed, and its code square's corners
/// (distorted px, TL, TR, BR, BL as printed).
pub type DrawnMarker = (u32, bool, [Vector2<f64>; 4]);

/// Where things really were in a rendered frame (for tests).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RenderTruth {
    /// Per camera, the markers drawn: id, mirrored, corners (distorted px, in texture order TL, TR, BR, BL).
    pub markers: [Vec<DrawnMarker>; 2],
    /// True end-effector position, mm.
    pub end_effector: Option<Vector3<f64>>,
}

/// What one camera sees of the still scene, per pixel.
struct View {
    /// Undistorted normalised coordinates of the pixel's centre (NaN: none).
    rays: Vec<[f32; 2]>,
    /// The still scene (with the fixed cards) in DN, blurred, vignetted,
    /// with flare: each frame starts from it.
    image: Vec<u8>,
    /// Vignetting.
    gain: Vec<f32>,
    /// Fraction of the pixel that shows the glass.
    glass: Vec<f32>,
}

/// Something drawn each frame.
#[derive(Debug, Clone, Copy)]
enum Shape {
    /// A marker card (code and margin), corners as seen, TL, TR, BR, BL as printed.
    Card { id: u32, corners: [Vector3<f64>; 4] },
    /// A card's plain back.
    Plate { corners: [Vector3<f64>; 4] },
    /// A link of the arm: a cylinder (a ball when the ends meet).
    Limb {
        a: Vector3<f64>,
        b: Vector3<f64>,
        radius: f64,
    },
}

#[derive(Debug, Clone, Copy)]
struct Item {
    shape: Shape,
    /// Seen in the glass: drawn only where the pixel's ray meets it.
    mirrored: bool,
    /// The glass's faint front-surface image: adds light, covers nothing.
    ghost: bool,
    /// DN of reflectance 1 on it (light, exposure, mirror).
    dn: f64,
}

impl Shape {
    fn points(&self) -> Vec<Vector3<f64>> {
        match self {
            Shape::Card { corners, .. } | Shape::Plate { corners } => corners.to_vec(),
            Shape::Limb { a, b, .. } => vec![*a, *b],
        }
    }

    fn center(&self) -> Vector3<f64> {
        let p = self.points();
        p.iter().sum::<Vector3<f64>>() / p.len() as f64
    }

    fn map(&self, f: impl Fn(&Vector3<f64>) -> Vector3<f64>) -> Shape {
        match *self {
            Shape::Card { id, corners } => Shape::Card {
                id,
                corners: corners.map(|c| f(&c)),
            },
            Shape::Plate { corners } => Shape::Plate {
                corners: corners.map(|c| f(&c)),
            },
            Shape::Limb { a, b, radius } => Shape::Limb {
                a: f(&a),
                b: f(&b),
                radius,
            },
        }
    }
}

/// Renders stereo frames of a [`SimWorld`].
pub struct Renderer {
    world: SimWorld,
    look: Look,
    /// Full-size card images (code and margin) per id, 8 bits.
    cards: HashMap<u32, Mat>,
    /// Cards shrunk to about their size on screen, per (id, side).
    shrunk: HashMap<(u32, i32), Picture>,
    views: [View; 2],
    noise: Noise,
    /// Per camera, [`NOISY_STILLS`] copies of its still image with sensor
    /// noise (none when the look has no noise).
    noisy_stills: [Vec<Vec<u8>>; 2],
    /// Per camera, where the fixed cards are drawn in its still image:
    /// noised afresh each frame.
    fixed_drawn: [Drawn; 2],
    /// The views last drawn, before noise: reused while the arm holds still.
    last_drawn: Option<LastDrawn>,
    /// Frames drawn anew, not reused.
    frames_drawn: u64,
    /// Where a moving arm's card is drawn over an exposure:
    /// [`MOTION_SAMPLING`] (finer in tests, as the reference).
    motion: MotionSampling,
}

/// How far apart the poses a moving arm's card is drawn at over an
/// exposure are: `step_sigmas` sigmas of the blur its image gets (lens and
/// defocus), at least `step_px` pixels, at most `max_steps` poses.
#[derive(Debug, Clone, Copy)]
struct MotionSampling {
    step_sigmas: f64,
    step_px: f64,
    max_steps: usize,
}

/// The two views of a frame drawn over their still images, before the
/// sensor's noise, and the arm's poses over the exposure they show. A
/// frame with the same poses (the arm held still) shows the same drawing,
/// noised afresh: drawing it again would give the same bytes.
struct LastDrawn {
    open: Vec<f64>,
    close: Vec<f64>,
    faces: Facing,
    views: [DrawnView; 2],
}

/// One view drawn over its still image, and where.
struct DrawnView {
    image: Vec<u8>,
    drawn: Drawn,
}

/// A rectangle of the image.
#[derive(Debug, Clone)]
struct Region {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    /// Nearest depth of what it shows, mm: its defocus.
    depth: f64,
}

impl Renderer {
    /// A renderer with the default ([`Look::realistic`]) look.
    pub fn new(world: SimWorld) -> Result<Self> {
        Self::with_look(world, Look::realistic())
    }

    /// Prepares card textures and traces the still scene for each camera.
    pub fn with_look(world: SimWorld, look: Look) -> Result<Self> {
        look.validate()?;
        let dictionary =
            aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)?;
        let margin_px =
            (f64::from(TEXTURE_MARKER_PX) * MARKER_MARGIN_MM / MARKER_SIZE_MM).round() as i32;
        let mut cards = HashMap::new();
        for id in std::iter::once(world.arm_marker).chain(world.fixed.iter().map(|f| f.id)) {
            if id >= 50 {
                return Err(RenderError::UnknownMarker(id));
            }
            let mut code = Mat::default();
            aruco::draw_marker(&dictionary, id as i32, TEXTURE_MARKER_PX, &mut code, 1)?;
            let mut texture = Mat::default();
            core::copy_make_border(
                &code,
                &mut texture,
                margin_px,
                margin_px,
                margin_px,
                margin_px,
                core::BORDER_CONSTANT,
                Scalar::all(255.0),
            )?;
            cards.insert(id, texture);
        }
        let eyes = [world.rig.cameras[0].center, world.rig.cameras[1].center];
        let room = Room::new(world.mirror, eyes, &look)?;
        let views = [
            still_view(&world.rig.cameras[0], &room, &look)?,
            still_view(&world.rig.cameras[1], &room, &look)?,
        ];
        let pixels = views[0].image.len();
        let mut renderer = Self {
            noise: Noise::new(&look, pixels, 0x5EED),
            world,
            look,
            cards,
            shrunk: HashMap::new(),
            views,
            noisy_stills: [Vec::new(), Vec::new()],
            fixed_drawn: [Drawn::new(0), Drawn::new(0)],
            last_drawn: None,
            frames_drawn: 0,
            motion: MOTION_SAMPLING,
        };
        // The fixed cards do not move: drawn into the still image once.
        let fixed = [renderer.items(None)?];
        for k in 0..2 {
            let mut image = std::mem::take(&mut renderer.views[k].image);
            renderer.shrink_cards(k, &fixed)?;
            let height = renderer.world.rig.cameras[k].intrinsics.height as usize;
            let mut drawn = Drawn::new(height);
            renderer.draw_over(k, &fixed[0], &fixed, &mut image, &mut drawn)?;
            renderer.views[k].image = image;
            renderer.fixed_drawn[k] = drawn;
        }
        if !renderer.noise.is_silent() {
            for k in 0..2 {
                renderer.noisy_stills[k] = (0..NOISY_STILLS as u64)
                    .map(|v| {
                        let mut image = renderer.views[k].image.clone();
                        renderer.noise.add(&mut image, v << 1 | k as u64);
                        image
                    })
                    .collect();
            }
        }
        Ok(renderer)
    }

    /// The world being rendered.
    pub fn world(&self) -> &SimWorld {
        &self.world
    }

    /// The look it renders with.
    pub fn look(&self) -> &Look {
        &self.look
    }

    /// Renders both cameras into new buffers sized by the rig (for tests and
    /// benchmarks); see [`Renderer::render`].
    pub fn render_pair(
        &mut self,
        q: &[f64],
        arm_faces: Facing,
        seq: u64,
    ) -> Result<([Vec<u8>; 2], RenderTruth)> {
        let len = self.views[0].image.len();
        let (mut left, mut right) = (vec![0u8; len], vec![0u8; len]);
        let truth = self.render(q, arm_faces, seq, &mut left, &mut right)?;
        Ok(([left, right], truth))
    }

    /// Renders both cameras for encoder readings `q` into `left` and `right`
    /// (mono8, width x height, no row padding), the arm still; `seq` seeds
    /// the sensor noise. `arm_faces` says which way the wrist turns the
    /// arm's card.
    pub fn render(
        &mut self,
        q: &[f64],
        arm_faces: Facing,
        seq: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderTruth> {
        self.render_moving(q, None, arm_faces, seq, left, right)
    }

    /// [`Renderer::render`] with the arm moving at `velocity` (rad/s per
    /// joint): the exposure is centred on `q`, and the arm blurs over it.
    pub fn render_moving(
        &mut self,
        q: &[f64],
        velocity: Option<&[f64]>,
        arm_faces: Facing,
        seq: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderTruth> {
        let arm = self.world.rig.arm.as_ref().ok_or(RenderError::NoArm)?;
        let end_effector = arm.end_effector(q, &self.world.true_offsets)?;
        let mut truth = RenderTruth {
            end_effector: Some(end_effector),
            ..RenderTruth::default()
        };
        // The poses the arm is drawn at over the exposure.
        let half_exposure = self.look.exposure_ms / 2000.0;
        let (open, close): (Vec<f64>, Vec<f64>) = match velocity {
            Some(v) if v.len() == q.len() && self.look.exposure_ms > 0.0 => q
                .iter()
                .zip(v)
                .map(|(q, v)| (q - v * half_exposure, q + v * half_exposure))
                .unzip(),
            _ => (q.to_vec(), q.to_vec()),
        };
        let reused = self
            .last_drawn
            .take()
            .filter(|l| l.open == open && l.close == close && l.faces == arm_faces);
        let mut items_per_pose = Vec::new();
        // What is drawn once, unblurred (links, backs): at the exposure's middle.
        let mut middle = Vec::new();
        if reused.is_none() {
            middle = self.items(Some((q, arm_faces)))?;
            self.frames_drawn += 1;
            let steps = self.motion_steps(&open, &close, arm_faces)?;
            // The poses' spread widened to the exposure's: n midpoints of
            // equal parts of it spread 1 - 1/n^2 times its variance.
            let widen = if steps > 1 {
                1.0 / (1.0 - 1.0 / (steps * steps) as f64).sqrt()
            } else {
                1.0
            };
            for s in 0..steps {
                let f = 0.5 + ((s as f64 + 0.5) / steps as f64 - 0.5) * widen;
                let pose: Vec<f64> = open
                    .iter()
                    .zip(&close)
                    .map(|(a, b)| a + (b - a) * f)
                    .collect();
                items_per_pose.push(self.items(Some((&pose, arm_faces)))?);
            }
        }
        let code_side = MARKER_SIZE_MM;
        for k in 0..2 {
            let cam = self.world.rig.cameras[k];
            // Truth: cards whose code the camera sees whole (through the glass if reflected).
            for (id, center, faces) in self.cards_at(&end_effector, arm_faces) {
                let code = self.world.seen_card(center, faces, code_side);
                let behind_glass = !code.mirrored
                    || self.world.mirror.is_some_and(|m| {
                        code.corners
                            .iter()
                            .all(|c| m.ray_hits_glass(&cam.center, c))
                    });
                if !behind_glass || code.corners.iter().any(|c| cam.depth(c) <= 1.0) {
                    continue;
                }
                let mut px = [Vector2::zeros(); 4];
                for (p, c) in px.iter_mut().zip(&code.corners) {
                    *p = cam.project(c)?;
                }
                if px.iter().any(|p| cam.intrinsics.contains(p, 0.0)) {
                    truth.markers[k].push((id, code.mirrored, px));
                }
            }
            self.shrink_cards(k, &items_per_pose)?;
        }
        // The two views on two threads: the right one's on a scoped thread.
        let this = &*self;
        let draw = |k: usize, out: &mut [u8], last: Option<DrawnView>| -> Result<DrawnView> {
            let mut view = match last {
                Some(view) => {
                    out.copy_from_slice(&view.image);
                    view
                }
                None => {
                    let mut drawn = this.fixed_drawn[k].clone();
                    out.copy_from_slice(&this.views[k].image);
                    this.draw_over(k, &middle, &items_per_pose, out, &mut drawn)?;
                    DrawnView {
                        image: out.to_vec(),
                        drawn,
                    }
                }
            };
            this.add_noise(k, out, &mut view.drawn, seq);
            let width = this.world.rig.cameras[k].intrinsics.width as usize;
            this.noise.compress(out, width)?;
            Ok(view)
        };
        let [last_left, last_right] = match reused {
            Some(l) => l.views.map(Some),
            None => [None, None],
        };
        let (l, r) = std::thread::scope(|s| {
            let r = s.spawn(|| draw(1, right, last_right));
            (draw(0, left, last_left), r.join())
        });
        let views = [l?, r.map_err(|_| RenderError::Panicked("right"))??];
        self.last_drawn = Some(LastDrawn {
            open,
            close,
            faces: arm_faces,
            views,
        });
        Ok(truth)
    }

    /// The cards in the world: (id, centre, which way it faces).
    fn cards_at(
        &self,
        end_effector: &Vector3<f64>,
        arm_faces: Facing,
    ) -> Vec<(u32, Vector3<f64>, Facing)> {
        std::iter::once((self.world.arm_marker, *end_effector, arm_faces))
            .chain(self.fixed_cards())
            .collect()
    }

    /// The cards fixed in the world, each turned its own way.
    fn fixed_cards(&self) -> impl Iterator<Item = (u32, Vector3<f64>, Facing)> + '_ {
        self.world.fixed.iter().map(|f| (f.id, f.center, f.faces))
    }

    /// How many poses to draw the arm at over the exposure: one per
    /// [`MOTION_SAMPLING`] step its card moves in either image. Every card
    /// is drawn through the blur at its depth (at least the lens's 1.5 px),
    /// which smooths poses 1.25 sigmas apart, spread as the exposure is,
    /// into its streak: on the fast direct moves (the worst case) within
    /// 2 DN of the streak drawn at 0.3 px steps, as close as poses 1.5 px
    /// apart were, with 70% of the poses to draw.
    fn motion_steps(&self, open: &[f64], close: &[f64], faces: Facing) -> Result<usize> {
        if open == close {
            return Ok(1);
        }
        let arm = self.world.rig.arm.as_ref().ok_or(RenderError::NoArm)?;
        let a = self.world.seen_card(
            arm.end_effector(open, &self.world.true_offsets)?,
            faces,
            1.0,
        );
        let b = self.world.seen_card(
            arm.end_effector(close, &self.world.true_offsets)?,
            faces,
            1.0,
        );
        let mut steps: f64 = 1.0;
        for cam in &self.world.rig.cameras {
            if let (Ok(pa), Ok(pb)) = (cam.project(&a.center), cam.project(&b.center)) {
                let depth = cam.depth(&a.center).min(cam.depth(&b.center));
                let spacing =
                    (self.motion.step_sigmas * self.look.blur_at(depth)).max(self.motion.step_px);
                steps = steps.max((pa - pb).norm() / spacing);
            }
        }
        Ok((steps.ceil() as usize).clamp(1, self.motion.max_steps))
    }

    /// What is drawn for the arm with `arm_at` `Some((q, faces))`: at `q`,
    /// its card turned `faces` (its card, the card's back, its links); or
    /// with `None` for the fixed cards (each turned its own way); directly
    /// and in the glass, with the glass's ghost.
    fn items(&self, arm_at: Option<(&[f64], Facing)>) -> Result<Vec<Item>> {
        let arm = self.world.rig.arm.as_ref().ok_or(RenderError::NoArm)?;
        let offsets = &self.world.true_offsets;
        let cards = match arm_at {
            Some((q, faces)) => vec![(self.world.arm_marker, arm.end_effector(q, offsets)?, faces)],
            None => self.fixed_cards().collect(),
        };
        let q = arm_at.map(|(q, _)| q);
        let look = &self.look;
        let lit = |p: &Vector3<f64>, n: &Vector3<f64>| {
            look.exposure_dn * if look.room { irradiance(p, n) } else { 1.0 }
        };
        let head = 0.5 * (self.world.rig.cameras[0].center + self.world.rig.cameras[1].center);
        let side = MARKER_SIZE_MM + 2.0 * MARKER_MARGIN_MM;
        // Real (unreflected) shapes with their reflectance-1 DN, and for a
        // card or its back whether its face is turned to the glass.
        let mut real: Vec<(Shape, f64, Option<bool>)> = Vec::new();
        for (id, center, faces) in cards {
            // Which way the card's face points: towards the head or its image.
            let eye = match (faces, self.world.mirror) {
                (Facing::Mirror, Some(m)) if m.plane.signed_distance(&center) > 0.0 => {
                    Some(m.plane.reflect_point(&head))
                }
                _ => None,
            };
            let to_glass = eye.is_some();
            let eye = eye.unwrap_or(head);
            let front = card_corners(&center, &eye, side);
            let normal = (eye - center).normalize();
            real.push((
                Shape::Card { id, corners: front },
                lit(&center, &normal),
                Some(to_glass),
            ));
            if look.room {
                // The back: the same square seen from behind.
                let back = [front[1], front[0], front[3], front[2]];
                real.push((
                    Shape::Plate { corners: back },
                    CARD_BACK_ALBEDO * lit(&center, &-normal),
                    Some(!to_glass),
                ));
            }
        }
        if let (true, Some(q)) = (look.room, q) {
            let joints = arm.skeleton(q, offsets)?;
            let mut limb = 0;
            for pair in joints.windows(2) {
                let (a, b) = (pair[0], pair[1]);
                if (a - b).norm() < 1.0 {
                    continue;
                }
                let radius = LIMB_RADII_MM[limb.min(LIMB_RADII_MM.len() - 1)];
                limb += 1;
                let n = (head - 0.5 * (a + b)).normalize();
                let dn = LIMB_ALBEDO * lit(&(0.5 * (a + b)), &n);
                real.push((Shape::Limb { a, b, radius }, dn, None));
                // A ball at the joint it starts from.
                real.push((
                    Shape::Limb {
                        a,
                        b: a,
                        radius: radius * 1.15,
                    },
                    dn,
                    None,
                ));
            }
        }
        let mut items = Vec::new();
        for (shape, dn, to_glass) in &real {
            // A card (or its back) shows its face to the head directly or to
            // the head's mirror image; links show to both.
            if *to_glass != Some(true) && (matches!(shape, Shape::Card { .. }) || look.room) {
                items.push(Item {
                    shape: *shape,
                    mirrored: false,
                    ghost: false,
                    dn: *dn,
                });
            }
            let Some(m) = self.world.mirror else { continue };
            if *to_glass == Some(false) || m.plane.signed_distance(&shape.center()) <= 0.0 {
                continue;
            }
            items.push(Item {
                shape: shape.map(|p| m.plane.reflect_point(p)),
                mirrored: true,
                ghost: false,
                dn: dn * look.reflectance,
            });
            if look.ghost > 0.0 {
                let n = m.plane.normal.into_inner() * look.ghost_offset_mm;
                items.push(Item {
                    shape: shape.map(|p| m.plane.reflect_point(p) + n),
                    mirrored: true,
                    ghost: true,
                    dn: dn * look.reflectance * look.ghost,
                });
            }
        }
        Ok(items)
    }

    /// Sensor noise over a frame of camera `k` that was `drawn` over its
    /// still image: the rest is one of the still image's noisy copies; what
    /// was drawn gets noise of its own.
    fn add_noise(&self, k: usize, out: &mut [u8], drawn: &mut Drawn, seq: u64) {
        let stills = &self.noisy_stills[k];
        if stills.is_empty() {
            return;
        }
        let background = &stills[(seq % stills.len() as u64) as usize];
        let width = self.world.rig.cameras[k].intrinsics.width as usize;
        for (y, ((row, still), spans)) in out
            .chunks_exact_mut(width)
            .zip(background.chunks_exact(width))
            .zip(drawn.merged_rows())
            .enumerate()
        {
            let mut x = 0;
            for &(x0, x1) in spans.iter() {
                row[x..x0].copy_from_slice(&still[x..x0]);
                let seed = (seq << 1 | k as u64) ^ ((y as u64) << 32 | x0 as u64);
                self.noise.add(&mut row[x0..x1], seed);
                x = x1;
            }
            row[x..].copy_from_slice(&still[x..]);
        }
    }

    /// Draws items over what `out` shows (a frame starts as the still
    /// scene): what is seen in the glass, then what is seen directly; each
    /// of those far to near, links and card backs before cards (a card is
    /// held at the wrist). Links and backs are drawn once, as `middle` (the
    /// arm at the exposure's middle), cards at each of `items_per_pose`.
    /// Where it drew goes to `drawn`.
    fn draw_over(
        &self,
        k: usize,
        middle: &[Item],
        items_per_pose: &[Vec<Item>],
        out: &mut [u8],
        drawn: &mut Drawn,
    ) -> Result<()> {
        let cam = self.world.rig.cameras[k];
        for mirrored in [true, false] {
            // Links and backs: large and plain, drawn once at the exposure's middle pose.
            let mut plain: Vec<&Item> = middle
                .iter()
                .filter(|i| i.mirrored == mirrored && !matches!(i.shape, Shape::Card { .. }))
                .collect();
            plain.sort_by(|a, b| {
                cam.depth(&b.shape.center())
                    .total_cmp(&cam.depth(&a.shape.center()))
            });
            for item in plain {
                self.draw_plain(k, item, out, drawn)?;
            }
            // Cards: at every pose over the exposure, in regions around them.
            let mut cards: Vec<(usize, &Item, [f64; 4], Region)> = Vec::new();
            for (pose, items) in items_per_pose.iter().enumerate() {
                for item in items.iter().filter(|i| i.mirrored == mirrored) {
                    if let (Shape::Card { .. }, Some((bbox, area))) =
                        (item.shape, self.area(&cam, &item.shape))
                    {
                        cards.push((pose, item, bbox, area));
                    }
                }
            }
            cards.sort_by(|a, b| b.3.depth.total_cmp(&a.3.depth));
            let mut regions: Vec<Region> = Vec::new();
            for (_, _, _, area) in &cards {
                let mut region = area.clone();
                while let Some(j) = regions.iter().position(|r| overlaps(r, &region)) {
                    region = union(&region, &regions.swap_remove(j));
                }
                regions.push(region);
            }
            let poses = items_per_pose.len();
            for region in &regions {
                let n = region.w * region.h;
                let (mut light, mut alpha) = (vec![0f32; n], vec![0f32; n]);
                let inside: Vec<_> = cards.iter().filter(|c| overlaps(&c.3, region)).collect();
                if poses == 1 {
                    for (_, item, bbox, _) in &inside {
                        self.draw_card(k, item, *bbox, region, &mut light, &mut alpha)?;
                    }
                } else {
                    // Each pose's cards drawn alone, then the poses averaged.
                    let (mut step_light, mut step_alpha) = (vec![0f32; n], vec![0f32; n]);
                    for pose in 0..poses {
                        step_light.fill(0.0);
                        step_alpha.fill(0.0);
                        for (_, item, bbox, _) in inside.iter().filter(|c| c.0 == pose) {
                            self.draw_card(
                                k,
                                item,
                                *bbox,
                                region,
                                &mut step_light,
                                &mut step_alpha,
                            )?;
                        }
                        let share = 1.0 / poses as f32;
                        for (acc, v) in light.iter_mut().zip(&step_light) {
                            *acc += v * share;
                        }
                        for (acc, v) in alpha.iter_mut().zip(&step_alpha) {
                            *acc += v * share;
                        }
                    }
                }
                self.composite(k, region, &mut light, &mut alpha, out, drawn)?;
            }
        }
        Ok(())
    }

    /// A shape's distorted-pixel box, and its area: the box grown by its
    /// blur's reach, within the image, with its depth.
    fn area(&self, cam: &Camera, shape: &Shape) -> Option<([f64; 4], Region)> {
        let bbox = project_bbox(cam, shape)?;
        let depth = cam.depth(&shape.center()).max(1.0);
        let reach = (3.0 * self.look.blur_at(depth)).ceil() + 2.0;
        let (width, height) = (
            cam.intrinsics.width as usize,
            cam.intrinsics.height as usize,
        );
        let x0 = (bbox[0] - reach).floor().max(0.0) as usize;
        let y0 = (bbox[1] - reach).floor().max(0.0) as usize;
        let x1 = ((bbox[2] + reach).ceil().max(0.0) as usize).min(width);
        let y1 = ((bbox[3] + reach).ceil().max(0.0) as usize).min(height);
        (x1 > x0 && y1 > y0).then_some((
            bbox,
            Region {
                x0,
                y0,
                w: x1 - x0,
                h: y1 - y0,
                depth,
            },
        ))
    }

    /// Draws a link or a card's back straight into the frame: its
    /// anti-aliased outline blurred by the defocus at its depth, at its
    /// shade, vignetted, only where the glass is for a reflection; where
    /// it drew goes to `drawn`.
    fn draw_plain(&self, k: usize, item: &Item, out: &mut [u8], drawn: &mut Drawn) -> Result<()> {
        let cam = self.world.rig.cameras[k];
        let Some((_, area)) = self.area(&cam, &item.shape) else {
            return Ok(());
        };
        let mut mask = polygon_mask(&cam, &item.shape, area.x0, area.y0, area.w, area.h)?;
        // Two box filters of the same sigma stand in for a Gaussian: a
        // near link's blur is wide, and box filters cost the same at any width.
        let sigma = self.look.blur_at(area.depth);
        let side = ((6.0 * sigma * sigma + 1.0).sqrt().round() as i32) | 1;
        if side > 1 {
            for _ in 0..2 {
                let src = mask.try_clone()?;
                imgproc::blur(
                    &src,
                    &mut mask,
                    Size::new(side, side),
                    Point::new(-1, -1),
                    core::BORDER_REPLICATE,
                )?;
            }
        }
        let view = &self.views[k];
        let width = cam.intrinsics.width as usize;
        let (dn, flare) = (item.dn as f32, self.look.flare_dn as f32);
        let mask = mask.data_bytes()?;
        for y in 0..area.h {
            let row = (area.y0 + y) * width + area.x0;
            let line = &mask[y * area.w..(y + 1) * area.w];
            let Some((first, last)) = nonzero_span(line) else {
                continue;
            };
            drawn.add(area.y0 + y, area.x0 + first, area.x0 + last + 1);
            for x in first..=last {
                let m = line[x];
                if m == 0 {
                    continue;
                }
                let i = row + x;
                let g = if item.mirrored { view.glass[i] } else { 1.0 };
                let a = f32::from(m) / 255.0 * g;
                let v = f32::from(out[i]) * (1.0 - a) + (dn * view.gain[i] + flare) * a;
                out[i] = to_dn(v);
            }
        }
        Ok(())
    }

    /// Draws a card (or its ghost) into a region's light (premultiplied
    /// DN) and coverage, sampling its texture through each pixel's ray.
    fn draw_card(
        &self,
        k: usize,
        item: &Item,
        bbox: [f64; 4],
        region: &Region,
        light: &mut [f32],
        alpha: &mut [f32],
    ) -> Result<()> {
        let Shape::Card { id, corners } = item.shape else {
            return Err(RenderError::Internal("only cards are drawn from a texture"));
        };
        let cam = self.world.rig.cameras[k];
        // The card's pixels within the region.
        let x0 = (bbox[0].floor().max(0.0) as usize).max(region.x0);
        let y0 = (bbox[1].floor().max(0.0) as usize).max(region.y0);
        let x1 = ((bbox[2].ceil().max(0.0) as usize) + 1).min(region.x0 + region.w);
        let y1 = ((bbox[3].ceil().max(0.0) as usize) + 1).min(region.y0 + region.h);
        if x1 <= x0 || y1 <= y0 {
            return Ok(());
        }
        let side = self.card_side(id, &cam, &corners)?;
        let texture = self.shrunk.get(&(id, side)).ok_or(RenderError::Internal(
            "a card's texture drawn before it was shrunk",
        ))?;
        let h = texel_from_normalized(&cam, &corners, texture.width, texture.height)?;
        let view = &self.views[k];
        let width = cam.intrinsics.width as usize;
        let dn = item.dn as f32;
        for y in y0..y1 {
            for x in x0..x1 {
                let i = y * width + x;
                let r = view.rays[i];
                let t = h * Vector3::new(r[0], r[1], 1.0);
                // NaN rays (no lens model there) fail the test and draw nothing.
                if t.z.is_nan() || t.z <= 0.0 {
                    continue;
                }
                let (value, cover) = texture.sample(t.x / t.z, t.y / t.z);
                if cover == 0.0 {
                    continue;
                }
                let g = if item.mirrored { view.glass[i] } else { 1.0 };
                let (c, a) = (value * dn * g, cover * g);
                let j = (y - region.y0) * region.w + (x - region.x0);
                if item.ghost {
                    light[j] += c;
                } else {
                    light[j] = c + light[j] * (1.0 - a);
                    alpha[j] = a + alpha[j] * (1.0 - a);
                }
            }
        }
        Ok(())
    }

    /// Caches the textures camera `k` draws the cards of `items_per_pose`
    /// with, so that drawing needs no cache updates (and the two views
    /// draw at once).
    fn shrink_cards(&mut self, k: usize, items_per_pose: &[Vec<Item>]) -> Result<()> {
        let cam = self.world.rig.cameras[k];
        for item in items_per_pose.iter().flatten() {
            if let Shape::Card { id, corners } = item.shape {
                self.shrink_card(id, &cam, &corners)?;
            }
        }
        Ok(())
    }

    /// Caches the card's texture shrunk (area averaging) to about its size
    /// on screen, as bilinear sampling of a much larger texture aliases the
    /// edges; returns the side it has in the cache.
    fn shrink_card(&mut self, id: u32, cam: &Camera, corners: &[Vector3<f64>; 4]) -> Result<i32> {
        let side = self.card_side(id, cam, corners)?;
        let card = self
            .cards
            .get(&id)
            .ok_or(RenderError::Internal("a card without its texture"))?;
        let full = card.cols();
        if !self.shrunk.contains_key(&(id, side)) {
            let mut small = Mat::default();
            let source = if side < full {
                imgproc::resize(
                    card,
                    &mut small,
                    Size::new(side, side),
                    0.0,
                    0.0,
                    imgproc::INTER_AREA,
                )?;
                &small
            } else {
                card
            };
            let picture = Picture::from_mat(source, self.look.paper[0], self.look.paper[1])?;
            self.shrunk.insert((id, side), picture);
        }
        Ok(side)
    }

    /// The side of the card's texture drawn for these corners: about the
    /// card's size on screen, the full texture when near it.
    fn card_side(&self, id: u32, cam: &Camera, corners: &[Vector3<f64>; 4]) -> Result<i32> {
        let card = self
            .cards
            .get(&id)
            .ok_or(RenderError::Internal("a card without its texture"))?;
        let px: Vec<Vector2<f64>> = corners.iter().filter_map(|c| cam.project(c).ok()).collect();
        let on_screen = (0..px.len())
            .map(|i| (px[i] - px[(i + 1) % px.len()]).norm())
            .fold(0.0, f64::max);
        let full = card.cols();
        let scale = (on_screen / f64::from(full)).min(1.0);
        Ok(if scale < 0.9 {
            ((f64::from(full) * scale).round() as i32).max(8)
        } else {
            full
        })
    }

    /// Writes a region: what was drawn over what the frame shows there,
    /// vignetted and blurred by the defocus at its depth.
    fn composite(
        &self,
        k: usize,
        region: &Region,
        light: &mut [f32],
        alpha: &mut [f32],
        out: &mut [u8],
        drawn: &mut Drawn,
    ) -> Result<()> {
        let view = &self.views[k];
        let width = self.world.rig.cameras[k].intrinsics.width as usize;
        for y in 0..region.h {
            let row = (region.y0 + y) * width + region.x0;
            for (l, g) in light[y * region.w..(y + 1) * region.w]
                .iter_mut()
                .zip(&view.gain[row..row + region.w])
            {
                *l *= g;
            }
        }
        let sigma = self.look.blur_at(region.depth);
        if sigma > 0.05 {
            blur(light, region.w, region.h, sigma)?;
            blur(alpha, region.w, region.h, sigma)?;
        }
        let flare = self.look.flare_dn as f32;
        // Only where the blur's tails change a pixel by more than a
        // hundredth of a DN.
        let changes = |j: usize| alpha[j] > 4e-5 || light[j] > 0.01;
        for y in 0..region.h {
            let row = (region.y0 + y) * width + region.x0;
            let base = y * region.w;
            let (Some(first), Some(last)) = (
                (0..region.w).find(|&x| changes(base + x)),
                (0..region.w).rfind(|&x| changes(base + x)),
            ) else {
                continue;
            };
            drawn.add(region.y0 + y, region.x0 + first, region.x0 + last + 1);
            for x in first..=last {
                let j = base + x;
                let v = f32::from(out[row + x]) * (1.0 - alpha[j]) + light[j] + flare * alpha[j];
                out[row + x] = to_dn(v);
            }
        }
        Ok(())
    }
}

/// Gaussian blur of a w x h f32 image in place.
fn blur(data: &mut [f32], w: usize, h: usize, sigma: f64) -> Result<()> {
    let src = Mat::new_rows_cols_with_data(h as i32, w as i32, &*data)?.try_clone()?;
    let mut dst = Mat::new_rows_cols_with_data_mut(h as i32, w as i32, data)?;
    imgproc::gaussian_blur(
        &src,
        &mut dst,
        Size::new(0, 0),
        sigma,
        0.0,
        core::BORDER_REPLICATE,
    )?;
    Ok(())
}

/// The nearest 8-bit value (saturating; the cast rounds without the
/// library call `f32::round` compiles to here).
fn to_dn(v: f32) -> u8 {
    (v + 0.5) as u8
}

/// The first and last non-zero bytes of `line`, looked for 8 at a time (a
/// link's mask is mostly zeros around its outline).
fn nonzero_span(line: &[u8]) -> Option<(usize, usize)> {
    let nonzero = |c: &[u8]| match <[u8; 8]>::try_from(c) {
        Ok(word) => u64::from_ne_bytes(word) != 0,
        Err(_) => c.iter().any(|&m| m > 0),
    };
    let chunk = |i: usize| &line[8 * i..(8 * i + 8).min(line.len())];
    let (first, last) = (
        line.chunks(8).position(nonzero)?,
        line.chunks(8).rposition(nonzero)?,
    );
    Some((
        8 * first + chunk(first).iter().position(|&m| m > 0)?,
        8 * last + chunk(last).iter().rposition(|&m| m > 0)?,
    ))
}

/// Where a frame was drawn over its still image: per row, spans of
/// pixels `x0..x1`.
#[derive(Debug, Clone)]
struct Drawn {
    rows: Vec<Vec<(usize, usize)>>,
}

impl Drawn {
    fn new(height: usize) -> Self {
        Self {
            rows: vec![Vec::new(); height],
        }
    }

    fn add(&mut self, y: usize, x0: usize, x1: usize) {
        self.rows[y].push((x0, x1));
    }

    /// Each row's spans sorted, overlapping and touching ones merged.
    fn merged_rows(&mut self) -> impl Iterator<Item = &Vec<(usize, usize)>> {
        self.rows.iter_mut().map(|spans| {
            spans.sort_unstable();
            let mut merged: Vec<(usize, usize)> = Vec::with_capacity(spans.len());
            for &(x0, x1) in spans.iter() {
                match merged.last_mut() {
                    Some(last) if x0 <= last.1 => last.1 = last.1.max(x1),
                    _ => merged.push((x0, x1)),
                }
            }
            *spans = merged;
            &*spans
        })
    }
}

fn overlaps(a: &Region, b: &Region) -> bool {
    a.x0 < b.x0 + b.w && b.x0 < a.x0 + a.w && a.y0 < b.y0 + b.h && b.y0 < a.y0 + a.h
}

fn union(a: &Region, b: &Region) -> Region {
    let (x0, y0) = (a.x0.min(b.x0), a.y0.min(b.y0));
    let (x1, y1) = ((a.x0 + a.w).max(b.x0 + b.w), (a.y0 + a.h).max(b.y0 + b.h));
    Region {
        x0,
        y0,
        w: x1 - x0,
        h: y1 - y0,
        depth: a.depth.min(b.depth),
    }
}

/// The still scene as one camera sees it.
fn still_view(cam: &Camera, room: &Room, look: &Look) -> Result<View> {
    let intr = cam.intrinsics;
    let (w, h) = (intr.width as usize, intr.height as usize);
    let mut rays = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            rays.push(
                match intr.undistort_pixel(&Vector2::new(u as f64, v as f64)) {
                    Ok(xy) => [xy.x as f32, xy.y as f32],
                    Err(_) => [f32::NAN; 2],
                },
            );
        }
    }
    let (radiance, glass) = room.trace_image(cam, &rays);
    let gain = vignetting(w, h, [intr.cx + 0.5, intr.cy + 0.5], look.vignetting);
    let mut level: Vec<f32> = if look.room {
        radiance
            .iter()
            .map(|r| r * look.exposure_dn as f32)
            .collect()
    } else {
        vec![look.background_dn as f32; w * h]
    };
    let sigma = look.blur_at(ROOM_DEPTH_MM);
    if look.room && sigma > 0.05 {
        blur(&mut level, w, h, sigma)?;
    }
    for (l, g) in level.iter_mut().zip(&gain) {
        *l *= g;
    }
    let flare = look.flare_dn as f32;
    let image = level
        .iter()
        .map(|l| (l + flare).round().clamp(0.0, 255.0) as u8)
        .collect();
    Ok(View {
        rays,
        image,
        gain,
        glass,
    })
}

/// Distorted-pixel bounding box (x0, y0, x1, y1) of a shape, if it is in
/// front of the camera and touches the image.
fn project_bbox(cam: &Camera, shape: &Shape) -> Option<[f64; 4]> {
    let points = shape.points();
    if points.iter().any(|p| cam.depth(p) <= 10.0) {
        return None;
    }
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let pad = match shape {
        Shape::Limb { radius, .. } => {
            let depth = points
                .iter()
                .map(|p| cam.depth(p))
                .fold(f64::INFINITY, f64::min);
            cam.intrinsics.fx * radius * 1.2 / depth
        }
        _ => 0.0,
    };
    for p in &points {
        let px = cam.project(p).ok()?;
        b = [
            b[0].min(px.x - pad),
            b[1].min(px.y - pad),
            b[2].max(px.x + pad),
            b[3].max(px.y + pad),
        ];
    }
    let (w, h) = (
        f64::from(cam.intrinsics.width),
        f64::from(cam.intrinsics.height),
    );
    // Barrel distortion bows edges out a little: a pixel of slack.
    let b = [b[0] - 1.0, b[1] - 1.0, b[2] + 1.0, b[3] + 1.0];
    (b[2] > 0.0 && b[3] > 0.0 && b[0] < w && b[1] < h).then_some(b)
}

/// The homography from a card's undistorted normalised image coordinates
/// to its texture's texel coordinates (texel centres at integers, so the
/// card's outer edge is at -0.5).
fn texel_from_normalized(
    cam: &Camera,
    corners: &[Vector3<f64>; 4],
    width: usize,
    height: usize,
) -> Result<Matrix3<f32>> {
    let mut seen = Vector::<Point2f>::new();
    for c in corners {
        let xy = cam.normalized(c)?;
        seen.push(Point2f::new(xy.x as f32, xy.y as f32));
    }
    let (w, h) = (width as f32 - 0.5, height as f32 - 0.5);
    let texel = Vector::<Point2f>::from_iter([
        Point2f::new(-0.5, -0.5),
        Point2f::new(w, -0.5),
        Point2f::new(w, h),
        Point2f::new(-0.5, h),
    ]);
    let m = imgproc::get_perspective_transform(&seen, &texel, core::DECOMP_LU)?;
    let mut out = Matrix3::zeros();
    for r in 0..3 {
        for c in 0..3 {
            out[(r, c)] = *m.at_2d::<f64>(r as i32, c as i32)? as f32;
        }
    }
    Ok(out)
}

/// Coverage (0-255, anti-aliased) of a plate or limb over a w x h box at (x0, y0).
fn polygon_mask(
    cam: &Camera,
    shape: &Shape,
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
) -> Result<Mat> {
    const SHIFT: i32 = 4;
    let scale = f64::from(1 << SHIFT);
    let to_point = |p: Vector2<f64>| {
        Point::new(
            ((p.x - x0 as f64) * scale).round() as i32,
            ((p.y - y0 as f64) * scale).round() as i32,
        )
    };
    let mut mask =
        Mat::new_rows_cols_with_default(h as i32, w as i32, core::CV_8UC1, Scalar::all(0.0))?;
    match *shape {
        Shape::Plate { corners } => {
            let mut poly = Vector::<Point>::new();
            for c in &corners {
                poly.push(to_point(cam.project(c)?));
            }
            imgproc::fill_convex_poly(
                &mut mask,
                &poly,
                Scalar::all(255.0),
                imgproc::LINE_AA,
                SHIFT,
            )?;
        }
        Shape::Limb { a, b, radius } => {
            const SAMPLES: usize = 5;
            let along: Vec<(Vector2<f64>, f64)> = (0..SAMPLES)
                .map(|i| {
                    let p = a + (b - a) * (i as f64 / (SAMPLES - 1) as f64);
                    Ok((cam.project(&p)?, cam.intrinsics.fx * radius / cam.depth(&p)))
                })
                .collect::<Result<_, geometry::GeometryError>>()?;
            let dir = along[SAMPLES - 1].0 - along[0].0;
            if dir.norm() > 1.0 {
                let normal = Vector2::new(-dir.y, dir.x).normalize();
                let mut poly = Vector::<Point>::new();
                for (p, r) in &along {
                    poly.push(to_point(p + normal * *r));
                }
                for (p, r) in along.iter().rev() {
                    poly.push(to_point(p - normal * *r));
                }
                let polys = Vector::<Vector<Point>>::from_iter([poly]);
                imgproc::fill_poly(
                    &mut mask,
                    &polys,
                    Scalar::all(255.0),
                    imgproc::LINE_AA,
                    SHIFT,
                    Point::default(),
                )?;
            }
            for (p, r) in [along[0], along[SAMPLES - 1]] {
                let radius = (r * scale).round() as i32;
                imgproc::circle(
                    &mut mask,
                    to_point(p),
                    radius,
                    Scalar::all(255.0),
                    imgproc::FILLED,
                    imgproc::LINE_AA,
                    SHIFT,
                )?;
            }
        }
        Shape::Card { .. } => {
            return Err(RenderError::Internal("cards are drawn from their texture"));
        }
    }
    Ok(mask)
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::sim::{Counts, generate, nico_noise, nico_scene};

    #[test]
    fn the_nonzero_span_of_a_row_is_its_first_and_last_nonzero_byte() {
        for len in [0, 1, 7, 8, 9, 16, 23, 40] {
            for a in 0..len {
                for b in a..len {
                    let mut line = vec![0u8; len];
                    line[a] = 3;
                    line[b] = 200;
                    assert_eq!(nonzero_span(&line), Some((a, b)), "{len} {a} {b}");
                }
            }
            assert_eq!(nonzero_span(&vec![0u8; len]), None);
        }
    }

    #[test]
    fn drawn_spans_are_merged_where_they_overlap_or_touch() {
        let mut drawn = Drawn::new(2);
        for (x0, x1) in [(30, 40), (5, 10), (8, 12), (12, 15), (39, 41)] {
            drawn.add(1, x0, x1);
        }
        let rows: Vec<Vec<(usize, usize)>> = drawn.merged_rows().cloned().collect();
        assert_eq!(rows, vec![vec![], vec![(5, 15), (30, 41)]]);
    }

    /// An arm pose in front of the mirror (seed 3's first calibration
    /// pose) and the realistic look without JPEG, for the noise tests.
    fn mirror_pose_realistic_look() -> (Vec<f64>, Look) {
        let data = generate(
            &nico_scene(),
            0,
            &nico_noise(),
            Counts {
                train: 1,
                test: 0,
                direct: 0,
            },
            3,
        )
        .unwrap();
        let look = Look {
            jpeg_quality: None,
            ..Look::realistic()
        };
        (data.train[0].joints.clone().unwrap(), look)
    }

    /// The sensor noise of a frame (its difference from the same frame
    /// rendered without noise, over each pixel's expected sigma) has the
    /// same spread on what was drawn over the still scene (the arm's card)
    /// as on the still scene, and differs from frame to frame on both.
    #[test]
    fn what_moves_is_as_noisy_as_the_still_scene_and_the_noise_changes_per_frame() {
        let (q, look) = mirror_pose_realistic_look();
        let silent = Look {
            read_noise_dn: 0.0,
            electrons_per_dn: 0.0,
            ..look
        };
        let world = SimWorld::nico(0).unwrap();
        let mut noisy = Renderer::with_look(world.clone(), look).unwrap();
        let mut clean = Renderer::with_look(world, silent).unwrap();
        let (frames, truth) = noisy.render_pair(&q, Facing::Mirror, 1).unwrap();
        let (again, _) = noisy.render_pair(&q, Facing::Mirror, 2).unwrap();
        let (without, _) = clean.render_pair(&q, Facing::Mirror, 1).unwrap();
        let width = 640;
        let sigma = |level: u8| {
            let signal = (f64::from(level) - look.flare_dn).max(0.0);
            (look.read_noise_dn.powi(2) + signal / look.electrons_per_dn).sqrt()
        };
        // The arm's card in the left image: its code square's box.
        let (_, _, corners) = truth.markers[0]
            .iter()
            .find(|m| m.0 == noisy.world().arm_marker)
            .expect("the arm's card in view");
        let (lo, hi) = corners.iter().fold(
            (Vector2::repeat(f64::MAX), Vector2::repeat(f64::MIN)),
            |(lo, hi), c| (lo.inf(c), hi.sup(c)),
        );
        let on_card = |i: usize| {
            (lo.x..hi.x).contains(&((i % width) as f64))
                && (lo.y..hi.y).contains(&((i / width) as f64))
        };
        let spread = |card: bool| {
            let z: Vec<f64> = (0..frames[0].len())
                .filter(|&i| on_card(i) == card && (20..235).contains(&without[0][i]))
                .map(|i| {
                    (f64::from(frames[0][i]) - f64::from(without[0][i])) / sigma(without[0][i])
                })
                .collect();
            let mean = z.iter().sum::<f64>() / z.len() as f64;
            (z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / z.len() as f64).sqrt()
        };
        let (card, still) = (spread(true), spread(false));
        assert!(
            (0.85..1.15).contains(&card) && (0.85..1.15).contains(&still),
            "noise over sigma: {card:.3} on the card, {still:.3} on the still scene"
        );
        let changed = |card: bool| {
            let pixels: Vec<usize> = (0..frames[0].len())
                .filter(|&i| on_card(i) == card)
                .collect();
            pixels
                .iter()
                .filter(|&&i| frames[0][i] != again[0][i])
                .count() as f64
                / pixels.len() as f64
        };
        assert!(
            changed(true) > 0.5 && changed(false) > 0.5,
            "{} {}",
            changed(true),
            changed(false)
        );
    }

    /// A fixed marker's card gets noise of its own each frame, as the arm's
    /// does: two frames that share the still scene's noisy copy differ on
    /// it, and on little else (the arm).
    #[test]
    fn a_still_marker_is_seen_through_fresh_noise_each_frame() {
        let (q, look) = mirror_pose_realistic_look();
        let world = SimWorld::nico(0).unwrap();
        let fixed = world.fixed[0].id;
        let width = world.rig.cameras[0].intrinsics.width as usize;
        let mut renderer = Renderer::with_look(world, look).unwrap();
        // The same noisy copy of the still scene behind both.
        let (a, truth) = renderer.render_pair(&q, Facing::Mirror, 1).unwrap();
        let (b, _) = renderer
            .render_pair(&q, Facing::Mirror, 1 + NOISY_STILLS as u64)
            .unwrap();
        let boxed = |id: u32| {
            let (_, _, corners) = truth.markers[0]
                .iter()
                .find(|m| m.0 == id)
                .expect("the card in view");
            corners.iter().fold(
                (Vector2::repeat(f64::MAX), Vector2::repeat(f64::MIN)),
                |(lo, hi), c| (lo.inf(c), hi.sup(c)),
            )
        };
        let changed_in = |(lo, hi): (Vector2<f64>, Vector2<f64>)| {
            let pixels: Vec<usize> = (0..a[0].len())
                .filter(|&i| {
                    (lo.x..hi.x).contains(&((i % width) as f64))
                        && (lo.y..hi.y).contains(&((i / width) as f64))
                })
                .collect();
            let changed = pixels.iter().filter(|&&i| a[0][i] != b[0][i]).count();
            changed as f64 / pixels.len() as f64
        };
        let on_fixed = changed_in(boxed(fixed));
        assert!(
            on_fixed > 0.5,
            "{on_fixed} of the fixed card's pixels changed"
        );
        let all = a[0].iter().zip(&b[0]).filter(|(x, y)| x != y).count() as f64;
        assert!(
            all / (a[0].len() as f64) < 0.2,
            "{all} pixels changed: the still scene's noise is shared"
        );
    }

    /// The arm's card in fast direct moves (the card near the head, where
    /// it moves furthest in the image) drawn as the renderer draws it is
    /// its streak: within 2 DN of the card drawn at poses 0.3 px apart,
    /// with no more pixels off by more than 1 DN than poses 1.5 px apart
    /// (the renderer's rule before) give, and fewer poses.
    #[test]
    fn a_moving_card_is_drawn_as_its_streak() {
        let data = generate(
            &nico_scene(),
            0,
            &nico_noise(),
            Counts {
                train: 0,
                test: 0,
                direct: 4,
            },
            3,
        )
        .unwrap();
        let poses: Vec<Vec<f64>> = data
            .direct
            .iter()
            .filter_map(|s| s.joints.clone())
            .collect();
        let sequence = geometry::sim::sweep(&poses, 9, 0, 90.0);
        let silent = Look {
            read_noise_dn: 0.0,
            electrons_per_dn: 0.0,
            jpeg_quality: None,
            ..Look::realistic()
        };
        let world = SimWorld::nico(0).unwrap();
        let with = |motion: MotionSampling| {
            let mut r = Renderer::with_look(world.clone(), silent).unwrap();
            r.motion = motion;
            r
        };
        let mut streak = with(MotionSampling {
            step_sigmas: 0.0,
            step_px: 0.3,
            max_steps: 64,
        });
        let mut before = with(MotionSampling {
            step_sigmas: 0.0,
            step_px: 1.5,
            ..MOTION_SAMPLING
        });
        let mut ours = with(MOTION_SAMPLING);
        let half = silent.exposure_ms / 2000.0;
        // Per renderer: the most DN off, pixels off by more than 1, poses.
        let mut off = [(0u8, 0usize, 0usize); 2];
        for (seq, (q, speed)) in sequence.iter().enumerate() {
            let render = |r: &mut Renderer| {
                let [mut l, mut right] = [(); 2].map(|_| vec![0u8; 640 * 480]);
                r.render_moving(q, Some(speed), Facing::Head, seq as u64, &mut l, &mut right)
                    .unwrap();
                l.extend(right);
                l
            };
            let truth = render(&mut streak);
            let open: Vec<f64> = q.iter().zip(speed).map(|(q, v)| q - v * half).collect();
            let close: Vec<f64> = q.iter().zip(speed).map(|(q, v)| q + v * half).collect();
            for (r, off) in [&mut before, &mut ours].into_iter().zip(&mut off) {
                let image = render(r);
                for (a, b) in image.iter().zip(&truth) {
                    off.0 = off.0.max(a.abs_diff(*b));
                    off.1 += usize::from(a.abs_diff(*b) > 1);
                }
                off.2 += r.motion_steps(&open, &close, Facing::Head).unwrap();
            }
        }
        let [before, ours] = off;
        assert!(
            ours.0 <= 2 && ours.1 <= before.1 && ours.2 * 4 <= before.2 * 3,
            "off the streak: ours {ours:?}, poses 1.5 px apart {before:?} (DN, pixels > 1 DN, poses)"
        );
    }

    /// A frame whose arm poses are those of the last frame (the arm held
    /// still) reuses its drawing and noises it afresh: every frame of a
    /// sequence that moves, holds still and moves again is the same, byte
    /// for byte, as one drawn from nothing.
    #[test]
    fn a_still_arm_is_drawn_once_and_every_frame_is_what_drawing_it_anew_gives() {
        let poses = geometry::sim::nico_train_poses(0, 2, 3).unwrap();
        let sequence = geometry::sim::sweep(&poses, 2, 3, 30.0);
        let world = SimWorld::nico(0).unwrap();
        let mut renderer = Renderer::new(world.clone()).unwrap();
        let mut fresh = Renderer::new(world).unwrap();
        let (mut reused, mut redrawn) = (0, 0);
        for (seq, (q, speed)) in sequence.iter().enumerate() {
            let [mut l, mut r, mut fl, mut fr] = [(); 4].map(|_| vec![0u8; 640 * 480]);
            let still = seq > 0
                && speed.iter().all(|v| *v == 0.0)
                && sequence[seq - 1].0 == *q
                && sequence[seq - 1].1.iter().all(|v| *v == 0.0);
            let drawn_before = renderer.frames_drawn;
            renderer
                .render_moving(q, Some(speed), Facing::Mirror, seq as u64, &mut l, &mut r)
                .unwrap();
            fresh.last_drawn = None;
            fresh
                .render_moving(q, Some(speed), Facing::Mirror, seq as u64, &mut fl, &mut fr)
                .unwrap();
            assert!(
                l == fl && r == fr,
                "frame {seq} differs from one drawn anew"
            );
            let drew = renderer.frames_drawn > drawn_before;
            assert_eq!(
                drew, !still,
                "frame {seq}: drawn anew {drew}, arm still {still}"
            );
            if still {
                reused += 1;
            } else {
                redrawn += 1;
            }
        }
        assert!(
            reused >= 2 && redrawn >= 2,
            "{reused} reused, {redrawn} drawn"
        );
    }
}
