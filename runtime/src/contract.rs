//! The contract between the Rust side and the shaders, from one source (STYLE.md §2).
//!
//! WGSL has no includes, and everything a shader shares with Rust used to be copied into it
//! by hand. Now each shared fact is written once, in Rust, and the WGSL sees a generated copy:
//!
//! - [`prelude`]: WGSL `const`s from the Rust constants below (light kinds, the no-slot
//!   sentinel, workgroup sizes, cube layers), `luminance` from [`prm::LUMINANCE`], glTF's range
//!   window from [`prm::light::RANGE_WINDOW_WGSL`] (written next to its Rust twin), and every
//!   struct of [`crate::layout`];
//! - the `@group @binding` declarations, from each pass's table ([`crate::bindings`]);
//! - then the [`Library`]s the pass uses: the light library `shaders/lights.wgsl` for passes
//!   that light surfaces, the polygon form factor `shaders/form_factor.wgsl`; last the pass's
//!   own `shaders/<stem>.wgsl`, which only adds functions, local structs and entry points.
//!
//! A [`Shader`] names those parts; [`SHADERS`] lists every one, so the layout test can parse
//! each assembled source with naga and check bindings, visibility and workgroup sizes against
//! the Rust tables and constants. Rust dispatch math divides by the same constants the WGSL
//! `@workgroup_size` attributes name.

use std::fmt::Write;
use std::sync::LazyLock;

use crate::bindings::{self, Binding};
use crate::layout::gpu_structs;

/// Invocations per workgroup of one-dimensional compute passes (`@workgroup_size(WG_LINEAR)`).
pub const WG_LINEAR: u32 = 64;
/// Side of the square workgroups of per-texel passes (`@workgroup_size(WG_TILE, WG_TILE)`).
pub const WG_TILE: u32 = 8;
/// The slot of an atlas texel no stored tile covers (`runtime/src/compose.rs`).
pub const NO_SLOT: u32 = u32::MAX;
/// A near point without a cell to read its echo against (`shaders/echo.wgsl`,
/// [`crate::cpu::NearTables::point_cell`]).
pub const NO_CELL: u32 = u32::MAX;
/// Words per record and corner of its tile in the compose's `counts` buffer under a local budget
/// (the state of the pane standing there and its weight: `shaders/compose.wgsl`).
pub const CORNER_WORDS: u32 = 4;
/// Shadow-map layers of a cube (a point light or a wide spot): +X -X +Y -Y +Z -Z.
pub const CUBE_LAYERS: u32 = 6;
/// Blocks per side of each shadow-map layer in [`crate::shadow`]'s block minima (the farthest
/// occluder over each block, which tells the entry pass a light is hidden from a whole cell).
pub const SHADOW_BLOCKS: u32 = 32;
/// [`crate::layout::GpuLight::kind`] of a point light.
pub const KIND_POINT: u32 = 0;
/// [`crate::layout::GpuLight::kind`] of a spot light.
pub const KIND_SPOT: u32 = 1;
/// [`crate::layout::GpuLight::kind`] of a directional light.
pub const KIND_DIRECTIONAL: u32 = 2;

/// Set in [`crate::layout::GpuCellTriangle::fine_hi`] when a shadow edge crosses the triangle
/// (`prm::cell_light::TriangleLight::mixed`); the fine points' bits take the low 4 bits.
pub const CELL_MIXED: u32 = 1 << 31;
const _: () = assert!(prm::cell_light::FINE_POINTS <= 32 + 31, "the fine bits must fit beside CELL_MIXED");
// irradiance.wgsl's "every bit set" takes the second word's bits as FINE_POINTS - 32.
const _: () = assert!(prm::cell_light::FINE_POINTS > 32, "the fine bits must fill the first word");

/// A flag of the entry irradiance's w (`shaders/irradiance.wgsl`, as a float): a shadow edge
/// crosses one of the entry's cell triangles.
pub const ENTRY_EDGE: u32 = 1;
/// A flag of the entry irradiance's w: the entry kept last update's light (no light that
/// changed reaches its cell), and the concentration keeps its links' light.
pub const ENTRY_UNCHANGED: u32 = 2;

