//! Rendering what the simulated head sees, with real ArUco marker images.
//!
//! The arm's marker is a square card (60 mm of black-bordered code inside a
//! 15 mm white margin) centred on the end-effector as placed by the arm's
//! *true* kinematics (encoder reading plus the simulator's true offsets). We
//! model the wrist as keeping the card facing the head's mirror image (so
//! it reads in the mirror), or the head itself for direct views. Per camera:
//! OpenCV warps each marker texture onto an ideal (undistorted) image, at
//! its reflected corners for a mirror view (which is what mirror-reverses
//! it) and only where the ray passes through the mirror's finite glass; then
//! `remap` applies the lens distortion straight into the output buffer,
//! followed by a Gaussian blur and sensor noise.

use anyhow::{Context, Result, bail};
use geometry::Camera;
use geometry::sim::{Facing, ImageNoise, MARKER_MARGIN_MM, MARKER_SIZE_MM, SeenCard, SimWorld};
use nalgebra::{Vector2, Vector3};
use opencv::core::{self, Mat, Point2f, Scalar, Size, Vector};
use opencv::prelude::*;
use opencv::{aruco, imgproc};

/// Texture pixels per marker module side.
const TEXTURE_MARKER_PX: i32 = 120;
/// Grey level of the background.
const BACKGROUND: f64 = 110.0;

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

/// Renders stereo frames of a [`SimWorld`].
pub struct Renderer {
    world: SimWorld,
    textures: Vec<(u32, Mat)>,
    /// Per camera: for each distorted pixel, the ideal pixel to sample.
    maps: [(Mat, Mat); 2],
    canvas: Mat,
}

impl Renderer {
    /// Prepares textures and distortion maps.
    pub fn new(world: SimWorld) -> Result<Self> {
        let dictionary =
            aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)?;
        let margin_px =
            (f64::from(TEXTURE_MARKER_PX) * MARKER_MARGIN_MM / MARKER_SIZE_MM).round() as i32;
        let mut textures = Vec::new();
        for id in std::iter::once(world.arm_marker).chain(world.fixed.iter().map(|f| f.id)) {
            if id >= 50 {
                bail!("marker id {id} is not in DICT_4X4_50");
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
            textures.push((id, texture));
        }
        let maps = [
            distortion_maps(&world.rig.cameras[0])?,
            distortion_maps(&world.rig.cameras[1])?,
        ];
        let k = world.rig.cameras[0].intrinsics;
        let canvas = Mat::new_rows_cols_with_default(
            k.height as i32,
            k.width as i32,
            core::CV_8UC1,
            Scalar::all(BACKGROUND),
        )?;
        Ok(Self {
            world,
            textures,
            maps,
            canvas,
        })
    }

    /// The world being rendered.
    pub fn world(&self) -> &SimWorld {
        &self.world
    }

    /// Renders both cameras into new buffers sized by the rig (for tests and
    /// benchmarks); see [`Renderer::render`].
    pub fn render_pair(
        &mut self,
        q: &[f64],
        arm_faces: Facing,
        seq: u64,
    ) -> Result<([Vec<u8>; 2], RenderTruth)> {
        let i = self.world.rig.cameras[0].intrinsics;
        let len = (i.width * i.height) as usize;
        let (mut left, mut right) = (vec![0u8; len], vec![0u8; len]);
        let truth = self.render(q, arm_faces, seq, &mut left, &mut right)?;
        Ok(([left, right], truth))
    }

