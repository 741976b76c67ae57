//! The camera stage: readers of real footage ([`source`]), the frame
//! schedule ([`clock`]), the loops that publish frames, rendered by the
//! `renderer` crate or read from a source ([`stage`]), and a snapshot of
//! the simulated scene for debugging ([`snapshot`]).

pub mod clock;
pub mod snapshot;
pub mod source;
pub mod stage;
