//! The still part of the realistic scene, traced once per camera: a lit
//! room with posters, a table, the mirror's glass and frame, and the
//! robot's head and body (seen in the glass). What moves, the arm and the
//! cards, is drawn over it each frame by [`crate::render`].
//!
//! World frame as in `geometry`: x right, y down, z forward from the head,
//! millimetres. Light is a ceiling lamp, a window on the left and ambient
//! light; there are no shadows.

use crate::Result;
use geometry::Camera;
use geometry::sim::{Mirror, ROBOT_BODY_MM, line_through_box};
use nalgebra::{Vector2, Vector3};
use opencv::core::{self, Mat, Point, Scalar};
use opencv::prelude::*;
use opencv::{aruco, imgproc};

use crate::look::Look;

/// Where the lamp hangs, mm, its strength and the distance it is rated at.
const LAMP: ([f64; 3], f64, f64) = ([200.0, -1250.0, 700.0], 0.9, 1500.0);
/// Direction towards the window's light (from the left, above, ahead) and its strength.
const WINDOW: ([f64; 3], f64) = ([-0.85, -0.4, 0.3], 0.35);
/// Light reaching every surface.
const AMBIENT: f64 = 0.4;
/// The room: x, y (ceiling to floor) and z extents, mm.
const ROOM: [[f64; 2]; 3] = [[-1600.0, 1600.0], [-1300.0, 1200.0], [-1400.0, 2600.0]];
/// The table the mirror stands on.
const TABLE: [[f64; 2]; 3] = [[-800.0, 800.0], [430.0, 460.0], [-400.0, 900.0]];
/// The robot's head around the cameras, neck and torso.
const HEAD: [[f64; 2]; 3] = ROBOT_BODY_MM[0];
const NECK: [[f64; 2]; 3] = ROBOT_BODY_MM[1];
const TORSO: [[f64; 2]; 3] = ROBOT_BODY_MM[2];
/// Width of the mirror's frame around the glass, mm.
const FRAME_MM: f64 = 35.0;
/// Rays traced per pixel side (supersampling).
const SUBSAMPLES: usize = 2;

/// How bright light makes a surface at `p` with normal `n` (1: the
/// reference illumination of [`Look::exposure_dn`]).
pub fn irradiance(p: &Vector3<f64>, n: &Vector3<f64>) -> f64 {
    let lamp = Vector3::from(LAMP.0) - p;
    let d = lamp.norm();
    let lamp_light = LAMP.1 * (n.dot(&lamp) / d).max(0.0) * (LAMP.2 / d).powi(2);
    let window = Vector3::from(WINDOW.0).normalize();
    AMBIENT + lamp_light.min(1.5) + WINDOW.1 * n.dot(&window).max(0.0)
}

/// A printed picture on a wall: the wall, its centre on the wall (u, v),
/// its width, and the picture (reflectance, row-major).
struct Poster {
    wall: Face,
    center: [f64; 2],
    width: f64,
    picture: Picture,
}

/// A reflectance image.
pub struct Picture {
    /// Texels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Reflectances, row-major.
    pub texels: Vec<f32>,
}

impl Picture {
    /// From an 8-bit grey image: 0 -> `black`, 255 -> `white`.
    pub fn from_mat(mat: &Mat, black: f64, white: f64) -> Result<Self> {
        let (width, height) = (mat.cols() as usize, mat.rows() as usize);
        let span = (white - black) / 255.0;
        let texels = mat
            .data_bytes()?
            .iter()
            .map(|&t| (black + span * f64::from(t)) as f32)
            .collect();
        Ok(Self {
            width,
            height,
            texels,
        })
    }

