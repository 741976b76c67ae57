//! The pipeline's results on a ROS 2 graph: each calibration revision as
//! `/tf_static` (TRANSIENT_LOCAL, so a node started later still gets it),
//! with the frame names of `mirror_proc export` and the live view, and
//! each located object as a `geometry_msgs/PointStamped`. Millimetres
//! become metres; our monotonic stamps become ROS (wall-clock) time.

use std::ops::ControlFlow;

use formats::export::{CAMERA_FRAMES, MIRROR_CAMERA_FRAMES, MIRROR_FRAME, WORLD_FRAME};
use geometry::Rig;
use messages::{CalibrationMsg, LocatedObject, topics};
use nalgebra::Isometry3;
use runtime::BusError;
use runtime::stats::StageStats;
use stages::ros2::Ros2Tf;

use crate::clock;
use crate::msgs::{
    Header, Point, PointStamped, Quaternion, TfMessage, Time, Transform, TransformStamped, Vector3,
};
use crate::node::{Node, Ros2Error};
use crate::wire::Qos;

/// What stops the stage.
#[derive(Debug, thiserror::Error)]
pub enum TfError {
    /// The pipeline's bus.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The graph.
    #[error(transparent)]
    Ros2(#[from] Ros2Error),
}

/// Where the results go.
#[derive(Debug, Clone)]
pub struct TfOptions {
    /// The pipeline's prefix.
    pub prefix: String,
    /// The latched transforms' topic.
    pub tf_static: String,
    /// The located objects' topic.
    pub located: String,
}

fn header(wall_ns: i64) -> Header {
    Header {
        stamp: Time::from_ns(wall_ns),
        frame_id: WORLD_FRAME.into(),
    }
}

fn transform(wall_ns: i64, child: &str, pose: &Isometry3<f64>) -> TransformStamped {
    let t = pose.translation.vector * 1e-3;
    let q = pose.rotation;
    TransformStamped {
        header: header(wall_ns),
        child_frame_id: child.into(),
        transform: Transform {
            translation: Vector3 {
                x: t.x,
                y: t.y,
                z: t.z,
            },
            rotation: Quaternion {
                x: q.i,
                y: q.j,
                z: q.k,
                w: q.w,
            },
        },
    }
}

/// A calibration's frames relative to the world: the mirror plane (if
/// solved), both mirror cameras and both real cameras. `/tf_static` keeps
/// one transform per child frame, so each revision sends them all.
/// Stamped `wall_ns`: the calibration's stamp on the wall clock.
pub fn transforms_of(c: &CalibrationMsg, rig: &Rig, wall_ns: i64) -> TfMessage {
    let mut transforms = Vec::new();
    if c.has_plane != 0 {
        let normal = nalgebra::Vector3::new(c.plane[0], c.plane[1], c.plane[2]);
        if let Ok(plane) = geometry::Plane::new(normal, c.plane[3]) {
            transforms.push(transform(wall_ns, MIRROR_FRAME, &plane.world_from_plane()));
        }
    }
    for k in 0..2 {
        let mirror_camera = c.cameras[k].to_camera(rig.cameras[k].intrinsics);
        transforms.push(transform(
            wall_ns,
            MIRROR_CAMERA_FRAMES[k],
            &mirror_camera.world_from_camera(),
        ));
        transforms.push(transform(
            wall_ns,
            CAMERA_FRAMES[k],
            &rig.cameras[k].world_from_camera(),
        ));
    }
    TfMessage { transforms }
}

/// A located object as a point in the world frame, m, stamped `wall_ns`
/// (its stamp on the wall clock).
pub fn point_of(o: &LocatedObject, wall_ns: i64) -> PointStamped {
    PointStamped {
        header: header(wall_ns),
        point: Point {
            x: o.position[0] * 1e-3,
            y: o.position[1] * 1e-3,
            z: o.position[2] * 1e-3,
        },
    }
}

/// Runs until SIGINT/SIGTERM.
pub fn run(node: &Node, rig: &Rig, options: &TfOptions) -> Result<(), TfError> {
    let tf = node.publisher::<TfMessage>(&options.tf_static, Qos::LATCHED)?;
    let points = node.publisher::<PointStamped>(&options.located, Qos::reliable(10))?;
    let bus = stages::bus_of::<Ros2Tf>(&options.prefix)?;
    let calibrations = bus.subscriber::<topics::Calibration>()?;
    let located = bus.subscriber::<topics::Located>()?;
    let mut stats = StageStats::new("ros2_tf");
    let (mut revisions, mut objects) = (0u64, 0u64);
    bus.wake()?.run(
        &[calibrations.listener(), located.listener()],
        None,
        || -> Result<_, TfError> {
            while let Some(c) = calibrations.receive()? {
                tf.publish(&transforms_of(&c, rig, clock::to_wall(c.stamp_ns)))?;
                revisions += 1;
                tracing::info!(
                    revision = c.revision,
                    topic = tf.topic(),
                    "calibration published"
                );
            }
            while let Some(o) = located.receive()? {
                points.publish(&point_of(&o, clock::to_wall(o.stamp_ns)))?;
                objects += 1;
            }
            Ok(ControlFlow::Continue(()))
        },
    )?;
    stats.count("calibrations_published", revisions);
    stats.count("located_published", objects);
    stats.finish();
    Ok(())
}
