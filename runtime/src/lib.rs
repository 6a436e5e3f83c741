//! PRM runtime: per-frame indirect lightmaps from a precomputed radiance map (paper 004 §2.2,
//! DESIGN.md §5).
//!
//! - [`Runtime`]: bring your own `wgpu::Device` and `Queue`, load a `.prm`, call
//!   [`Runtime::update`] with each frame's lights, bind [`Runtime::lightmap`].
//! - [`Renderer`]: draws a whole frame (direct light from the same shadow maps + albedo/pi x
//!   the indirect lightmap) into an HDR target; used by `prm render`, `prm bench` and tests.
//! - [`cpu`]: the CPU twin of weights, selection and compose, which the GPU is tested against;
//!   with the `cpu-twin` feature also ray-traced entry irradiance and whole frames, which `prm`
//!   falls back to without an adapter.
//!
//! # A frame in a game
//!
//! ```no_run
//! use std::path::Path;
//!
//! use prm::prm_file::Prm;
//! use prm_runtime::{Runtime, RuntimeParams};
//!
//! # fn lights_this_frame() -> Vec<prm::Light> { Vec::new() }
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // The game's device and queue (`Gpu::new` makes them for tools that have none).
//! let gpu = prm_runtime::Gpu::new()?;
//! // The level as it was baked: the same triangles, lightmap UVs (TEXCOORD_1) and albedos.
//! // With the core's `gltf` feature it loads from the file; otherwise build a `prm::Scene`
//! // from the engine's own mesh data.
//! let scene = prm::gltf_load::load_scene("level.glb", &Default::default())?;
//! // `Some(&scene)`: a map baked for another level or atlas is refused, not misapplied.
//! let map = Prm::read(Path::new("level.prm"), Some(&scene))?;
//! let mut runtime = Runtime::new(&gpu.device, &gpu.queue, &scene, &map, RuntimeParams::default())?;
//! for _frame in 0..3 {
//!     // At most 64 lights, in W/sr (point, spot) or W/m² (directional); checked every frame.
//!     let update = runtime.update(&lights_this_frame())?;
//!     // No GPU work at all when no light changed.
//!     if update.composed {
//!         // The indirect lightmap: `Rgba32Float`, irradiance in W/m² over TEXCOORD_1. Shade
//!         // with `albedo / pi x (E_direct + E_indirect)`.
//!         let _lightmap: &wgpu::Texture = runtime.lightmap();
//!     }
//!     // The same shadow maps and lights, for the game's own direct lighting.
//!     let _shadows = runtime.shadows().group();
//! }
//! # Ok(())
//! # }
//! ```
//!
//! **Features.** By default the runtime pulls no baking code: the core crate without glTF
//! loading, UV generation, EXR, rayon or the BVH. `cpu-twin` adds `cpu::CpuTwin` and
//! `cpu::entry_irradiance` (ray-traced visibility, for tools and tests).
//!
//! Shaders live in `shaders/`, each next to the module of the same stem; what they share with
//! Rust (constants, structs, bind groups, workgroup sizes) is generated from the `contract`,
//! `layout` and `bindings` modules, and a test checks every shader against them with naga.

mod axis;
mod bindings;
pub mod budget;
mod compose;
mod concentrate;
mod contract;
pub mod cpu;
mod far;
mod gpu;
mod irradiance;
mod layout;
mod lift;
mod lights;
pub mod memory;
mod near;
pub mod radiosity;
mod runtime;
mod shade;
mod shadow;
mod tile_changes;
mod timer;
mod tonemap;
mod weights;

#[cfg(test)]
mod tests;

pub use compose::ComposeBytes;
pub use gpu::{Gpu, GpuError};
pub use lights::LightError;
pub use memory::GpuMemory;
pub use runtime::{Budget, Runtime, RuntimeError, RuntimeParams, Update};
pub use shade::Renderer;
pub use shadow::ShadowMaps;
pub use timer::PassTimer;
pub use tonemap::Tonemap;
