//! The viewing channels: Foxglove's well-known schemas (protobuf, from the
//! `foxglove` SDK), derived from the lossless messages, so a recording or
//! the live view opens in Foxglove as two images with overlays and a 3D
//! scene. Lengths are in metres here, as Foxglove expects.

use foxglove::Encode;
use foxglove::messages::{
    CameraCalibration, CircleAnnotation, Color, CubePrimitive, FrameTransform, FrameTransforms,
    ImageAnnotations, Point2, PointsAnnotation, Pose, Quaternion, RawImage, SceneEntity,
    SceneUpdate, SpherePrimitive, TextAnnotation, TextPrimitive, Timestamp, Vector3,
    points_annotation,
};
use geometry::{Camera, Rig};
use messages::{
    CalibrationMsg, CameraMarkers, Encoding, EpochState, FrameHeader, JointState, LocatedObject,
    Moved,
};
use nalgebra::UnitQuaternion;

use crate::channels::Message;

/// The world frame: the robot's base, in which the rig is given.
pub use formats::export::WORLD_FRAME as WORLD;
// The frame names `mirror_proc export` writes, so a viewer shows both alike.
use formats::export::{
    CAMERA_FRAMES as CAMERAS, MIRROR_CAMERA_FRAMES as MIRROR_CAMERAS, MIRROR_FRAME,
};
/// Camera calibration and static transforms are repeated this often (in
/// stamp time) so that a viewer joining late gets them.
const REPEAT_NS: i64 = 1_000_000_000;

/// A viewing channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ViewTopic {
    /// `foxglove.RawImage` of camera 0 or 1.
    Image(usize),
    /// `foxglove.ImageAnnotations`: detected markers of camera 0 or 1.
    Detections(usize),
    /// `foxglove.ImageAnnotations`: predicted marker centres in camera 0 or 1.
    Predictions(usize),
    /// `foxglove.CameraCalibration` of camera 0 or 1.
    CameraInfo(usize),
    /// `foxglove.FrameTransforms`: the head's cameras and the end effector
    /// (from joint states).
    Transforms,
    /// `foxglove.FrameTransforms`: the mirror and the mirror-perspective
    /// cameras (from calibrations).
    MirrorTransforms,
    /// `foxglove.SceneUpdate`: located objects.
    Scene,
    /// `foxglove.SceneUpdate`: the calibrated mirror.
    MirrorScene,
}

impl ViewTopic {
    /// Every viewing channel.
    pub const ALL: [ViewTopic; 12] = [
        ViewTopic::Image(0),
        ViewTopic::Image(1),
        ViewTopic::Detections(0),
        ViewTopic::Detections(1),
        ViewTopic::Predictions(0),
        ViewTopic::Predictions(1),
        ViewTopic::CameraInfo(0),
        ViewTopic::CameraInfo(1),
        ViewTopic::Transforms,
        ViewTopic::MirrorTransforms,
        ViewTopic::Scene,
        ViewTopic::MirrorScene,
    ];

    /// The MCAP / WebSocket topic.
    pub fn name(self) -> String {
        let side = |k: usize| if k == 0 { "left" } else { "right" };
        match self {
            ViewTopic::Image(k) => format!("/camera/{}/image", side(k)),
            ViewTopic::Detections(k) => format!("/camera/{}/detections", side(k)),
            ViewTopic::Predictions(k) => format!("/camera/{}/predictions", side(k)),
            ViewTopic::CameraInfo(k) => format!("/camera/{}/calibration", side(k)),
            ViewTopic::Transforms => "/tf".into(),
            ViewTopic::MirrorTransforms => "/mirror/tf".into(),
            ViewTopic::Scene => "/scene".into(),
            ViewTopic::MirrorScene => "/mirror/scene".into(),
        }
    }

