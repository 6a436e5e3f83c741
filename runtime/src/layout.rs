//! Every structure the GPU reads or writes, in one place (STYLE.md §2).
//!
//! Each is declared once, through [`gpu_struct!`]: the macro writes the `#[repr(C)]` +
//! `bytemuck::Pod` Rust struct and, from the same field list, its WGSL twin (same name, same
//! fields, [`GpuStruct::wgsl`]), which [`crate::contract::prelude`] puts in front of every
//! shader. Shaders never declare these structs themselves. WGSL lays structs out by its own
//! alignment rules (a `vec3f` is 16-aligned), so the Rust side pads explicitly, with scalar
//! `_padN` fields (a uniform buffer cannot hold `array<u32, N>`); the test
//! `runtime/src/tests/contract.rs` lets naga lay out every generated struct and checks its size and
//! field offsets against [`GpuStruct::FIELDS`] (taken from the Rust struct with `offset_of!`).

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};
use prm::{Light, LightKind};

use crate::contract::{KIND_DIRECTIONAL, KIND_POINT, KIND_SPOT};

/// One field of a [`GpuStruct`]: its name, WGSL type and byte offset in the Rust struct.
#[derive(Clone, Copy, Debug)]
pub struct Field {
    pub name: &'static str,
    pub wgsl: &'static str,
    #[cfg_attr(not(test), allow(dead_code, reason = "the contract tests read it"))]
    pub offset: usize,
}

/// A Rust struct with a WGSL twin of the same layout (declared with [`gpu_struct!`]).
pub trait GpuStruct: Pod {
    /// The struct's name, in Rust and in WGSL.
    const NAME: &'static str;
    /// Its fields in declaration order, with their Rust offsets.
    const FIELDS: &'static [Field];
    /// Its size in bytes in Rust.
    const SIZE: usize = std::mem::size_of::<Self>();

    /// The WGSL declaration of the twin.
    fn wgsl() -> String {
        let mut s = format!("struct {} {{\n", Self::NAME);
        for f in Self::FIELDS {
            s += &format!("    {}: {},\n", f.name, f.wgsl);
        }
        s + "}\n"
    }
}

/// The WGSL type of a Rust field type a [`GpuStruct`] may hold.
pub trait WgslType {
    const WGSL: &'static str;
}

macro_rules! wgsl_type {
    ($($rust:ty => $wgsl:literal),* $(,)?) => {
        $(impl WgslType for $rust {
            const WGSL: &'static str = $wgsl;
        })*
    };
}

wgsl_type!(f32 => "f32", u32 => "u32", [f32; 2] => "vec2f", [f32; 3] => "vec3f", [f32; 4] => "vec4f",
    [u32; 4] => "vec4u", [[f32; 4]; 4] => "mat4x4f");

/// Declares a `#[repr(C)]`, `Pod` struct and implements [`GpuStruct`] for it from the same
/// field list, so the Rust and WGSL sides cannot differ in names, types or order.
macro_rules! gpu_struct {
    ($(#[$meta:meta])* pub struct $name:ident {
        $($(#[$fmeta:meta])* pub $field:ident: $ty:ty,)*
    }) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
        pub struct $name {
            $($(#[$fmeta])* pub $field: $ty,)*
        }

        impl GpuStruct for $name {
            const NAME: &'static str = stringify!($name);
            const FIELDS: &'static [Field] = &[$(Field {
                name: stringify!($field),
                wgsl: <$ty as WgslType>::WGSL,
                offset: std::mem::offset_of!($name, $field),
            }),*];
        }
    };
}

gpu_struct! {
    /// A light as the shaders see it (`shaders/lights.wgsl`).
    pub struct GpuLight {
        pub position: [f32; 3],
        /// [`KIND_POINT`], [`KIND_SPOT`] or [`KIND_DIRECTIONAL`].
        pub kind: u32,
        /// Unit direction the light points along (spot, directional).
        pub direction: [f32; 3],
        /// glTF range in scene units; 0 = none.
        pub range: f32,
        /// W/sr (point, spot) or W/m² (directional), per channel.
        pub intensity: [f32; 3],
        /// First shadow-map layer of this light.
        pub first_layer: u32,
        pub cos_inner: f32,
        pub cos_outer: f32,
        /// World size of one shadow texel: per unit distance (perspective) or absolute (ortho).
        pub texel: f32,
        /// Shadow layers owned: [`crate::contract::CUBE_LAYERS`] (cube) or 1.
        pub layers: u32,
    }
}

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

