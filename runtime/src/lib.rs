//! PRM runtime: per-frame indirect lightmaps from a precomputed radiance map.
//!
//! Today this holds the CPU twin ([`cpu`]): entry irradiance with ray-traced visibility,
//! cluster weights, top-K selection and compose. The wgpu path (shadow maps, compute shaders,
//! shading) arrives with the runtime issue and is held to this twin.

pub mod cpu;