    /// The Foxglove schema of the channel.
    pub fn schema(self) -> foxglove::Schema {
        match self {
            ViewTopic::Image(_) => RawImage::get_schema(),
            ViewTopic::Detections(_) | ViewTopic::Predictions(_) => ImageAnnotations::get_schema(),
            ViewTopic::CameraInfo(_) => CameraCalibration::get_schema(),
            ViewTopic::Transforms | ViewTopic::MirrorTransforms => FrameTransforms::get_schema(),
            ViewTopic::Scene | ViewTopic::MirrorScene => SceneUpdate::get_schema(),
        }
        .expect("Foxglove's schema types carry their schema")
    }

    /// Whether the channel carries state (its latest message is what holds
    /// now, so a viewer joining late needs it) rather than a stream.
    pub fn is_state(self) -> bool {
        matches!(
            self,
            ViewTopic::CameraInfo(_)
                | ViewTopic::Transforms
                | ViewTopic::MirrorTransforms
                | ViewTopic::Scene
                | ViewTopic::MirrorScene
        )
    }

    /// The message encoding (`protobuf`).
    pub fn message_encoding() -> String {
        RawImage::get_message_encoding()
    }
}

/// One encoded viewing message.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewMessage {
    /// Its channel.
    pub topic: ViewTopic,
    /// Log time, ns.
    pub log_time: u64,
    /// Protobuf bytes.
    pub data: Vec<u8>,
}

fn encode(topic: ViewTopic, stamp_ns: i64, message: &impl Encode) -> ViewMessage {
    let mut data = Vec::with_capacity(message.encoded_len().unwrap_or(256));
    message
        .encode(&mut data)
        .expect("a Vec grows to fit the message");
    ViewMessage {
        topic,
        log_time: crate::channels::log_time(stamp_ns),
        data,
    }
}