/// A bit of an atlas tile's state (`shaders/tile_changes.wgsl`): one of the tile's records is of
/// a pane whose weight changed since the last compose.
pub const CHANGED_WEIGHT: u32 = 1;
/// A bit of an atlas tile's state: one of its texels' near-field sums changed.
pub const CHANGED_SUM: u32 = 2;
/// A bit of an atlas tile's state: a tile of the 3 x 3 around it has `CHANGED_WEIGHT`, so its
/// records are gathered again (the compose's `gather_main`).
pub const REGATHER: u32 = 4;

/// The WGSL `u32` constants of the prelude, by name.
pub const U32_CONSTANTS: &[(&str, u32)] = &[
    ("WG_LINEAR", WG_LINEAR),
    ("WG_TILE", WG_TILE),
    ("NO_SLOT", NO_SLOT),
    ("NO_CELL", NO_CELL),
    ("CORNER_WORDS", CORNER_WORDS),
    ("CUBE_LAYERS", CUBE_LAYERS),
    ("SHADOW_BLOCKS", SHADOW_BLOCKS),
    ("KIND_POINT", KIND_POINT),
    ("KIND_SPOT", KIND_SPOT),
    ("KIND_DIRECTIONAL", KIND_DIRECTIONAL),
    ("CONCENTRATION_SUB", crate::cpu::concentrate::SUB),
    ("CELL_FINE_SUB", prm::cell_light::FINE_SUB),
    ("CELL_FINE_POINTS", prm::cell_light::FINE_POINTS as u32),
    ("LANDING_SIDE", prm::cell_light::LANDING_SIDE),
    ("CELL_MIXED", CELL_MIXED),
    ("ENTRY_EDGE", ENTRY_EDGE),
    ("ENTRY_UNCHANGED", ENTRY_UNCHANGED),
    ("CHANGED_WEIGHT", CHANGED_WEIGHT),
    ("CHANGED_SUM", CHANGED_SUM),
    ("REGATHER", REGATHER),
    ("MAX_LIGHTS", prm::rig::MAX_LIGHTS as u32),
    ("CONCENTRATION_SUB_FAR", crate::cpu::concentrate::SUB_FAR),
    ("FAR_SOURCES", crate::cpu::FAR_SOURCES as u32),
    ("NO_LIGHT", crate::far::NO_LIGHT),
    ("APART", crate::far::APART),
    ("CLOSE_SIGHTS", crate::cpu::CLOSE_SIGHTS as u32),
    ("WG_FAR_SOURCES", crate::far::WG_FAR_SOURCES),
    ("CSSM_NOTHING", prm::visibility::cssm::NOTHING as u32),
    ("CSM_MISS", prm::visibility::csm::MISS as u32),
];

