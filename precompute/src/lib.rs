//! PRM offline stages: the ground-truth path tracer and the generator of the bundled scenes.
//! The precompute and the reference baker join here.

pub mod ground_truth;
pub mod scenes;