    /// Bilinear sample at texel coordinates (centres at integers), with
    /// zero outside: (premultiplied reflectance, coverage).
    #[inline]
    pub fn sample(&self, u: f32, v: f32) -> (f32, f32) {
        let (w, h) = (self.width as f32, self.height as f32);
        // Wholly outside (beyond the half-texel fringe): nothing.
        if !(u > -1.0 && v > -1.0 && u < w && v < h) {
            return (0.0, 0.0);
        }
        // Shifted by one so truncation floors.
        let (x0, y0) = ((u + 1.0) as usize, (v + 1.0) as usize);
        let (fx, fy) = (u + 1.0 - x0 as f32, v + 1.0 - y0 as f32);
        let weights = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        // All four taps inside, as for most of a card's pixels: no checks
        // (the same sums in the same order as below).
        if x0 >= 1 && y0 >= 1 && x0 < self.width && y0 < self.height {
            let i = (y0 - 1) * self.width + (x0 - 1);
            let t = &self.texels;
            let taps = [t[i], t[i + 1], t[i + self.width], t[i + self.width + 1]];
            let (mut value, mut cover) = (0.0, 0.0);
            for (texel, weight) in taps.into_iter().zip(weights) {
                value += weight * texel;
                cover += weight;
            }
            return (value, cover);
        }
        let at = |x: usize, y: usize| -> Option<f32> {
            (x >= 1 && y >= 1 && x <= self.width && y <= self.height)
                .then(|| self.texels[(y - 1) * self.width + (x - 1)])
        };
        let taps = [
            (at(x0, y0), weights[0]),
            (at(x0 + 1, y0), weights[1]),
            (at(x0, y0 + 1), weights[2]),
            (at(x0 + 1, y0 + 1), weights[3]),
        ];
        let (mut value, mut cover) = (0.0, 0.0);
        for (texel, weight) in taps {
            if let Some(t) = texel {
                value += weight * t;
                cover += weight;
            }
        }
        (value, cover)
    }

    /// Nearest texel at (u, v) in [0, 1)^2, or `None` outside.
    fn at(&self, u: f64, v: f64) -> Option<f64> {
        if !(0.0..1.0).contains(&u) || !(0.0..1.0).contains(&v) {
            return None;
        }
        let (x, y) = (
            (u * self.width as f64) as usize,
            (v * self.height as f64) as usize,
        );
        Some(f64::from(self.texels[y * self.width + x]))
    }
}

/// Which surface of the room a ray meets.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Face {
    /// The wall behind the mirror (z max), seen directly.
    Far,
    /// The wall behind the robot (z min), seen in the mirror.
    Near,
    Left,
    Right,
    Floor,
    Ceiling,
}

/// A smooth pseudo-random field in [0, 1) over the plane (value noise).
fn value_noise(x: f64, y: f64, seed: u32) -> f64 {
    let hash = |i: i64, j: i64| -> f64 {
        let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ u64::from(seed).wrapping_mul(0x1656_67B1_9E37_79F9);
        h ^= h >> 29;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 32;
        (h >> 11) as f64 / (1u64 << 53) as f64
    };
    let (i, j) = (x.floor(), y.floor());
    let (fx, fy) = (x - i, y - j);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (i, j) = (i as i64, j as i64);
    let top = hash(i, j) + (hash(i + 1, j) - hash(i, j)) * sx;
    let bottom = hash(i, j + 1) + (hash(i + 1, j + 1) - hash(i, j + 1)) * sx;
    top + (bottom - top) * sy
}

/// What a traced ray found.
struct Hit {
    /// Radiance towards the camera, in units of the reference white.
    radiance: f64,
    /// The first thing it met was the glass.
    glass: bool,
}

/// The room, the robot's still parts and the mirror, for tracing.
pub struct Room {
    mirror: Option<Mirror>,
    eyes: [Vector3<f64>; 2],
    posters: Vec<Poster>,
    reflectance: f64,
}

/// Where a ray meets an axis-aligned box from outside (entry distance and
/// the entry face's normal), if it does beyond `t_min`.
fn enter_box(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    b: &[[f64; 2]; 3],
    t_min: f64,
) -> Option<(f64, Vector3<f64>)> {
    let (t0, _, axis) = line_through_box(o, d, b)?;
    if t0 <= t_min {
        return None;
    }
    let mut n = Vector3::zeros();
    n[axis] = -d[axis].signum();
    Some((t0, n))
}