/// The WGSL every shader starts with: shared constants, functions and structs.
pub fn prelude() -> &'static str {
    static PRELUDE: LazyLock<String> = LazyLock::new(|| {
        let mut s =
            String::from("// Generated by runtime/src/contract.rs from the Rust side; do not copy.\n\n");
        for (name, value) in U32_CONSTANTS {
            let _ = writeln!(s, "const {name}: u32 = {value}u;");
        }
        // `{:?}` prints the shortest literal that reads back as the same f32; the `f` suffix
        // makes WGSL read it as an f32 directly.
        let [r, g, b] = prm::LUMINANCE;
        let _ = write!(
            s,
            "\n// Rec. 709 luminance (prm::luminance).\nfn luminance(c: vec3f) -> f32 {{\n    \
             return dot(c, vec3f({r:?}f, {g:?}f, {b:?}f));\n}}\n\n"
        );
        let _ = writeln!(
            s,
            "// A cell is hot within this many cell sizes of a light (prm_runtime::cpu::concentrate).\n\
             const HOT_REACH: f32 = {:?}f;\n\
             // Nearer than this many cell sizes, the quadrature is the fine one.\n\
             const NEAR_SIZES: f32 = {:?}f;\n\
             // A spot's band narrower than a cell's diameter makes it hot for the texels this near (in cell sizes).\n\
             const BAND_SIZES: f32 = {:?}f;\n\
             // The far field's sources against the light the surfaces reflect (prm_runtime::cpu::far_threshold).\n\
             const FAR_SOURCE_SCALE: f32 = {:?}f;\n\
             // Shadow texels within which an entry's lookup near a triangle's edge looks again, pulled in (crate::shadow).\n\
             const FOOTPRINT_TEXELS: f32 = {:?}f;\n\
             // Shadow texels a directional light's lookup stands off its receiver (crate::shadow).\n\
             const SUN_NORMAL_OFFSET: f32 = {:?}f;\n\
             // Texels a directional light's tile reaches past its part of the grid (crate::lights).\n\
             const SUN_TILE_MARGIN: f32 = {:?}f;\n\
             // Shadow texels a cube face reaches past its 90° (crate::lights).\n\
             const CUBE_PAD_TEXELS: f32 = {:?}f;\n\
             // A spot's cone lights a cell up close when it reaches this many cell sizes of its centroid (prm_runtime::cpu::up_close).\n\
             const CONE_REACH: f32 = {:?}f;\n\
             // A light lands off a triangle's centroid within this many longest edges (prm::cell_light::landing).\n\
             const LANDING_REACH: f32 = {:?}f;\n\
             // The far field sends a cell's light from where it lands this many sizes off its centroid, or leaving past this cosine of its normal (prm_runtime::cpu::lands_apart).\n\
             const LANDING_APART: f32 = {:?}f;\n\
             const LANDING_TURN: f32 = {:?}f;\n\
             // The least and most the lift moves a room's panes' power from the balance's (prm_runtime::cpu::POWER_KEPT_LIMITS).\n\
             const POWER_KEPT_LO: f32 = {:?}f;\n\
             const POWER_KEPT_HI: f32 = {:?}f;\n\
             const PI: f32 = {:?}f;\n",
            crate::cpu::concentrate::HOT_REACH,
            crate::cpu::concentrate::NEAR_SIZES,
            crate::cpu::concentrate::BAND_SIZES,
            crate::cpu::FAR_SOURCE_SCALE,
            crate::shadow::FOOTPRINT_TEXELS,
            crate::shadow::SUN_NORMAL_OFFSET,
            crate::lights::SUN_TILE_MARGIN as f32,
            crate::lights::CUBE_PAD_TEXELS,
            crate::cpu::CONE_REACH,
            prm::cell_light::LANDING_REACH,
            crate::cpu::LANDING_APART,
            crate::cpu::LANDING_TURN,
            crate::cpu::POWER_KEPT_LIMITS[0],
            crate::cpu::POWER_KEPT_LIMITS[1],
            std::f32::consts::PI
        );
        let _ = writeln!(
            s,
            "// A pane texel's intensity from its 8-bit code (prm::prm_file::intensity).\n\
             fn intensity(code: u32) -> f32 {{\n    \
             if code == 0u {{\n        return 0.0;\n    }}\n    \
             return exp2({:?}f * f32(255u - code) / 254.0);\n}}\n",
            prm::prm_file::INTENSITY_FLOOR.log2()
        );
        let _ = writeln!(
            s,
            "// Radiosity: texel sizes within which a texel sends by its square's form factor\n\
             // (prm_runtime::radiosity::NEAR), and the CSSM's relative depth slack\n\
             // (prm::visibility::cssm::SLACK) and edge margin (prm::visibility::cssm::EDGE).\n\
             const RADIOSITY_NEAR: f32 = {:?}f;\nconst CSSM_SLACK: f32 = {:?}f;\nconst CSSM_EDGE: f32 = {:?}f;\n\
             // The largest factor power conservation scales a pass by.\nconst MAX_CONSERVE: f32 = {:?}f;\n",
            crate::radiosity::NEAR,
            prm::visibility::cssm::SLACK,
            prm::visibility::cssm::EDGE,
            crate::radiosity::MAX_CONSERVE
        );
        s += "// glTF range window (prm::light::range_window).\n";
        s += prm::light::RANGE_WINDOW_WGSL;
        s += "\n// glTF spot falloff (prm::light::spot_falloff_cos).\n";
        s += prm::light::SPOT_FALLOFF_WGSL;
        s += "\n// The far field's share of a cell's light (prm::prm_file::far_share).\n";
        s += prm::prm_file::FAR_SHARE_WGSL;
        for (_, wgsl, _, _) in gpu_structs() {
            s += "\n";
            s += &wgsl;
        }
        s
    });
    &PRELUDE
}

