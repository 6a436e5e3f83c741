//! Bind-group tables: each group of each pass described once, as a `const` slice of
//! [`Binding`]s, index = binding number.
//!
//! The same table builds the `wgpu::BindGroupLayout` ([`layout_entries`]), writes the shader's
//! `@group(g) @binding(b) var ...` declarations ([`declarations`], put in front of the pass's
//! WGSL by [`crate::contract::Shader::source`]) and fills the bind group by name ([`bind`]).
//! Shaders never declare bindings themselves, so a layout and its shader cannot disagree about
//! numbers, kinds or access; `runtime/src/tests/contract.rs` still parses every assembled shader with
//! naga and checks each binding's kind, access and visibility against these tables.

use std::fmt::Write;

/// What a binding holds. Buffers carry the WGSL type of their contents.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Res {
    /// `var<uniform>` of this WGSL type.
    Uniform(&'static str),
    /// `var<storage, read>` of this WGSL type.
    Read(&'static str),
    /// `var<storage, read_write>` of this WGSL type.
    ReadWrite(&'static str),
    /// `texture_2d<f32>`, read with `textureLoad` (unfilterable: `Rgba32Float` is not
    /// filterable everywhere).
    Texture2d,
    /// `texture_depth_2d_array`: the shadow maps.
    DepthArray,
    /// `texture_2d_array<f32>`, read with `textureLoad` (the lightmap's pages).
    Texture2dArray,
    /// `texture_storage_2d_array<format, write>` (the lightmap's pages).
    WriteTexture2dArray(wgpu::TextureFormat),
    /// `sampler_comparison`.
    ComparisonSampler,
}

/// One binding of a group: its WGSL variable name, what it holds, and the stages that see it.
#[derive(Clone, Copy, Debug)]
pub struct Binding {
    pub name: &'static str,
    pub res: Res,
    pub stages: wgpu::ShaderStages,
}

/// Compute only.
pub const COMPUTE: wgpu::ShaderStages = wgpu::ShaderStages::COMPUTE;
/// The entry irradiance and the shading: the stages that light surfaces.
pub const LIT: wgpu::ShaderStages = wgpu::ShaderStages::COMPUTE.union(wgpu::ShaderStages::FRAGMENT);
pub const VERTEX: wgpu::ShaderStages = wgpu::ShaderStages::VERTEX;
pub const FRAGMENT: wgpu::ShaderStages = wgpu::ShaderStages::FRAGMENT;
pub const VERTEX_FRAGMENT: wgpu::ShaderStages =
    wgpu::ShaderStages::VERTEX.union(wgpu::ShaderStages::FRAGMENT);

/// A binding named `name` holding `res`, seen by `stages`.
pub const fn b(name: &'static str, res: Res, stages: wgpu::ShaderStages) -> Binding {
    Binding { name, res, stages }
}

impl Res {
    /// The wgpu layout type of this resource.
    pub fn binding_type(self) -> wgpu::BindingType {
        let buffer = |ty| wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None };
        match self {
            Res::Uniform(_) => buffer(wgpu::BufferBindingType::Uniform),
            Res::Read(_) => buffer(wgpu::BufferBindingType::Storage { read_only: true }),
            Res::ReadWrite(_) => buffer(wgpu::BufferBindingType::Storage { read_only: false }),
            Res::Texture2d => wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            Res::DepthArray => wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Depth,
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            Res::Texture2dArray => wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            Res::WriteTexture2dArray(format) => wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format,
                view_dimension: wgpu::TextureViewDimension::D2Array,
            },
            Res::ComparisonSampler => wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
        }
    }

    /// `<address space> name: type` of the WGSL declaration.
    fn wgsl(self, name: &str) -> String {
        match self {
            Res::Uniform(t) => format!("var<uniform> {name}: {t}"),
            Res::Read(t) => format!("var<storage, read> {name}: {t}"),
            Res::ReadWrite(t) => format!("var<storage, read_write> {name}: {t}"),
            Res::Texture2d => format!("var {name}: texture_2d<f32>"),
            Res::DepthArray => format!("var {name}: texture_depth_2d_array"),
            Res::Texture2dArray => format!("var {name}: texture_2d_array<f32>"),
            Res::WriteTexture2dArray(format) => {
                format!("var {name}: texture_storage_2d_array<{}, write>", wgsl_format(format))
            }
            Res::ComparisonSampler => format!("var {name}: sampler_comparison"),
        }
    }
}

/// WGSL's name of a storage-texture format.
fn wgsl_format(format: wgpu::TextureFormat) -> &'static str {
    match format {
        wgpu::TextureFormat::Rgba32Float => "rgba32float",
        wgpu::TextureFormat::Rgba16Float => "rgba16float",
        wgpu::TextureFormat::R32Float => "r32float",
        other => unimplemented!("no storage textures of {other:?} in this runtime"),
    }
}

/// The layout entries of one group, binding `i` = `table[i]`.
pub fn layout_entries(table: &[Binding]) -> Vec<wgpu::BindGroupLayoutEntry> {
    table
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: b.stages,
            ty: b.res.binding_type(),
            count: None,
        })
        .collect()
}

/// The bind group layout of one group.
pub fn layout(device: &wgpu::Device, label: &str, table: &[Binding]) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &layout_entries(table),
    })
}

/// A bind group for `table` from `(name, resource)` pairs: every binding of the table given
/// exactly once, in any order (a missing, unknown or repeated name is a bug: it panics).
pub fn bind(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    table: &[Binding],
    resources: &[(&str, wgpu::BindingResource)],
) -> wgpu::BindGroup {
    assert_eq!(
        resources.len(),
        table.len(),
        "{label}: {} resources for {} bindings",
        resources.len(),
        table.len()
    );
    let entries: Vec<wgpu::BindGroupEntry> = resources
        .iter()
        .map(|(name, resource)| {
            let binding = table
                .iter()
                .position(|b| b.name == *name)
                .unwrap_or_else(|| panic!("{label}: no binding named {name}"));
            assert!(
                resources.iter().filter(|(n, _)| n == name).count() == 1,
                "{label}: binding {name} given twice"
            );
            wgpu::BindGroupEntry { binding: binding as u32, resource: resource.clone() }
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries: &entries })
}

/// The WGSL declarations of every binding of `groups` (group `g` = `groups[g]`).
pub fn declarations(groups: &[&[Binding]]) -> String {
    let mut s = String::new();
    for (g, table) in groups.iter().enumerate() {
        for (i, b) in table.iter().enumerate() {
            let _ = writeln!(s, "@group({g}) @binding({i}) {};", b.res.wgsl(b.name));
        }
    }
    s
}
