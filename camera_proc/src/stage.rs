//! The camera stage's loops: frames rendered or decoded straight into
//! loaned shared memory and published, on the [`FrameClock`]'s schedule.

use std::ops::ControlFlow;
use std::time::Duration;

use messages::{Encoding, FrameHeader, JointPositions, Role, now_ns, topics};
use runtime::Bus;

use crate::CameraError;
use crate::clock::FrameClock;
use crate::source::StereoSource;
use geometry::sim::{Facing, SimWorld, WorldChange};
use renderer::Renderer;
use renderer::look::Look;
use stages::camera::ChangeAt;

fn header(seq: u64, width: u32, height: u32) -> FrameHeader {
    FrameHeader {
        seq,
        stamp_ns: now_ns(),
        published_ns: 0,
        width,
        height,
        stride: width,
        encoding: Encoding::Mono8 as u32,
    }
}

/// Direct test poses turn the card to the head; all others to the mirror.
fn facing(role: u32) -> Facing {
    if role == Role::Direct as u32 {
        Facing::Head
    } else {
        Facing::Mirror
    }
}

/// Joint speeds (rad/s) between two position messages of the arm, if they
/// are close enough in time (100 ms) to say how it moves now.
fn joint_velocity(last: &JointPositions, now: &JointPositions) -> Option<Vec<f64>> {
    let dt = (now.stamp_ns - last.stamp_ns) as f64 * 1e-9;
    (dt > 0.0 && dt <= 0.1).then(|| {
        now.joints()
            .iter()
            .zip(last.joints())
            .map(|(a, b)| (a - b) / dt)
            .collect()
    })
}

/// The world after each of `changes`, in turn: the first is `world`.
fn worlds(world: SimWorld, changes: &[ChangeAt]) -> Result<Vec<SimWorld>, CameraError> {
    let mut worlds = vec![world];
    for c in changes {
        let change = WorldChange::from(c.change);
        let next = worlds[worlds.len() - 1].changed(&change)?;
        worlds.push(next);
    }
    Ok(worlds)
}

/// The simulated head: renders what it sees at `fps`, the arm where the
/// arm driver's joint positions put it (its card turned as the current pose
/// goal's role says), until `tail_frames` after the goal that ends the plan.
/// From the goal of each of `changes`' poses on, the world is changed so.
/// A rate outside (0, 1000] Hz is a [`CameraError::BadFps`].
pub fn run_sim(
    prefix: &str,
    mirror: usize,
    fps: f64,
    tail_frames: u32,
    look: Look,
    changes: &[ChangeAt],
) -> Result<(), CameraError> {
    if !(fps > 0.0 && fps <= 1000.0) {
        return Err(CameraError::BadFps { fps });
    }
    let world = SimWorld::nico(mirror)?;
    let intr = world.rig.cameras[0].intrinsics;
    let dof = world.rig.arm.as_ref().map_or(0, |a| a.dof());
    // One renderer per world, ready before the first frame: a change
    // takes effect at once, no frame late.
    let mut renderers = worlds(world, changes)?
        .into_iter()
        .map(|w| Renderer::with_look(w, look))
        .collect::<Result<Vec<_>, _>>()?;
    // Changes that have taken effect.
    let mut changed = 0usize;
    let bus = stages::bus_of::<stages::camera::Camera>(prefix)?;
    let frames = bus.frame_publisher::<topics::Frames>(2 * (intr.width * intr.height) as usize)?;
    let joints = bus.subscriber::<topics::JointPositions>()?;
    let goals = bus.subscriber::<topics::PoseGoal>()?;
    let mut latest: Option<JointPositions> = None;
    // The arm's speed from its last two positions, for motion blur.
    let mut velocity: Option<Vec<f64>> = None;
    let (mut role, mut finished) = (Role::Train as u32, false);
    let mut rejections = runtime::Rejections::default();
    let mut order = runtime::StampOrder::default();
    let (mut seq, mut after_done) = (0u64, 0u32);
    let mut clock = FrameClock::new(fps);
    let mut last_published = None::<i64>;
    let mut stats = runtime::stats::StageStats::new("camera_proc");
    tracing::info!(mirror, fps, ?look, "rendering the simulated head");
    // A fine tick keeps frames within a millisecond of their schedule.
    let tick = Duration::from_nanos(clock.period_ns() as u64).min(Duration::from_millis(1));
    bus.wake()?.run(
        &[joints.listener()],
        Some(tick),
        || -> Result<_, CameraError> {
            while let Some(s) = joints.receive()? {
                // Bad positions would render nonsense or fail the render:
                // dropped, and the last good pose kept.
                let checked = s.fault(dof).map_or_else(
                    || order.check(s.stamp_ns).map_err(|behind| behind.to_string()),
                    Err,
                );
                match checked {
                    Err(why) => rejections.reject("joint positions message", s.seq, &why),
                    Ok(()) => {
                        velocity = latest.as_ref().and_then(|last| joint_velocity(last, &s));
                        latest = Some(s);
                    }
                }
            }
            while let Some(g) = goals.receive()? {
                match g.fault(dof) {
                    Some(why) => rejections.reject("pose goal", g.seq, &why),
                    None if g.finished() => finished = true,
                    None => {
                        role = g.role;
                        while changes.get(changed).is_some_and(|c| c.pose == g.pose) {
                            changed += 1;
                            tracing::info!(pose = g.pose, change = %changes[changed - 1], "the world changes");
                        }
                    }
                }
            }
            // Render on the frame clock only; joint-state wake-ups just update the pose.
            let Some(state) = latest else {
                return Ok(ControlFlow::Continue(()));
            };
            if !clock.due(now_ns()) {
                return Ok(ControlFlow::Continue(()));
            }
            let h = header(seq, intr.width, intr.height);
            let _span = tracing::trace_span!("camera_step", seq).entered();
            let cpu = runtime::stats::StepStart::now();
            frames.publish(h, |left, right| {
                renderers[changed]
                    .render_moving(
                        state.joints(),
                        velocity.as_deref(),
                        facing(role),
                        seq,
                        left,
                        right,
                    )
                    .map(|_| true)
            })??;
            stats.cpu_step(cpu);
            // The simulated capture: the frame's stamp to its publication (rendering).
            let published = now_ns();
            stats.record("capture_to_publish", published - h.stamp_ns);
            if let Some(last) = last_published {
                stats.record("frame_interval", published - last);
            }
            last_published = Some(published);
            seq += 1;
            if finished {
                after_done += 1;
            }
            Ok(if after_done <= tail_frames {
                ControlFlow::Continue(())
            } else {
                ControlFlow::Break(())
            })
        },
    )?;
    stats.count("frames", seq);
    stats.count("frames_late", clock.late());
    stats.count("arm_messages_rejected", rejections.count());
    stats.finish();
    tracing::info!(frames = seq, "camera done");
    Ok(())
}