impl Room {
    /// The room around `mirror` for a head whose cameras sit at `eyes`.
    pub fn new(mirror: Option<Mirror>, eyes: [Vector3<f64>; 2], look: &Look) -> Result<Self> {
        let [black, white] = look.paper;
        let marker = |dictionary, id: i32, modules: i32| -> Result<Picture> {
            let dict = aruco::get_predefined_dictionary(dictionary)?;
            let side = (modules + 2) * 12;
            let mut code = Mat::default();
            aruco::draw_marker(&dict, id, side - 48, &mut code, 1)?;
            let mut framed = Mat::default();
            core::copy_make_border(
                &code,
                &mut framed,
                24,
                24,
                24,
                24,
                core::BORDER_CONSTANT,
                Scalar::all(255.0),
            )?;
            Picture::from_mat(&framed, black, white)
        };
        use aruco::PREDEFINED_DICTIONARY_NAME as D;
        let posters = vec![
            Poster {
                wall: Face::Far,
                center: [-700.0, -350.0],
                width: 420.0,
                picture: checkerboard(9, 6, black, white)?,
            },
            Poster {
                wall: Face::Far,
                center: [650.0, -250.0],
                width: 220.0,
                picture: marker(D::DICT_6X6_250, 23, 6)?,
            },
            Poster {
                wall: Face::Far,
                center: [150.0, -650.0],
                width: 500.0,
                picture: text_sheet(black, white)?,
            },
            Poster {
                wall: Face::Near,
                center: [-350.0, -250.0],
                width: 200.0,
                picture: marker(D::DICT_5X5_100, 4, 5)?,
            },
            Poster {
                wall: Face::Near,
                center: [300.0, -300.0],
                width: 240.0,
                picture: marker(D::DICT_APRILTAG_36h11, 11, 8)?,
            },
            Poster {
                wall: Face::Near,
                center: [0.0, 150.0],
                width: 600.0,
                picture: text_sheet(black, white)?,
            },
            Poster {
                wall: Face::Near,
                center: [-900.0, -100.0],
                width: 360.0,
                picture: checkerboard(7, 5, black, white)?,
            },
        ];
        Ok(Self {
            mirror,
            eyes,
            posters,
            reflectance: look.reflectance,
        })
    }

    /// Radiance of the room along the ray from `o` in direction `d`.
    fn trace(&self, o: &Vector3<f64>, d: &Vector3<f64>, bounce: u32) -> Hit {
        const EPS: f64 = 1e-6;
        let mut best: Option<(f64, Vector3<f64>, &'static str)> = None;
        let mut consider = |t: f64, n: Vector3<f64>, what: &'static str| {
            if t > EPS && best.is_none_or(|(b, _, _)| t < b) {
                best = Some((t, n, what));
            }
        };
        for (b, name) in [(&TABLE, "table"), (&TORSO, "torso"), (&NECK, "neck")] {
            if let Some((t, n)) = enter_box(o, d, b, EPS) {
                consider(t, n, name);
            }
        }
        // The cameras sit inside the head: only reflections see it.
        if let (true, Some((t, n))) = (bounce > 0, enter_box(o, d, &HEAD, EPS)) {
            consider(t, n, "head");
        }
        // The room's walls, from inside.
        let mut wall = (f64::INFINITY, Face::Far);
        for (k, faces) in [
            (0, [Face::Left, Face::Right]),
            (1, [Face::Ceiling, Face::Floor]),
            (2, [Face::Near, Face::Far]),
        ] {
            if d[k].abs() > 1e-12 {
                let side = usize::from(d[k] > 0.0);
                let t = (ROOM[k][side] - o[k]) / d[k];
                if t > EPS && t < wall.0 {
                    wall = (t, faces[side]);
                }
            }
        }
        let mut glass_hit = None;
        if let Some(m) = &self.mirror {
            let dn = d.dot(&m.plane.normal);
            let dist = m.plane.signed_distance(o);
            if dn < 0.0 && dist > 0.0 {
                let t = dist / -dn;
                let p = o + d * t;
                let (u, v) = in_mirror(m, &p);
                let (hw, hh) = (m.size.x / 2.0, m.size.y / 2.0);
                if u.abs() <= hw && v.abs() <= hh {
                    glass_hit = Some(t);
                } else if u.abs() <= hw + FRAME_MM && v.abs() <= hh + FRAME_MM {
                    consider(t, m.plane.normal.into_inner(), "frame");
                }
            }
        }
        let nearest = best.map_or(f64::INFINITY, |b| b.0).min(wall.0);
        if let (Some(t), Some(m)) = (glass_hit, &self.mirror)
            && t < nearest
            && bounce < 2
        {
            let p = o + d * t;
            let n = m.plane.normal.into_inner();
            let r = d - 2.0 * d.dot(&n) * n;
            let behind = self.trace(&p, &r, bounce + 1);
            return Hit {
                radiance: self.reflectance * behind.radiance,
                glass: true,
            };
        }
        let radiance = match best {
            Some((t, n, what)) if t <= wall.0 => {
                let p = o + d * t;
                let albedo = match what {
                    "table" => 0.45 + 0.06 * value_noise(p.x / 6.0, p.z / 300.0, 3),
                    "frame" => 0.12 + 0.04 * value_noise(p.x / 20.0, p.y / 20.0, 4),
                    "head" => self.head_albedo(&p, &n),
                    _ => 0.5,
                };
                albedo * irradiance(&p, &n)
            }
            _ => {
                let p = o + d * wall.0;
                let (albedo, n, emits) = self.wall(wall.1, &p);
                albedo * irradiance(&p, &n) + emits
            }
        };
        Hit {
            radiance,
            glass: false,
        }
    }