gpu_struct! {
    /// An entry point of the irradiance pass (`shaders/irradiance.wgsl`): its cell, the
    /// triangles `first_cell .. first_cell + cell_count` of the cell buffer, 1 / its area, and
    /// a sphere holding the cell's triangles (what the shadow maps' blocks are asked about).
    pub struct GpuEntry {
        pub first_cell: u32,
        pub cell_count: u32,
        pub inv_area: f32,
        pub _pad0: u32,
        pub bound_centre: [f32; 3],
        pub bound_radius: f32,
    }
}

gpu_struct! {
    /// A near-field link on the GPU (`shaders/near.wgsl`): the entry and albedo x factor.
    pub struct GpuNearLink {
        pub factor: [f32; 3],
        pub entry: u32,
    }
}

gpu_struct! {
    /// A link of the near field's echo on the GPU (`shaders/echo.wgsl`): the source point and
    /// the source's albedo x the form factor.
    pub struct GpuEchoLink {
        pub factor: [f32; 3],
        pub source: u32,
    }
}

gpu_struct! {
    /// A texel with near-field links: links `first .. first + count` (`shaders/near.wgsl`),
    /// and its sample point and unit normal (`shaders/concentrate.wgsl`).
    pub struct NearTexel {
        pub texel: u32,
        pub first: u32,
        pub count: u32,
        pub _pad0: u32,
        pub position: [f32; 3],
        pub _pad1: u32,
        pub normal: [f32; 3],
        pub _pad2: u32,
    }
}

gpu_struct! {
    /// An entry's cell as the near field's concentration sees it (`shaders/concentrate.wgsl`):
    /// its centroid and size (square root of its area), its triangles `first_cell ..
    /// first_cell + cell_count`, and its links `link_ids[first_link .. first_link + link_count]`.
    pub struct GpuHotEntry {
        pub centroid: [f32; 3],
        pub size: f32,
        pub first_cell: u32,
        pub cell_count: u32,
        pub first_link: u32,
        pub link_count: u32,
    }
}

gpu_struct! {
    /// A triangle of an entry's cell, corners counter-clockwise seen from the front
    /// (`prm::prm_file::Cells`).
    pub struct GpuCellTriangle {
        pub a: [f32; 3],
        /// The visible share of the power of the lights that reach it, written by the entry pass
        /// (`prm::cell_light::TriangleLight::share`).
        pub visibility: f32,
        pub b: [f32; 3],
        /// Fine points 0-31's visibility bits on a mixed triangle, written by the entry pass
        /// (`prm::cell_light::TriangleLight::fine`).
        pub fine_lo: u32,
        pub c: [f32; 3],
        /// Fine points 32-35's bits, and [`crate::contract::CELL_MIXED`] on a mixed triangle.
        pub fine_hi: u32,
        /// The unshadowed irradiance on it as the light that arrives tells it (W/m²: its power
        /// over its visible share and area, 0 where none arrives), written by the entry pass
        /// for the concentration of cells no light is near
        /// (`prm_runtime::cpu::concentrate::concentration`).
        pub level: [f32; 3],
        /// Lights 0-31 that reach it (`prm::cell_light::TriangleLight::reach`), written by the
        /// entry pass; the concentration sums only those.
        pub reach_lo: u32,
        /// Lights 32-63 that reach it.
        pub reach_hi: u32,
        pub _pad0: u32,
        pub _pad1: u32,
        pub _pad2: u32,
    }
}

