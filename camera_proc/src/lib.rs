//! The camera stage: a renderer of what the simulated head sees
//! ([`render`]) and readers of real footage ([`source`]).
//!
//! ```no_run
//! use camera_proc::render::{Facing, Renderer, SimWorld};
//! let world = SimWorld::nico(0)?;
//! let mut renderer = Renderer::new(world)?;
//! let (mut left, mut right) = (vec![0u8; 640 * 480], vec![0u8; 640 * 480]);
//! renderer.render(&[0.8, 0.1, 0.2, -0.4], Facing::Mirror, 1, &mut left, &mut right)?;
//! # Ok::<(), anyhow::Error>(())
//! ```
#![warn(missing_docs)]

pub mod render;
pub mod source;
