//! PRM core: the pieces every stage shares.
//!
//! - [`scene`]: a glTF level flattened into one world-space triangle soup with Lambertian
//!   materials, punctual lights and cameras ([`gltf_load`] reads it, [`glb`] writes one).
//! - [`light`]: the radiometric light model (DESIGN.md §3) used by every stage; [`photometry`]
//!   reads IES / EULUMDAT emission profiles for it; [`emitters`] merges emissive surfaces into
//!   polygon lights.
//! - [`density`]: the atlas size a texel size in metres gives a level.
//! - [`zones`]: generated UVs packed zone by zone, so nearby geometry stays together.
//! - [`uv`]: lightmap-UV checks (range, overlap) and generation when a level has none.
//! - [`texels`]: the lightmap texel set: exit points with exact conservative coverage.
//! - [`bvh`]: closest-hit and occlusion queries with a scale-independent offset scheme.
//! - [`cell_light`]: the light on an entry cell's triangle, its visibility filtered over it.
//! - [`exr_io`]: named-channel EXR files in the DESIGN.md §8 layouts, written atomically.
//! - [`prm_file`]: the `.prm` format; [`fingerprint`]: what a map was baked for.
//! - [`sampling`]: seeded streams and sample warps for the bakers.
//! - [`visibility`]: precomputed visibility for levels with moving objects (paper 003).
//!
//! No wgpu here: the runtime crate adds the GPU side.
//!
//! **Cargo features** (all on by default) keep a game that links only the runtime lean: the
//! runtime needs the scene, lights, rigs and the `.prm` reader, none of these.
//!
//! | feature | gives | pulls |
//! | --- | --- | --- |
//! | `gltf` | [`gltf_load`] (+ `unwrap`) | gltf, image decoders |
//! | `unwrap` | lightmap-UV generation in [`uv`] | uvunwrap |
//! | `exr` | [`exr_io`] (+ `texels`) | exr |
//! | `texels` | [`texels`] | rayon |
//! | `bvh` | [`bvh`] ray queries | obvhs |
//! | `sampling` | [`sampling`] | rand, rand_pcg |

#[cfg(feature = "bvh")]
pub mod bvh;
pub mod cell_light;
pub mod cone;
pub mod density;
pub mod emitters;
#[cfg(feature = "exr")]
pub mod exr_io;
pub mod fingerprint;
pub mod form_factor;
pub mod fsutil;
pub mod glb;
#[cfg(feature = "gltf")]
pub mod gltf_load;
pub mod light;
pub mod metric;
pub mod photometry;
pub mod prefetch;
pub mod prm_file;
pub mod rig;
pub mod rooms;
#[cfg(feature = "sampling")]
pub mod sampling;
pub mod scene;
#[cfg(feature = "texels")]
pub mod texels;
pub mod uv;
pub mod visibility;
#[cfg(feature = "unwrap")]
pub mod zones;

#[cfg(feature = "bvh")]
pub use bvh::{Bvh, Hit};
#[cfg(feature = "gltf")]
pub use gltf_load::{load_scene, LoadOptions, SceneError};
pub use light::{Light, LightKind};
pub use scene::{Camera, Material, Scene, Triangle};
#[cfg(feature = "texels")]
pub use texels::{Smoothing, Texel, TexelSet};

/// Rec. 709 luminance weights of linear R, G and B; the GPU's `luminance` (the runtime's WGSL
/// prelude) is generated from these.
pub const LUMINANCE: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Rec. 709 luminance of a linear RGB value (DESIGN.md §3 metric, Russian roulette).
#[inline]
pub fn luminance(c: glam::Vec3) -> f32 {
    LUMINANCE[0] * c.x + LUMINANCE[1] * c.y + LUMINANCE[2] * c.z
}