gpu_struct! {
    /// The uniform of `shaders/irradiance.wgsl` and `shaders/weights.wgsl`.
    pub struct IndirectParams {
        pub entry_count: u32,
        pub light_count: u32,
        pub cluster_count: u32,
        /// Clusters composed per frame.
        pub top_k: u32,
        pub group_count: u32,
        /// 1: groups stand in for the clusters left out.
        pub residual: u32,
        /// Texels with near-field links (`shaders/near.wgsl`).
        pub near_texel_count: u32,
        /// This update's number (from 1): link light written this update carries it, so a
        /// value left from an earlier update is never read (`shaders/concentrate.wgsl`).
        pub frame: u32,
        /// 1 when some cell is hot this update (else the concentration pass did not run and
        /// no link light is read).
        pub any_hot: u32,
        /// Texels the far field lights (`shaders/far.wgsl`; 0: none).
        pub far_texel_count: u32,
        /// `prm::prm_file::Far::reach`.
        pub far_reach: f32,
        /// Near-field links (`crate::concentrate::link_ids`; where the hot cells' work list
        /// starts in it: `crate::concentrate::work_list`).
        pub link_count: u32,
        /// 1: the entry pass skips the shadow probes of a light whose shadow maps' blocks hide
        /// the whole cell (`crate::RuntimeParams::cull_hidden_lights`).
        pub cull_hidden: u32,
        /// Bits of the lights that changed since the last update's entry pass (any field),
        /// lights 0-31 and 32-63.
        pub changed_lo: u32,
        pub changed_hi: u32,
        /// 1: an entry every changed light is hidden from, now and at the last update that ran
        /// it, keeps its light (`shaders/irradiance.wgsl`); 0: the entry pass runs every entry.
        pub keep_unchanged: u32,
        /// Bits of the lights whose spots the far field sees in their cubes (lights 0-31,
        /// 32-63: `crate::cpu::sighted`, `shaders/far.wgsl`).
        pub sighted_lo: u32,
        pub sighted_hi: u32,
        /// Where the near points' expected light starts in `near_sum` (`shaders/near.wgsl`,
        /// `shaders/echo.wgsl`; `crate::cpu::echo_input`): the slot after the far field's.
        pub near_expected_at: u32,
        /// 1: the lift keeps each room's power from the far texels' areas
        /// (`crate::cpu::lift_weights`, `shaders/lift.wgsl`); 0: its energy (a map before v17).
        pub lift_power: u32,
        /// Column k: the eye of the light in sighted slot k (`crate::cpu::sight_eye`: where its
        /// cube is and its spots are seen from), w = 1; zero past the last.
        pub sight_eyes: [[f32; 4]; 4],
    }
}

gpu_struct! {
    /// An entry as the far field sees it (`shaders/far.wgsl`): its cell's centroid and size
    /// (the square root of its area), its normal, albedo x A/N (what turns its deviation into
    /// flux) and its stay share (how much of its light counts in the threshold's reflected
    /// light: `crate::cpu::far_threshold`).
    pub struct FarEntry {
        pub centroid: [f32; 3],
        pub size: f32,
        pub normal: [f32; 3],
        pub _pad0: u32,
        pub flux: [f32; 3],
        pub stay: f32,
    }
}

gpu_struct! {
    /// A texel the far field lights (`prm::prm_file::FarTexel`): its point, normal, the slot of
    /// its sum in the near field's `near_sum`, and the entries it borrows visibility from.
    pub struct GpuFarTexel {
        pub position: [f32; 3],
        pub slot: u32,
        pub normal: [f32; 3],
        pub _pad0: u32,
        pub entries: [u32; 4],
        pub weights: [f32; 4],
    }
}