    /// The head's shell, with the camera lenses dark on its front.
    fn head_albedo(&self, p: &Vector3<f64>, n: &Vector3<f64>) -> f64 {
        if n.z > 0.5 {
            for eye in &self.eyes {
                let r = Vector2::new(p.x - eye.x, p.y - eye.y).norm();
                if r < 7.0 {
                    return 0.03;
                }
                if r < 13.0 {
                    return 0.15;
                }
            }
        }
        0.78
    }

    /// Reflectance, outward normal and emitted light of a wall point.
    fn wall(&self, face: Face, p: &Vector3<f64>) -> (f64, Vector3<f64>, f64) {
        let (n, u, v) = match face {
            Face::Far => (-Vector3::z(), p.x, p.y),
            Face::Near => (Vector3::z(), p.x, p.y),
            Face::Left => (Vector3::x(), p.z, p.y),
            Face::Right => (-Vector3::x(), p.z, p.y),
            Face::Floor => (-Vector3::y(), p.x, p.z),
            Face::Ceiling => (Vector3::y(), p.x, p.z),
        };
        for poster in self.posters.iter().filter(|q| q.wall == face) {
            let height = poster.width * poster.picture.height as f64 / poster.picture.width as f64;
            let pu = (u - poster.center[0]) / poster.width + 0.5;
            let pv = (v - poster.center[1]) / height + 0.5;
            if let Some(r) = poster.picture.at(pu, pv) {
                return (r, n, 0.0);
            }
        }
        let plaster = 0.62
            + 0.06 * value_noise(u / 400.0, v / 400.0, 1)
            + 0.03 * value_noise(u / 9.0, v / 9.0, 2);
        match face {
            // Wooden planks, 150 mm wide, each a little different.
            Face::Floor => {
                let plank = (u / 150.0).floor();
                let grain = 0.05 * value_noise(u / 4.0, v / 180.0, 5);
                (0.3 + 0.08 * value_noise(plank, 0.5, 6) + grain, n, 0.0)
            }
            // A window: bright, and its light comes into the room.
            Face::Left if (300.0..1500.0).contains(&u) && (-900.0..100.0).contains(&v) => {
                let mullion = (u - 900.0).abs() < 20.0 || (v + 400.0).abs() < 20.0;
                if mullion {
                    (0.8, n, 0.0)
                } else {
                    (0.0, n, 1.6 + 0.2 * value_noise(u / 200.0, v / 200.0, 7))
                }
            }
            // A skirting board along the bottom of the walls.
            Face::Far | Face::Near | Face::Left | Face::Right if v > 1100.0 => (0.85, n, 0.0),
            Face::Ceiling => (0.85, n, 0.0),
            _ => (plaster, n, 0.0),
        }
    }

