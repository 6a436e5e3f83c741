//! Every structure the GPU reads or writes, in one place (STYLE.md §2).
//!
//! Each is `#[repr(C)]` + `bytemuck::Pod` and mirrors a WGSL struct of the same meaning; the
//! test `runtime/tests/layout.rs` parses every shader with naga and checks the sizes and field
//! offsets against these, so the two sides cannot drift apart silently.

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};
use prm::{Light, LightKind};

/// `Light` in `shaders/lights.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    pub position: [f32; 3],
    /// 0 point, 1 spot, 2 directional.
    pub kind: u32,
    pub direction: [f32; 3],
    /// glTF range in scene units; 0 = none.
    pub range: f32,
    /// W/sr (point, spot) or W/m² (directional).
    pub intensity: [f32; 3],
    /// First shadow-map layer of this light.
    pub first_layer: u32,
    pub cos_inner: f32,
    pub cos_outer: f32,
    /// World size of one shadow texel: per unit distance (perspective) or absolute (ortho).
    pub texel: f32,
    /// Shadow layers owned: 6 (cube) or 1.
    pub layers: u32,
}

pub const KIND_POINT: u32 = 0;
pub const KIND_SPOT: u32 = 1;
pub const KIND_DIRECTIONAL: u32 = 2;

impl GpuLight {
    /// The GPU form of `l`, its shadow layers starting at `first_layer`.
    pub fn new(l: &Light, first_layer: u32, layers: u32, texel: f32) -> GpuLight {
        let (kind, cos_inner, cos_outer) = match l.kind {
            LightKind::Point => (KIND_POINT, 1.0, -1.0),
            LightKind::Spot { inner, outer } => (KIND_SPOT, inner.cos(), outer.cos()),
            LightKind::Directional => (KIND_DIRECTIONAL, 1.0, -1.0),
        };
        GpuLight {
            position: l.position.to_array(),
            kind,
            direction: l.direction.to_array(),
            range: l.range.filter(|r| *r > 0.0).unwrap_or(0.0),
            intensity: l.intensity.to_array(),
            first_layer,
            cos_inner,
            cos_outer,
            texel,
            layers,
        }
    }
}

/// `Entry` in `shaders/irradiance.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuEntry {
    pub position: [f32; 3],
    pub _pad0: u32,
    pub normal: [f32; 3],
    pub _pad1: u32,
}

/// `Params` in `shaders/irradiance.wgsl` and `shaders/weights.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct IndirectParams {
    pub entry_count: u32,
    pub light_count: u32,
    pub cluster_count: u32,
    /// Clusters composed per frame.
    pub top_k: u32,
    pub group_count: u32,
    /// 1: groups stand in for the clusters left out.
    pub residual: u32,
    pub _pad: [u32; 2],
}

/// `Params` in `shaders/compose.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ComposeParams {
    pub atlas_width: u32,
    pub atlas_height: u32,
    pub tile_size: u32,
    pub tiles_x: u32,
    /// Atlas tiles.
    pub tile_count: u32,
    /// Most stored tiles covering one atlas tile (the stride of the active lists).
    pub active_stride: u32,
    pub _pad: [u32; 2],
}

/// `TileRecord` in `shaders/compose.wgsl`: one stored pane tile.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TileRecord {
    /// RGB scale of the tile's f16 intensities.
    pub scale: [f32; 3],
    pub cluster: u32,
    /// Index (in f16 units) of the tile's first stored texel in the data buffer.
    pub data_offset: u32,
    pub _pad: [u32; 3],
}

/// `ActiveRecord` in `shaders/compose.wgsl`: a stored tile of a selected pane, as the compose
/// reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ActiveRecord {
    /// The pane's weight times the tile's colour scale.
    pub weighted_scale: [f32; 3],
    pub data_offset: u32,
}

/// `ShadeParams` in `shaders/shade.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ShadeParams {
    pub view_proj: [[f32; 4]; 4],
    pub light_count: u32,
    /// 1 to add the indirect lightmap, 0 for a direct-only frame.
    pub indirect_scale: f32,
    pub atlas_width: u32,
    pub atlas_height: u32,
}

/// `VertexIn` in `shaders/shade.wgsl`: one corner of a level triangle, unindexed.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ShadeVertex {
    pub position: [f32; 3],
    /// Geometric normal of the triangle (the lightmap texels use the same).
    pub normal: [f32; 3],
    pub uv1: [f32; 2],
    pub albedo: [f32; 3],
    pub emissive: [f32; 3],
    pub double_sided: u32,
}

impl ShadeVertex {
    pub const ATTRIBUTES: [wgpu::VertexAttribute; 6] = wgpu::vertex_attr_array![
        0 => Float32x3, 1 => Float32x3, 2 => Float32x2, 3 => Float32x3, 4 => Float32x3, 5 => Uint32
    ];
}

/// A column-major matrix as WGSL's `mat4x4f`.
pub fn mat(m: Mat4) -> [[f32; 4]; 4] {
    m.to_cols_array_2d()
}

/// A vector padded to WGSL's `vec4f`.
pub fn vec4(v: Vec3) -> [f32; 4] {
    [v.x, v.y, v.z, 0.0]
}

/// `TonemapParams` in `shaders/tonemap.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TonemapParams {
    /// Multiplies the radiance before the curve.
    pub exposure: f32,
    /// 1 to sRGB-encode in the shader (a non-sRGB target).
    pub encode: u32,
    pub _pad: [u32; 2],
}