gpu_struct! {
    /// The uniform of `shaders/compose.wgsl`.
    pub struct ComposeParams {
        pub atlas_width: u32,
        pub atlas_height: u32,
        pub tile_size: u32,
        pub tiles_x: u32,
        /// Atlas tiles.
        pub tile_count: u32,
        /// 1: every tile is composed again, changed or not (`crate::tile_changes`).
        pub recompose_all: u32,
        /// Panes picked per tile grid vertex under a local budget (`cpu::compose_local`); 0: the weight
        /// pass's global selection is composed as it is.
        pub local_k: u32,
        pub cluster_count: u32,
        pub group_count: u32,
        /// 1: under a local budget, groups stand in for the clusters each vertex leaves out.
        pub residual: u32,
        /// Rows of a lightmap page: atlas row y is row `y % page_rows` of layer `y / page_rows`.
        pub page_rows: u32,
        /// Words of pane data in `data`; the rest are in `data_hi` (`crate::compose::split_words`).
        pub data_split: u32,
        /// Near-field sums (`crate::near::NearData::total`).
        pub sum_count: u32,
        /// Where, in the compose's `counts`, the atlas tiles' states start, followed by the list
        /// of tiles to compose and the tiles' mean light (`crate::tile_changes`).
        pub state_offset: u32,
        /// A tile's weights or a near-field sum count as changed when they moved by more than
        /// this share of the tile's light (`RuntimeParams::recompose_tolerance`;
        /// `crate::tile_changes`).
        pub tolerance: f32,
        pub _pad0: u32,
    }
}

gpu_struct! {
    /// One stored pane tile (`shaders/compose.wgsl`), with what a local budget's picks at the
    /// tile's four corners ((0,0), (1,0), (0,1), (1,1)) need of it.
    pub struct TileRecord {
        /// RGB scale of the tile's 8-bit intensities.
        pub scale: [f32; 3],
        pub cluster: u32,
        /// Index (in bytes) of the tile's first stored texel in the data buffer.
        pub data_offset: u32,
        /// Luminance energy per unit weight (`cpu::TileRecord::energy`).
        pub energy: f32,
        /// A cluster tile's group (`NO_SLOT` for none and group tiles).
        pub group: u32,
        /// In this atlas tile's records: for a cluster's, the next of a cluster of the same
        /// group; for a group's, the first of its clusters (`NO_SLOT`: none).
        pub next: u32,
        /// Per corner, `4 x record + corner` of the record that stands for this pane at that
        /// vertex: the first of the pane's records in the tiles around it (in the order (x-1,
        /// y-1), (x, y-1), (x-1, y), (x, y)), whose words in the compose's `counts` hold its
        /// state and weight there.
        pub owner: [u32; 4],
        /// Per corner, the pane's energy summed over the tiles around that vertex.
        pub summed: [f32; 4],
    }
}

gpu_struct! {
    /// A stored tile of a selected pane, as the compose reads it (`shaders/compose.wgsl`): the
    /// pane's weight times the tile's colour scale at the tile's four corners, blended
    /// bilinearly at each texel (all four the same under a global budget).
    pub struct ActiveRecord {
        pub c00: [f32; 3],
        pub data_offset: u32,
        pub c10: [f32; 3],
        /// 1 when the corners differ; 0: `c00` is the weight everywhere in the tile, and the
        /// texel reads only it.
        pub blend: u32,
        pub c01: [f32; 3],
        pub _pad1: u32,
        pub c11: [f32; 3],
        pub _pad2: u32,
    }
}

gpu_struct! {
    /// The uniform of `shaders/shade.wgsl`.
    pub struct ShadeParams {
        pub view_proj: [[f32; 4]; 4],
        pub light_count: u32,
        /// 1 to add the indirect lightmap, 0 for a direct-only frame.
        pub indirect_scale: f32,
        pub atlas_width: u32,
        pub atlas_height: u32,
        /// Lightmap pages (layers of the lightmap texture), stacked down the atlas.
        pub pages: u32,
        pub _pad0: u32,
        pub _pad1: u32,
        pub _pad2: u32,
    }
}

/// `VertexIn` in `shaders/shade.wgsl`: one corner of a level triangle, unindexed. A vertex
/// buffer, not a binding: [`ShadeVertex::ATTRIBUTES`] is its contract, checked by the layout
/// test against these offsets and against the shader's inputs.
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

gpu_struct! {
    /// The uniform of `shaders/tonemap.wgsl`.
    pub struct TonemapParams {
        /// Multiplies the radiance before the curve.
        pub exposure: f32,
        /// 1 to sRGB-encode in the shader (a non-sRGB target).
        pub encode: u32,
        pub _pad0: u32,
        pub _pad1: u32,
    }
}