/// A compute entry point and its workgroup size.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(not(test), allow(dead_code, reason = "the contract tests read it"))]
pub struct Compute {
    pub entry: &'static str,
    pub workgroup: [u32; 3],
}

/// `@workgroup_size(WG_LINEAR)`.
pub const LINEAR: [u32; 3] = [WG_LINEAR, 1, 1];
/// `@workgroup_size(WG_TILE, WG_TILE)`.
pub const TILE: [u32; 3] = [WG_TILE, WG_TILE, 1];

/// WGSL functions more than one pass calls, written once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Library {
    /// `shaders/lights.wgsl`: how a light reaches a point, with its shadow maps (it needs
    /// [`crate::shadow::SHADOW_GROUP`] as group 0).
    Lights,
    /// `shaders/form_factor.wgsl`: a point's form factor to a convex polygon
    /// (`prm::form_factor::point_to_polygon`).
    FormFactor,
    /// `shaders/spherical.wgsl`: directions even in solid angle over a spherical triangle
    /// (`prm::cone::spherical_triangle`).
    Spherical,
}

impl Library {
    /// Every library, for the contract tests.
    pub const ALL: [Library; 3] = [Library::Lights, Library::FormFactor, Library::Spherical];

    /// Its WGSL.
    pub fn source(self) -> &'static str {
        match self {
            Library::Lights => crate::lights::LIBRARY,
            Library::FormFactor => include_str!("../../shaders/form_factor.wgsl"),
            Library::Spherical => include_str!("../../shaders/spherical.wgsl"),
        }
    }

    /// `shaders/<stem>.wgsl`.
    pub fn stem(self) -> &'static str {
        match self {
            Library::Lights => "lights",
            Library::FormFactor => "form_factor",
            Library::Spherical => "spherical",
        }
    }
}

/// One shader: the parts it is assembled from and what its entry points must be.
#[derive(Clone, Copy, Debug)]
pub struct Shader {
    /// `shaders/<stem>.wgsl`, loaded by `runtime/src/<stem>.rs`.
    pub stem: &'static str,
    /// The pass's own WGSL.
    pub body: &'static str,
    /// The WGSL libraries that go in before the pass, in this order.
    pub libraries: &'static [Library],
    /// Bind groups, group `g` = `groups[g]`.
    pub groups: &'static [&'static [Binding]],
    /// Compute entry points with their workgroup sizes (none for render shaders).
    #[cfg_attr(not(test), allow(dead_code, reason = "the contract tests read it"))]
    pub compute: &'static [Compute],
}

impl Shader {
    /// The assembled WGSL: prelude, bindings, the libraries it uses, the pass.
    pub fn source(&self) -> String {
        let mut s = String::from(prelude());
        s += "\n// Bindings (runtime/src/bindings.rs tables).\n";
        s += &bindings::declarations(self.groups);
        for library in self.libraries {
            s += "\n";
            s += library.source();
        }
        s += "\n";
        s += self.body;
        s
    }

    /// `<stem>.wgsl`, for labels and messages.
    pub fn label(&self) -> String {
        format!("{}.wgsl", self.stem)
    }

    /// The shader module.
    pub fn module(&self, device: &wgpu::Device) -> wgpu::ShaderModule {
        device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(&self.label()),
            source: wgpu::ShaderSource::Wgsl(self.source().into()),
        })
    }

    /// The bind group layout of group `g`.
    pub fn layout(&self, device: &wgpu::Device, g: usize) -> wgpu::BindGroupLayout {
        bindings::layout(device, &format!("{} group {g}", self.stem), self.groups[g])
    }
}

/// Every shader of the runtime.
#[cfg_attr(not(test), allow(dead_code, reason = "the contract tests read it"))]
pub const SHADERS: [&Shader; 16] = [
    &crate::shadow::SHADER,
    &crate::shadow::BLOCKS,
    &crate::irradiance::SHADER,
    &crate::concentrate::CONCENTRATE,
    &crate::weights::SHADER,
    &crate::near::SHADER,
    &crate::near::ECHO,
    &crate::near::RELAY,
    &crate::far::SHADER,
    &crate::lift::SHADER,
    &crate::tile_changes::SHADER,
    &crate::compose::SHADER,
    &crate::shade::SHADER,
    &crate::tonemap::SHADER,
    &crate::radiosity::SHADER,
    &crate::radiosity::DIRECT,
];