    /// Renders both cameras for encoder readings `q` into `left` and `right`
    /// (mono8, width x height, no row padding); `seq` seeds the sensor noise.
    /// `arm_faces` says which way the wrist turns the arm's card.
    pub fn render(
        &mut self,
        q: &[f64],
        arm_faces: Facing,
        seq: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderTruth> {
        let arm = self
            .world
            .rig
            .arm
            .as_ref()
            .context("the simulated world has no arm")?;
        let end_effector = arm.end_effector(q, &self.world.true_offsets)?;
        let mut truth = RenderTruth {
            end_effector: Some(end_effector),
            ..RenderTruth::default()
        };
        let mut things: Vec<(u32, Vector3<f64>)> = vec![(self.world.arm_marker, end_effector)];
        things.extend(self.world.fixed.iter().map(|f| (f.id, f.center)));
        // Where each card is seen (camera independent): the whole card, and its code square for the truth.
        let side = MARKER_SIZE_MM + 2.0 * MARKER_MARGIN_MM;
        let mut cards: Vec<(u32, SeenCard, SeenCard)> = things
            .iter()
            .map(|&(id, center)| {
                let faces = if id == self.world.arm_marker {
                    arm_faces
                } else {
                    Facing::Mirror
                };
                (
                    id,
                    self.world.seen_card(center, faces, side),
                    self.world.seen_card(center, faces, MARKER_SIZE_MM),
                )
            })
            .collect();
        for (k, out) in [left, right].into_iter().enumerate() {
            let cam = self.world.rig.cameras[k];
            self.canvas
                .set_to(&Scalar::all(BACKGROUND), &core::no_array())?;
            // Painter's order: what the camera sees farthest (a reflection is as
            // far as its virtual position) is drawn first.
            cards.sort_by(|a, b| cam.depth(&b.1.center).total_cmp(&cam.depth(&a.1.center)));
            for (id, card, code) in &cards {
                let texture = &self
                    .textures
                    .iter()
                    .find(|t| t.0 == *id)
                    .expect("texture per id")
                    .1;
                let behind_glass = !card.mirrored
                    || self.world.mirror.is_some_and(|m| {
                        card.corners
                            .iter()
                            .all(|c| m.ray_hits_glass(&cam.center, c))
                    });
                if behind_glass && warp_card(&mut self.canvas, texture, &cam, &card.corners)? {
                    let mut px = [Vector2::zeros(); 4];
                    for (p, c) in px.iter_mut().zip(&code.corners) {
                        *p = cam.project(c)?;
                    }
                    truth.markers[k].push((*id, card.mirrored, px));
                }
            }
            let intr = cam.intrinsics;
            let mut dst =
                Mat::new_rows_cols_with_data_mut(intr.height as i32, intr.width as i32, out)?;
            imgproc::remap(
                &self.canvas,
                &mut dst,
                &self.maps[k].0,
                &self.maps[k].1,
                imgproc::INTER_LINEAR,
                core::BORDER_REPLICATE,
                Scalar::default(),
            )?;
            degrade(
                &mut dst,
                self.world.noise,
                seq.wrapping_mul(2).wrapping_add(k as u64),
            )?;
        }
        Ok(truth)
    }
}

/// Warps a card texture onto the ideal canvas at the projections of its
/// corners; returns whether the card is in view (and so drawn).
fn warp_card(
    canvas: &mut Mat,
    texture: &Mat,
    cam: &Camera,
    corners: &[Vector3<f64>; 4],
) -> Result<bool> {
    let k = cam.intrinsics.k();
    let mut ideal = Vector::<Point2f>::new();
    let mut distorted = [Vector2::zeros(); 4];
    for (i, c) in corners.iter().enumerate() {
        if cam.depth(c) <= 1.0 {
            return Ok(false);
        }
        let xy = cam.normalized(c)?;
        let p = k * Vector3::new(xy.x, xy.y, 1.0);
        ideal.push(Point2f::new(p.x as f32, p.y as f32));
        distorted[i] = cam.project(c)?;
    }
    let inside = distorted.iter().any(|p| cam.intrinsics.contains(p, 0.0));
    if !inside {
        return Ok(false);
    }
    // Shrink the texture (area averaging) to about the card's size on screen:
    // bilinear sampling of a much larger texture aliases the edges.
    let on_screen = (0..4)
        .map(|i| {
            let (a, b) = (
                ideal.get(i).unwrap_or_default(),
                ideal.get((i + 1) % 4).unwrap_or_default(),
            );
            f64::from(((a.x - b.x).powi(2) + (a.y - b.y).powi(2)).sqrt())
        })
        .fold(0.0, f64::max);
    let scale = (on_screen / f64::from(texture.cols())).min(1.0);
    let mut shrunk = Mat::default();
    let texture = if scale < 0.9 {
        let side = ((f64::from(texture.cols()) * scale).round() as i32).max(8);
        imgproc::resize(
            texture,
            &mut shrunk,
            Size::new(side, side),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )?;
        &shrunk
    } else {
        texture
    };
    // Texel centres sit at integer coordinates, so the texture's outer edge is at -0.5.
    let (w, h) = (texture.cols() as f32 - 0.5, texture.rows() as f32 - 0.5);
    let source = Vector::<Point2f>::from_iter([
        Point2f::new(-0.5, -0.5),
        Point2f::new(w, -0.5),
        Point2f::new(w, h),
        Point2f::new(-0.5, h),
    ]);
    let homography = imgproc::get_perspective_transform(&source, &ideal, core::DECOMP_LU)?;
    let size = Size::new(canvas.cols(), canvas.rows());
    let mut out = canvas.clone();
    imgproc::warp_perspective(
        texture,
        &mut out,
        &homography,
        size,
        imgproc::INTER_LINEAR,
        core::BORDER_TRANSPARENT,
        Scalar::default(),
    )?;
    *canvas = out;
    Ok(true)
}

/// For every output (distorted) pixel, the ideal pixel it shows.
fn distortion_maps(cam: &Camera) -> Result<(Mat, Mat)> {
    let intr = cam.intrinsics;
    let (w, h) = (intr.width as i32, intr.height as i32);
    let mut map_x = Mat::new_rows_cols_with_default(h, w, core::CV_32FC1, Scalar::all(-1.0))?;
    let mut map_y = Mat::new_rows_cols_with_default(h, w, core::CV_32FC1, Scalar::all(-1.0))?;
    let k = intr.k();
    for v in 0..h {
        for u in 0..w {
            if let Ok(xy) = intr.undistort_pixel(&Vector2::new(f64::from(u), f64::from(v))) {
                let p = k * Vector3::new(xy.x, xy.y, 1.0);
                *map_x.at_2d_mut::<f32>(v, u)? = p.x as f32;
                *map_y.at_2d_mut::<f32>(v, u)? = p.y as f32;
            }
        }
    }
    Ok((map_x, map_y))
}

/// Blur and additive Gaussian noise, in place, seeded.
fn degrade<M: core::ToInputArray + core::ToOutputArray + MatTraitConst>(
    image: &mut M,
    noise: ImageNoise,
    seed: u64,
) -> Result<()> {
    if noise.blur_sigma > 0.0 {
        let mut blurred = Mat::default();
        imgproc::gaussian_blur(
            &*image,
            &mut blurred,
            Size::new(0, 0),
            noise.blur_sigma,
            0.0,
            core::BORDER_REPLICATE,
        )?;
        blurred.copy_to(image)?;
    }
    if noise.noise_sigma > 0.0 {
        let mut n = Mat::new_rows_cols_with_default(
            image.rows(),
            image.cols(),
            core::CV_16SC1,
            Scalar::default(),
        )?;
        core::set_rng_seed((seed % i32::MAX as u64) as i32)?;
        core::randn(&mut n, &Scalar::all(0.0), &Scalar::all(noise.noise_sigma))?;
        let mut sum = Mat::default();
        core::add(&*image, &n, &mut sum, &core::no_array(), core::CV_8U)?;
        sum.copy_to(image)?;
    }
    Ok(())
}