gpu_struct! {
    /// A node of the radiosity hierarchy (`crate::cpu::radiosity::Node`), rest frame.
    pub struct RadNode {
        pub centre: [f32; 3],
        pub radius: f32,
        pub normal: [f32; 3],
        pub area: f32,
        pub object: u32,
        pub first: u32,
        pub end: u32,
        /// `u32::MAX`: the walk ends.
        pub skip: u32,
    }
}

gpu_struct! {
    /// A texel as the radiosity reads it, rest frame: point, area, normal, object, albedo, its
    /// place in its object's CSSM sequence, its escaping share
    /// (`prm::visibility::Visibility::escape`) and its shape's area (the shape's vertices are
    /// in the `shapes` buffer, `crate::cpu::radiosity::Shape`).
    pub struct RadTexel {
        pub position: [f32; 3],
        pub area: f32,
        pub normal: [f32; 3],
        pub object: u32,
        pub albedo: [f32; 3],
        pub seq: u32,
        pub escape: f32,
        pub shape_area: f32,
        pub _pad0: u32,
        pub _pad1: u32,
    }
}

gpu_struct! {
    /// An object of the radiosity: its pose this frame, and where its visibility data start in
    /// the packed `vdata` words (`crate::radiosity::pack_visibility`).
    pub struct RadObject {
        pub to_world: [[f32; 4]; 4],
        pub to_rest: [[f32; 4]; 4],
        pub csm_centre: [f32; 3],
        pub csm_radius: f32,
        /// Word offsets of the CSSM's origins (3 words each), run offsets, run starts and
        /// depths (two 16-bit codes a word).
        pub origins: u32,
        pub offsets: u32,
        pub starts: u32,
        pub depths: u32,
        pub res: u32,
        pub far: f32,
        /// Word offset of the occluder maps (two 16-bit entry/exit pairs a word), or `u32::MAX`.
        pub csm: u32,
        pub csm_dirs: u32,
        pub csm_res: u32,
        /// Its tree's root node (`u32::MAX`: no texels).
        pub root: u32,
        pub _pad0: u32,
        pub _pad1: u32,
    }
}

gpu_struct! {
    /// The uniform of `shaders/radiosity.wgsl`, written before each pass.
    pub struct RadParams {
        pub texels: u32,
        pub nodes: u32,
        pub objects: u32,
        /// Jitter the representative texels (the final pass).
        pub jitter: u32,
        pub threshold: f32,
        /// The half of `flux` this pass writes and reads.
        pub flux_half: u32,
        /// Sum of the texels' areas, m².
        pub total_area: f32,
        /// Scale each pass to conserve power (`RadiosityParams::conserve`).
        pub conserve: u32,
        /// Near texels send by their shapes' parts (the first pass: direct light).
        pub parts: u32,
        pub _pad0: u32,
        pub _pad1: u32,
        pub _pad2: u32,
    }
}

gpu_struct! {
    /// The uniform of `shaders/texel_direct.wgsl`.
    pub struct DirectParams {
        pub texels: u32,
        pub light_count: u32,
        pub _pad0: u32,
        pub _pad1: u32,
    }
}

/// Every [`GpuStruct`], as `(name, WGSL declaration, size, fields)`: what the prelude declares
/// and the layout test checks.
pub fn gpu_structs() -> Vec<(&'static str, String, usize, &'static [Field])> {
    fn one<T: GpuStruct>() -> (&'static str, String, usize, &'static [Field]) {
        (T::NAME, T::wgsl(), T::SIZE, T::FIELDS)
    }
    vec![
        one::<GpuLight>(),
        one::<GpuEntry>(),
        one::<GpuCellTriangle>(),
        one::<GpuNearLink>(),
        one::<GpuEchoLink>(),
        one::<NearTexel>(),
        one::<GpuHotEntry>(),
        one::<FarEntry>(),
        one::<GpuFarTexel>(),
        one::<IndirectParams>(),
        one::<ComposeParams>(),
        one::<TileRecord>(),
        one::<ActiveRecord>(),
        one::<ShadeParams>(),
        one::<TonemapParams>(),
        one::<RadNode>(),
        one::<RadTexel>(),
        one::<RadObject>(),
        one::<RadParams>(),
        one::<DirectParams>(),
    ]
}
