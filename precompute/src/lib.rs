//! PRM offline stages. This crate grows with the precompute, the reference baker and the
//! ground-truth tracer; today it holds the generator of the bundled scenes.

pub mod scenes;