/// How real footage is paced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// One pair every 1/rate seconds (a file at its own rate or `--fps`).
    Rate(f64),
    /// As fast as the source delivers (a live device).
    AsDelivered,
    /// Once `subscribers` subscribers are attached to the frames, each pair
    /// as soon as the slowest of them has room: the services are created
    /// lossless, so no frame is overwritten unread (a file through the
    /// tracker, as replay does with recordings).
    Lockstep {
        /// Subscribers to wait for.
        subscribers: usize,
    },
}

/// How long a lockstep source waits for its subscribers.
const LOCKSTEP_WAIT: Duration = Duration::from_secs(30);

/// Real footage: publishes `source`'s pairs as `pace` says, until it ends.
pub fn run_source(
    prefix: &str,
    mut source: impl StereoSource,
    pace: Pace,
) -> Result<(), CameraError> {
    let (w, h) = source.size();
    let mut bus = Bus::new(prefix, "camera_proc")?;
    if let Pace::Lockstep { .. } = pace {
        bus = bus.lossless();
    }
    let frames = bus.frame_publisher::<topics::Frames>(2 * (w * h) as usize)?;
    if let Pace::Lockstep { subscribers } = pace {
        bus.wait_for_subscribers(topics::TopicId::Frames, subscribers, LOCKSTEP_WAIT, &|| {
            false
        })?;
        tracing::info!(
            subscribers,
            "lockstep: publishing as fast as the subscribers take frames"
        );
    }
    let mut stats = runtime::stats::StageStats::new("camera_proc");
    let mut seq = 0u64;
    let tick = match pace {
        Pace::Rate(f) => Duration::from_secs_f64(1.0 / f),
        Pace::AsDelivered => Duration::from_millis(1),
        // Publishing waits for room; the tick only keeps the loop turning.
        Pace::Lockstep { .. } => Duration::from_micros(50),
    };
    bus.wake()?
        .run(&[], Some(tick), || -> Result<_, CameraError> {
            let cpu = runtime::stats::StepStart::now();
            let more = frames.publish(header(seq, w, h), |left, right| {
                source.next_into(left, right)
            })??;
            stats.cpu_step(cpu);
            Ok(if more {
                seq += 1;
                ControlFlow::Continue(())
            } else {
                ControlFlow::Break(())
            })
        })?;
    stats.count("frames", seq);
    stats.finish();
    Ok(())
}