    /// Traces every pixel of `camera` whose undistorted normalised
    /// coordinates are `rays` (NaN where the lens model has none): the
    /// room's radiance (reference white = 1) and the fraction of each
    /// pixel that shows the glass.
    pub fn trace_image(&self, camera: &Camera, rays: &[[f32; 2]]) -> (Vec<f32>, Vec<f32>) {
        let (w, h) = (
            camera.intrinsics.width as usize,
            camera.intrinsics.height as usize,
        );
        let world_from_camera = camera.camera_from_world.transpose();
        let at = |x: usize, y: usize| -> Option<Vector2<f64>> {
            let r = rays[y.min(h - 1) * w + x.min(w - 1)];
            r[0].is_finite()
                .then(|| Vector2::new(f64::from(r[0]), f64::from(r[1])))
        };
        let mut radiance = vec![0f32; w * h];
        let mut glass = vec![0f32; w * h];
        let s = SUBSAMPLES as f64;
        for y in 0..h {
            for x in 0..w {
                let (Some(c), Some(right), Some(down)) = (at(x, y), at(x + 1, y), at(x, y + 1))
                else {
                    continue;
                };
                // Sub-pixel rays by the local (linear) change of the lens map.
                let (du, dv) = (right - c, down - c);
                let (mut sum, mut seen) = (0.0, 0.0);
                for i in 0..SUBSAMPLES {
                    for j in 0..SUBSAMPLES {
                        let (fu, fv) = ((i as f64 + 0.5) / s - 0.5, (j as f64 + 0.5) / s - 0.5);
                        let xy = c + du * fu + dv * fv;
                        let d = (world_from_camera * Vector3::new(xy.x, xy.y, 1.0)).normalize();
                        let hit = self.trace(&camera.center, &d, 0);
                        sum += hit.radiance;
                        seen += f64::from(u8::from(hit.glass));
                    }
                }
                radiance[y * w + x] = (sum / (s * s)) as f32;
                glass[y * w + x] = (seen / (s * s)) as f32;
            }
        }
        (radiance, glass)
    }
}

/// Coordinates of a point of the mirror's plane along its width and height from its centre.
fn in_mirror(m: &Mirror, p: &Vector3<f64>) -> (f64, f64) {
    let height_axis = m.plane.normal.cross(&m.width_axis);
    let off = p - m.center;
    (off.dot(&m.width_axis), off.dot(&height_axis))
}

/// A checkerboard of `cols` x `rows` squares with a white margin.
fn checkerboard(cols: i32, rows: i32, black: f64, white: f64) -> Result<Picture> {
    let square = 16;
    let mut board = Mat::new_rows_cols_with_default(
        (rows + 2) * square,
        (cols + 2) * square,
        core::CV_8UC1,
        Scalar::all(255.0),
    )?;
    for r in 0..rows {
        for c in 0..cols {
            if (r + c) % 2 == 0 {
                let rect = core::Rect::new((c + 1) * square, (r + 1) * square, square, square);
                imgproc::rectangle(
                    &mut board,
                    rect,
                    Scalar::all(0.0),
                    imgproc::FILLED,
                    imgproc::LINE_8,
                    0,
                )?;
            }
        }
    }
    Picture::from_mat(&board, black, white)
}

/// A printed page of text: a title and lines of words.
fn text_sheet(black: f64, white: f64) -> Result<Picture> {
    let mut page = Mat::new_rows_cols_with_default(300, 420, core::CV_8UC1, Scalar::all(255.0))?;
    let lines = [
        "MIRROR LAB",
        "Safety rules for the robot cell",
        "1. Keep the area clear while",
        "   the arm is moving.",
        "2. Report broken glass at once.",
        "3. Calibrate after every move",
        "   of the mirror stand.",
        "Room 2.14  ext. 4471",
    ];
    for (i, line) in lines.iter().enumerate() {
        let scale = if i == 0 { 1.3 } else { 0.62 };
        let thickness = if i == 0 { 3 } else { 1 };
        imgproc::put_text(
            &mut page,
            line,
            Point::new(18, 46 + 34 * i as i32),
            imgproc::FONT_HERSHEY_SIMPLEX,
            scale,
            Scalar::all(0.0),
            thickness,
            imgproc::LINE_AA,
            false,
        )?;
    }
    Picture::from_mat(&page, black, white)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn light_falls_on_surfaces_turned_to_it() {
        let p = Vector3::new(0.0, 150.0, 400.0);
        let up = -Vector3::y();
        assert!(irradiance(&p, &up) > irradiance(&p, &Vector3::y()));
        assert!(irradiance(&p, &Vector3::y()) >= AMBIENT);
    }

    #[test]
    fn a_ray_into_a_box_enters_at_its_face() {
        let b = [[-1.0, 1.0], [-1.0, 1.0], [4.0, 6.0]];
        let (t, n) = enter_box(&Vector3::zeros(), &Vector3::z(), &b, 0.0).unwrap();
        assert!((t - 4.0).abs() < 1e-12);
        assert_eq!(n, -Vector3::z());
        assert!(enter_box(&Vector3::zeros(), &Vector3::x(), &b, 0.0).is_none());
    }
}
