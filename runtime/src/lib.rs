//! PRM runtime: per-frame indirect lightmaps from a precomputed radiance map (paper 004 §2.2,
//! DESIGN.md §5).
//!
//! - [`Runtime`]: bring your own `wgpu::Device` and `Queue`, load a `.prm`, call
//!   [`Runtime::update`] with each frame's lights, bind [`Runtime::lightmap`].
//! - [`Renderer`]: draws a whole frame (direct light from the same shadow maps + albedo/pi x
//!   the indirect lightmap) into an HDR target; used by `prm render`, `prm bench` and tests.
//! - [`cpu`]: the CPU twin of entry irradiance, weights, selection and compose, which the GPU
//!   is tested against and which `prm` falls back to without an adapter.
//!
//! Shaders live in `shaders/`, each next to the module of the same stem; what they share with
//! Rust (constants, structs, bind groups, workgroup sizes) is generated from [`contract`],
//! [`layout`] and [`bindings`].

pub mod bindings;
pub mod compose;
pub mod contract;
pub mod cpu;
pub mod gpu;
pub mod irradiance;
pub mod layout;
pub mod lights;
pub mod runtime;
pub mod shade;
pub mod shadow;
pub mod timer;
pub mod tonemap;
pub mod weights;

pub use gpu::Gpu;
pub use runtime::{Runtime, RuntimeError, RuntimeParams, Update};
pub use shade::Renderer;
