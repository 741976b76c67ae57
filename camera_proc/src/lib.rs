//! The camera stage: a renderer of what the simulated head sees
//! ([`render`], the still scene in [`room`], the camera in [`sensor`], its
//! settings a [`look::Look`]), readers of real footage ([`source`]), the frame schedule
//! ([`clock`]) and the loops that publish frames ([`stage`]).
//!
//! ```no_run
//! use camera_proc::render::Renderer;
//! use geometry::sim::{Facing, SimWorld};
//! let world = SimWorld::nico(0)?;
//! let mut renderer = Renderer::new(world)?;
//! let (mut left, mut right) = (vec![0u8; 640 * 480], vec![0u8; 640 * 480]);
//! renderer.render(&[0.8, 0.1, 0.2, -0.4], Facing::Mirror, 1, &mut left, &mut right)?;
//! # Ok::<(), anyhow::Error>(())
//! ```

pub mod clock;
pub mod look;
pub mod render;
pub mod room;
pub mod sensor;
pub mod snapshot;
pub mod source;
pub mod stage;