fn timestamp(stamp_ns: i64) -> Option<Timestamp> {
    let ns = stamp_ns.max(0);
    Some(Timestamp::new(
        (ns / 1_000_000_000).min(u32::MAX as i64) as u32,
        (ns % 1_000_000_000) as u32,
    ))
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Option<Color> {
    Some(Color { r, g, b, a })
}

/// Markers seen directly are green, mirror-reversed ones magenta.
fn marker_color(mirrored: bool) -> Option<Color> {
    if mirrored {
        color(1.0, 0.0, 1.0, 1.0)
    } else {
        color(0.1, 0.9, 0.2, 1.0)
    }
}

fn metres(v: &nalgebra::Vector3<f64>) -> Option<Vector3> {
    Some(Vector3 {
        x: v.x / 1000.0,
        y: v.y / 1000.0,
        z: v.z / 1000.0,
    })
}

fn quaternion(q: &UnitQuaternion<f64>) -> Option<Quaternion> {
    Some(Quaternion {
        x: q.i,
        y: q.j,
        z: q.k,
        w: q.w,
    })
}

/// World-from-camera transform of a camera; `None` if its rotation is not
/// proper (Foxglove frames are right-handed).
fn camera_transform(stamp_ns: i64, child: &str, camera: &Camera) -> Option<FrameTransform> {
    Some(frame_transform(
        stamp_ns,
        child,
        &camera.world_from_camera(),
    ))
}

fn frame_transform(stamp_ns: i64, child: &str, pose: &nalgebra::Isometry3<f64>) -> FrameTransform {
    FrameTransform {
        timestamp: timestamp(stamp_ns),
        parent_frame_id: WORLD.into(),
        child_frame_id: child.into(),
        translation: metres(&pose.translation.vector),
        rotation: quaternion(&pose.rotation),
    }
}

/// Builds the viewing messages from the lossless ones. Each viewing channel
/// depends on one lossless channel only (and the rig), so a replay gives the
/// same viewing messages whatever order the topics arrive in.
pub struct ViewBuilder {
    rig: Option<Rig>,
    last_repeat_ns: Option<i64>,
    /// Whether raw images are derived from frames (they double the bytes).
    pub images: bool,
}

impl ViewBuilder {
    /// A builder for a pipeline with this rig, if known (camera
    /// calibrations, camera frames and the arm need it).
    pub fn new(rig: Option<Rig>) -> Self {
        Self {
            rig,
            last_repeat_ns: None,
            images: true,
        }
    }

    /// The viewing messages derived from one recorded message.
    pub fn view(&mut self, message: &Message<'_>) -> Vec<ViewMessage> {
        let mut out = Vec::new();
        match message {
            Message::Frames(header, pixels) if self.images => {
                Self::images(header, pixels, &mut out);
            }
            Message::Detections(d) => {
                for k in 0..2 {
                    out.push(encode(
                        ViewTopic::Detections(k),
                        d.stamp_ns,
                        &detections(d.stamp_ns, &d.cameras[k]),
                    ));
                }
            }
            Message::Predictions(p) => {
                for k in 0..2 {
                    let [x, y] = p.predicted_pixels[k];
                    let annotations = ImageAnnotations {
                        timestamp: timestamp(p.stamp_ns),
                        circles: vec![CircleAnnotation {
                            timestamp: timestamp(p.stamp_ns),
                            position: Some(Point2 { x, y }),
                            diameter: 14.0,
                            thickness: 2.0,
                            fill_color: color(0.0, 0.0, 0.0, 0.0),
                            outline_color: color(1.0, 0.85, 0.0, 1.0),
                            metadata: vec![],
                        }],
                        texts: vec![TextAnnotation {
                            timestamp: timestamp(p.stamp_ns),
                            position: Some(Point2 {
                                x: x + 9.0,
                                y: y + 14.0,
                            }),
                            text: format!("predicted, {:.1} px", p.error_px),
                            font_size: 12.0,
                            text_color: color(1.0, 0.85, 0.0, 1.0),
                            background_color: color(0.0, 0.0, 0.0, 0.5),
                            metadata: vec![],
                        }],
                        ..Default::default()
                    };
                    out.push(encode(ViewTopic::Predictions(k), p.stamp_ns, &annotations));
                }
            }
            Message::Calibration(c) => self.calibration(c, &mut out),
            Message::JointState(js) => {
                // Joint states pace the repeats: they come at a steady rate in
                // live runs and in both kinds of replay.
                if self
                    .last_repeat_ns
                    .is_none_or(|last| js.stamp_ns - last >= REPEAT_NS || js.stamp_ns < last)
                {
                    self.last_repeat_ns = Some(js.stamp_ns);
                    self.repeated(js.stamp_ns, &mut out);
                }
                self.arm(js, &mut out)
            }
            Message::Located(l) => out.push(encode(ViewTopic::Scene, l.stamp_ns, &located(l))),
            // Topics without a view (samples; frames when images are off).
            _ => {}
        }
        out
    }

    fn images(header: &FrameHeader, pixels: &[u8], out: &mut Vec<ViewMessage>) {
        let encoding = if header.encoding == Encoding::Bgr8 as u32 {
            "bgr8"
        } else {
            "mono8"
        };
        for (k, image) in pixels.chunks_exact(header.image_len()).take(2).enumerate() {
            let raw = RawImage {
                timestamp: timestamp(header.stamp_ns),
                frame_id: CAMERAS[k].into(),
                width: header.width,
                height: header.height,
                encoding: encoding.into(),
                step: header.stride,
                data: foxglove::bytes::Bytes::copy_from_slice(image),
            };
            out.push(encode(ViewTopic::Image(k), header.stamp_ns, &raw));
        }
    }

    /// Camera calibrations and the head's camera frames.
    fn repeated(&self, stamp: i64, out: &mut Vec<ViewMessage>) {
        let Some(rig) = &self.rig else { return };
        let mut transforms = FrameTransforms::default();
        for k in 0..2 {
            let c = &rig.cameras[k];
            let i = &c.intrinsics;
            let calibration = CameraCalibration {
                timestamp: timestamp(stamp),
                frame_id: CAMERAS[k].into(),
                width: i.width,
                height: i.height,
                distortion_model: i.dist.model().ros_name().into(),
                d: i.dist.coefficients(),
                k: vec![i.fx, i.skew, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0],
                r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                p: vec![
                    i.fx, i.skew, i.cx, 0.0, 0.0, i.fy, i.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
                ],
            };
            out.push(encode(ViewTopic::CameraInfo(k), stamp, &calibration));
            transforms
                .transforms
                .extend(camera_transform(stamp, CAMERAS[k], c));
        }
        out.push(encode(ViewTopic::Transforms, stamp, &transforms));
    }

    fn calibration(&self, c: &CalibrationMsg, out: &mut Vec<ViewMessage>) {
        let Some(rig) = &self.rig else { return };
        let mut transforms = FrameTransforms::default();
        for k in 0..2 {
            let camera = c.cameras[k].to_camera(rig.cameras[k].intrinsics);
            transforms
                .transforms
                .extend(camera_transform(c.stamp_ns, MIRROR_CAMERAS[k], &camera));
        }
        let mut scene = SceneUpdate::default();
        let alert = epoch_alert(c, &rig.names);
        if c.has_plane != 0 {
            let normal = nalgebra::Vector3::new(c.plane[0], c.plane[1], c.plane[2]);
            if let Ok(plane) = geometry::Plane::new(normal, c.plane[3]) {
                transforms.transforms.push(frame_transform(
                    c.stamp_ns,
                    MIRROR_FRAME,
                    &plane.world_from_plane(),
                ));
            }
            scene.entities.push(SceneEntity {
                timestamp: timestamp(c.stamp_ns),
                frame_id: "mirror".into(),
                id: "mirror".into(),
                cubes: vec![CubePrimitive {
                    pose: Some(Pose {
                        position: Some(Vector3::default()),
                        orientation: quaternion(&UnitQuaternion::identity()),
                    }),
                    size: Some(Vector3 {
                        x: 0.6,
                        y: 0.4,
                        z: 0.002,
                    }),
                    // Red while the world has changed under it.
                    color: match &alert {
                        Some((_, true)) => color(1.0, 0.2, 0.1, 0.5),
                        _ => color(0.6, 0.8, 1.0, 0.35),
                    },
                }],
                ..Default::default()
            });
        }
        if let Some((text, raised)) = alert {
            scene.entities.push(SceneEntity {
                timestamp: timestamp(c.stamp_ns),
                frame_id: WORLD.into(),
                id: "calibration state".into(),
                texts: vec![TextPrimitive {
                    pose: Some(Pose {
                        position: Some(Vector3::default()),
                        orientation: quaternion(&UnitQuaternion::identity()),
                    }),
                    billboard: true,
                    font_size: 18.0,
                    scale_invariant: true,
                    color: if raised {
                        color(1.0, 0.25, 0.1, 1.0)
                    } else {
                        color(1.0, 1.0, 1.0, 1.0)
                    },
                    text,
                }],
                ..Default::default()
            });
        }
        out.push(encode(ViewTopic::MirrorTransforms, c.stamp_ns, &transforms));
        if !scene.entities.is_empty() {
            out.push(encode(ViewTopic::MirrorScene, c.stamp_ns, &scene));
        }
    }

    /// The end effector from the joint state through the nominal arm model
    /// (the calibrated offsets are in `/mirror/tf`'s source, the calibration).
    fn arm(&self, js: &JointState, out: &mut Vec<ViewMessage>) {
        let Some(arm) = self.rig.as_ref().and_then(|r| r.arm.as_ref()) else {
            return;
        };
        let Ok(tip) = arm.end_effector(js.joints(), &vec![0.0; arm.dof()]) else {
            return;
        };
        let transforms = FrameTransforms {
            transforms: vec![FrameTransform {
                timestamp: timestamp(js.stamp_ns),
                parent_frame_id: WORLD.into(),
                child_frame_id: "end_effector".into(),
                translation: metres(&tip),
                rotation: quaternion(&UnitQuaternion::identity()),
            }],
        };
        out.push(encode(ViewTopic::Transforms, js.stamp_ns, &transforms));
    }
}

fn detections(stamp_ns: i64, markers: &CameraMarkers) -> ImageAnnotations {
    let mut a = ImageAnnotations {
        timestamp: timestamp(stamp_ns),
        ..Default::default()
    };
    for m in markers.iter() {
        let mirrored = m.mirrored != 0;
        a.points.push(PointsAnnotation {
            timestamp: timestamp(stamp_ns),
            r#type: points_annotation::Type::LineLoop as i32,
            points: m
                .corners
                .chunks_exact(2)
                .map(|c| Point2 { x: c[0], y: c[1] })
                .collect(),
            outline_color: marker_color(mirrored),
            thickness: 2.0,
            ..Default::default()
        });
        a.circles.push(CircleAnnotation {
            timestamp: timestamp(stamp_ns),
            position: Some(Point2 {
                x: m.center[0],
                y: m.center[1],
            }),
            diameter: 6.0,
            thickness: 2.0,
            fill_color: marker_color(mirrored),
            outline_color: marker_color(mirrored),
            metadata: vec![],
        });
        a.texts.push(TextAnnotation {
            timestamp: timestamp(stamp_ns),
            position: Some(Point2 {
                x: m.corners[0],
                y: m.corners[1] - 6.0,
            }),
            text: format!("{}{}", m.id, if mirrored { " (mirrored)" } else { "" }),
            font_size: 12.0,
            text_color: marker_color(mirrored),
            background_color: color(0.0, 0.0, 0.0, 0.5),
            metadata: vec![],
        });
    }
    a
}

fn located(l: &LocatedObject) -> SceneUpdate {
    let position = metres(&nalgebra::Vector3::from(l.position));
    let mut spheres = vec![SpherePrimitive {
        pose: Some(Pose {
            position,
            orientation: quaternion(&UnitQuaternion::identity()),
        }),
        size: Some(Vector3 {
            x: 0.03,
            y: 0.03,
            z: 0.03,
        }),
        color: color(1.0, 0.5, 0.0, 0.9),
    }];
    let mut texts = Vec::new();
    if let Some((orientation, axes_m)) = one_sigma_ellipsoid(l) {
        spheres.push(SpherePrimitive {
            pose: Some(Pose {
                position,
                orientation: quaternion(&orientation),
            }),
            size: Some(Vector3 {
                x: 2.0 * axes_m.x,
                y: 2.0 * axes_m.y,
                z: 2.0 * axes_m.z,
            }),
            color: color(1.0, 0.5, 0.0, 0.2),
        });
        texts.push(TextPrimitive {
            pose: Some(Pose {
                position,
                orientation: quaternion(&UnitQuaternion::identity()),
            }),
            billboard: true,
            font_size: 14.0,
            scale_invariant: true,
            color: color(1.0, 1.0, 1.0, 1.0),
            text: format!("marker {}: ±{:.1} mm (1σ)", l.id, l.sigma_mm()),
        });
    }
    SceneUpdate {
        deletions: vec![],
        entities: vec![SceneEntity {
            timestamp: timestamp(l.stamp_ns),
            frame_id: WORLD.into(),
            id: format!("object {}", l.id),
            spheres,
            texts,
            ..Default::default()
        }],
    }
}

/// What the live view says of a calibration's epoch, and whether it is an
/// alert (the world changed under it): none for the first epoch's
/// calibrations, or a recording made before epochs were stated.
fn epoch_alert(c: &CalibrationMsg, names: &[String; 2]) -> Option<(String, bool)> {
    let e = &c.epoch;
    let what = match e.moved() {
        Some(Moved::Mirror) => "the mirror".to_string(),
        Some(Moved::Camera) => format!(
            "the {} camera",
            names.get(e.camera as usize).map_or("?", String::as_str)
        ),
        Some(Moved::Head) => "the head".into(),
        Some(Moved::Nothing) | None => return None,
    };
    Some(match e.state() {
        Some(EpochState::Drifted) => (
            format!(
                "THE WORLD CHANGED: {what} moved (from pose {}, found at pose {}); calibrating again",
                e.began_at_pose, e.found_at_pose
            ),
            true,
        ),
        Some(EpochState::Stopped) => (
            format!(
                "CALIBRATION STOPPED: {what} moved and could not be calibrated again (the report says why)"
            ),
            true,
        ),
        _ => (
            format!(
                "epoch {}: calibrated again after {what} moved at pose {}",
                e.epoch, e.began_at_pose
            ),
            false,
        ),
    })
}

/// The 1-sigma ellipsoid of a located object's covariance: its orientation
/// and semi-axes in metres, or `None` when no covariance is stated.
fn one_sigma_ellipsoid(l: &LocatedObject) -> Option<(UnitQuaternion<f64>, nalgebra::Vector3<f64>)> {
    let covariance = l.covariance();
    if covariance.iter().all(|v| *v == 0.0) || !covariance.iter().all(|v| v.is_finite()) {
        return None;
    }
    let eigen = covariance.symmetric_eigen();
    let mut axes = eigen.eigenvectors;
    if axes.determinant() < 0.0 {
        axes.set_column(2, &-axes.column(2));
    }
    let orientation =
        UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(axes));
    let semi_axes = eigen.eigenvalues.map(|v| v.max(0.0).sqrt() / 1000.0);
    Some((orientation, semi_axes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use foxglove::Decode;

    #[test]
    fn a_located_objects_ellipsoid_is_its_covariance() {
        // Sigmas 10, 20, 40 mm along axes turned about z and x.
        let turn = nalgebra::Rotation3::from_euler_angles(0.4, 0.0, 0.9);
        let covariance = turn.matrix()
            * nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(100.0, 400.0, 1600.0))
            * turn.matrix().transpose();
        let c = covariance;
        let l = LocatedObject {
            id: 7,
            covariance_mm2: [c.m11, c.m12, c.m13, c.m22, c.m23, c.m33],
            ..Default::default()
        };
        let (orientation, semi_axes) = one_sigma_ellipsoid(&l).unwrap();
        let r = orientation.to_rotation_matrix();
        let back = r.matrix()
            * nalgebra::Matrix3::from_diagonal(&semi_axes.map(|a| (a * 1000.0).powi(2)))
            * r.matrix().transpose();
        assert!((back - covariance).norm() < 1e-6, "{back} vs {covariance}");
        let mut sorted: Vec<f64> = semi_axes.iter().map(|a| a * 1000.0).collect();
        sorted.sort_by(f64::total_cmp);
        assert!((sorted[0] - 10.0).abs() < 1e-9 && (sorted[2] - 40.0).abs() < 1e-9);
        let scene = located(&l);
        let entity = &scene.entities[0];
        assert_eq!(entity.spheres.len(), 2, "the marker and its ellipsoid");
        assert!(
            entity.texts[0].text.contains("±45.8 mm"),
            "{}",
            entity.texts[0].text
        );
        // A recording made before the covariance existed: the marker alone.
        let old = located(&LocatedObject::default());
        assert_eq!(old.entities[0].spheres.len(), 1);
        assert!(old.entities[0].texts.is_empty());
    }

    #[test]
    fn a_drifted_calibration_raises_an_alert_in_the_view() {
        let rig = geometry::sim::nico_scene().rig;
        let view = ViewBuilder::new(Some(rig.clone()));
        let mut c = CalibrationMsg {
            has_plane: 1,
            plane: [0.0, 0.0, -1.0, 600.0],
            ..Default::default()
        };
        let texts = |c: &CalibrationMsg| -> Vec<String> {
            let mut out = Vec::new();
            view.calibration(c, &mut out);
            out.iter()
                .filter(|m| m.topic == ViewTopic::MirrorScene)
                .filter_map(|m| {
                    let scene = SceneUpdate::decode(m.data.as_slice()).ok()?;
                    Some(
                        scene
                            .entities
                            .into_iter()
                            .flat_map(|e| e.texts)
                            .map(|t| t.text),
                    )
                })
                .flatten()
                .collect()
        };
        assert!(texts(&c).is_empty(), "no alert in the first epoch");
        c.epoch = messages::CalibrationEpoch {
            epoch: 1,
            state: EpochState::Drifted as u32,
            moved: Moved::Camera as u32,
            camera: 0,
            began_at_pose: 40,
            found_at_pose: 42,
        };
        let alert = texts(&c);
        assert!(
            alert.len() == 1
                && alert[0].contains("left camera moved (from pose 40, found at pose 42)"),
            "{alert:?}"
        );
    }
}
