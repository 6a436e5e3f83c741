//! The GPU contract (STYLE.md §2), checked without a GPU: every shader, assembled as the runtime
//! assembles it (`crate::contract`), parses and validates with naga, and
//! - every struct of `layout.rs` has, as naga lays out its generated WGSL twin, the size and
//!   field offsets of the Rust struct;
//! - the set of `@group @binding`s equals the Rust bind-group tables', each with the table's
//!   kind (uniform, storage read / read-write, texture, storage texture and format, sampler),
//!   and every entry point that uses a binding runs in a stage the table makes it visible to;
//! - compute entry points are exactly those the Rust side dispatches, with its workgroup sizes;
//! - the prelude's constants have the Rust values, and the shading vertex inputs the Rust
//!   vertex attributes' locations and formats.
//!
//! Each checker returns its complaints, so the tests at the end can show that a wrong table,
//! workgroup size or struct is caught.

use std::collections::BTreeMap;
use std::mem::{offset_of, size_of};

use crate::bindings::{Binding, Res};
use crate::contract::{self, Compute, Library, Shader, SHADERS};
use crate::layout::{gpu_structs, Field, ShadeVertex};
use naga::valid::{Capabilities, ModuleInfo, ValidationFlags, Validator};
use naga::{AddressSpace, ImageClass, ImageDimension, Module, ScalarKind, StorageAccess, TypeInner};

fn parse(label: &str, src: &str) -> (Module, ModuleInfo) {
    let module =
        naga::front::wgsl::parse_str(src).unwrap_or_else(|e| panic!("{label}: {}", e.emit_to_string(src)));
    // unpack2x16float (compose) needs SHADER_FLOAT16_IN_FLOAT32, which wgpu grants every
    // adapter it gives a full (non-downlevel WebGL) device.
    let caps = Capabilities::default() | Capabilities::SHADER_FLOAT16_IN_FLOAT32;
    let info = Validator::new(ValidationFlags::all(), caps)
        .validate(&module)
        .unwrap_or_else(|e| panic!("{label}: {}", e.emit_to_string(src)));
    (module, info)
}

fn assembled(shader: &Shader) -> (Module, ModuleInfo) {
    parse(&shader.label(), &shader.source())
}

/// Complaints about the WGSL struct `name` against a Rust struct of `size` bytes and `fields`.
fn check_struct(m: &Module, name: &str, size: usize, fields: &[Field]) -> Vec<String> {
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(m.to_ctx()).unwrap();
    let Some((_, ty)) = m.types.iter().find(|(_, t)| t.name.as_deref() == Some(name)) else {
        return vec![format!("no WGSL struct {name}")];
    };
    let TypeInner::Struct { members, span } = &ty.inner else { return vec![format!("{name} is no struct")] };
    let mut bad = Vec::new();
    if *span as usize != size {
        bad.push(format!("{name}: WGSL size {span}, Rust {size}"));
    }
    let wgsl: Vec<(&str, usize)> =
        members.iter().map(|f| (f.name.as_deref().unwrap_or(""), f.offset as usize)).collect();
    let rust: Vec<(&str, usize)> = fields.iter().map(|f| (f.name, f.offset)).collect();
    if wgsl != rust {
        bad.push(format!("{name}: WGSL fields {wgsl:?}, Rust {rust:?}"));
    }
    bad
}

/// The wgpu stage of a naga entry point.
fn stage(s: naga::ShaderStage) -> wgpu::ShaderStages {
    match s {
        naga::ShaderStage::Vertex => wgpu::ShaderStages::VERTEX,
        naga::ShaderStage::Fragment => wgpu::ShaderStages::FRAGMENT,
        naga::ShaderStage::Compute => wgpu::ShaderStages::COMPUTE,
        other => panic!("no {other:?} shaders in this runtime"),
    }
}

/// Whether naga's global (address space, type) is what the layout entry `ty` binds.
fn same_kind(space: AddressSpace, inner: &TypeInner, ty: wgpu::BindingType) -> bool {
    use wgpu::{BindingType as B, BufferBindingType as Buf};
    match (ty, space, inner) {
        (B::Buffer { ty: Buf::Uniform, .. }, AddressSpace::Uniform, _) => true,
        (B::Buffer { ty: Buf::Storage { read_only }, .. }, AddressSpace::Storage { access }, _) => {
            read_only != access.contains(StorageAccess::STORE)
        }
        (
            B::Texture { sample_type, view_dimension, multisampled },
            AddressSpace::Handle,
            TypeInner::Image { dim: ImageDimension::D2, arrayed, class },
        ) => {
            let dim_ok = *arrayed == (view_dimension == wgpu::TextureViewDimension::D2Array)
                && matches!(
                    view_dimension,
                    wgpu::TextureViewDimension::D2 | wgpu::TextureViewDimension::D2Array
                );
            let class_ok = match (sample_type, class) {
                (wgpu::TextureSampleType::Depth, ImageClass::Depth { multi }) => *multi == multisampled,
                (
                    wgpu::TextureSampleType::Float { .. },
                    ImageClass::Sampled { kind: ScalarKind::Float, multi },
                ) => *multi == multisampled,
                _ => false,
            };
            dim_ok && class_ok
        }
        (
            B::StorageTexture {
                access,
                format,
                view_dimension: view @ (wgpu::TextureViewDimension::D2 | wgpu::TextureViewDimension::D2Array),
            },
            AddressSpace::Handle,
            TypeInner::Image {
                dim: ImageDimension::D2,
                arrayed,
                class: ImageClass::Storage { format: f, access: a },
            },
        ) if *arrayed == (view == wgpu::TextureViewDimension::D2Array) => {
            let access_ok = match access {
                wgpu::StorageTextureAccess::WriteOnly => *a == StorageAccess::STORE,
                wgpu::StorageTextureAccess::ReadOnly => *a == StorageAccess::LOAD,
                _ => *a == StorageAccess::LOAD | StorageAccess::STORE,
            };
            access_ok && texture_format(*f) == Some(format)
        }
        (B::Sampler(s), AddressSpace::Handle, TypeInner::Sampler { comparison }) => {
            *comparison == (s == wgpu::SamplerBindingType::Comparison)
        }
        _ => false,
    }
}

fn texture_format(f: naga::StorageFormat) -> Option<wgpu::TextureFormat> {
    match f {
        naga::StorageFormat::Rgba32Float => Some(wgpu::TextureFormat::Rgba32Float),
        naga::StorageFormat::Rgba16Float => Some(wgpu::TextureFormat::Rgba16Float),
        naga::StorageFormat::R32Float => Some(wgpu::TextureFormat::R32Float),
        _ => None,
    }
}

/// Complaints about the module's bindings against `groups` (the Rust tables, through the very
/// layout entries the runtime creates).
fn check_bindings(m: &Module, info: &ModuleInfo, groups: &[&[Binding]]) -> Vec<String> {
    let mut bad = Vec::new();
    let mut wgsl = BTreeMap::new();
    for (h, g) in m.global_variables.iter() {
        if let Some(rb) = &g.binding {
            wgsl.insert((rb.group, rb.binding), (h, g));
        }
    }
    let mut rust = BTreeMap::new();
    for (gi, table) in groups.iter().enumerate() {
        for entry in crate::bindings::layout_entries(table) {
            rust.insert((gi as u32, entry.binding), (table[entry.binding as usize].name, entry));
        }
    }
    let (wk, rk): (Vec<_>, Vec<_>) = (wgsl.keys().collect(), rust.keys().collect());
    if wk != rk {
        bad.push(format!("(group, binding)s: WGSL {wk:?}, Rust {rk:?}"));
    }
    for (key, (h, g)) in &wgsl {
        let Some((name, entry)) = rust.get(key) else { continue };
        let wname = g.name.as_deref().unwrap_or("");
        if wname != *name {
            bad.push(format!("{key:?}: WGSL {wname}, Rust {name}"));
        }
        if !same_kind(g.space, &m.types[g.ty].inner, entry.ty) {
            bad.push(format!(
                "{key:?} {wname}: WGSL {:?} {:?}, Rust {:?}",
                g.space, m.types[g.ty].inner, entry.ty
            ));
        }
        for (i, ep) in m.entry_points.iter().enumerate() {
            let s = stage(ep.stage);
            if !info.get_entry_point(i)[*h].is_empty() && !entry.visibility.contains(s) {
                bad.push(format!(
                    "{key:?} {wname}: used by {} ({s:?}), visible to {:?}",
                    ep.name, entry.visibility
                ));
            }
        }
    }
    bad
}

/// Complaints about the compute entry points against the Rust dispatch list.
fn check_compute(m: &Module, compute: &[Compute]) -> Vec<String> {
    let wgsl: BTreeMap<&str, [u32; 3]> = m
        .entry_points
        .iter()
        .filter(|e| e.stage == naga::ShaderStage::Compute)
        .map(|e| (e.name.as_str(), e.workgroup_size))
        .collect();
    let rust: BTreeMap<&str, [u32; 3]> = compute.iter().map(|c| (c.entry, c.workgroup)).collect();
    if wgsl == rust {
        Vec::new()
    } else {
        vec![format!("compute entry points and workgroup sizes: WGSL {wgsl:?}, Rust {rust:?}")]
    }
}

#[test]
fn every_shader_matches_the_rust_structs_bindings_and_workgroup_sizes() {
    let stems: Vec<&str> = SHADERS.iter().map(|s| s.stem).collect();
    for stem in ["shadow", "irradiance", "weights", "compose", "shade", "tonemap"] {
        assert!(stems.contains(&stem), "{stem} missing from contract::SHADERS");
    }
    for shader in SHADERS {
        let (m, info) = assembled(shader);
        let mut bad = Vec::new();
        for (name, _, size, fields) in gpu_structs() {
            bad.extend(check_struct(&m, name, size, fields));
        }
        bad.extend(check_bindings(&m, &info, shader.groups));
        bad.extend(check_compute(&m, shader.compute));
        assert!(bad.is_empty(), "{}:\n{}", shader.label(), bad.join("\n"));
    }
}

#[test]
fn the_prelude_constants_have_the_rust_values() {
    let (m, _) = parse("prelude", contract::prelude());
    for (name, value) in contract::U32_CONSTANTS {
        let (_, c) = m
            .constants
            .iter()
            .find(|(_, c)| c.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("no WGSL const {name}"));
        let e = &m.global_expressions[c.init];
        assert!(
            matches!(e, naga::Expression::Literal(naga::Literal::U32(v)) if v == value),
            "{name}: WGSL {e:?}, Rust {value}"
        );
    }
}

/// What the prelude provides must not be written again in a shader's own WGSL: literal
/// workgroup sizes, the slot sentinel, the cube's layer count, luminance weights, light kinds,
/// or bindings and structs of their own (those would be checked, but could still drift).
#[test]
fn no_shader_writes_the_contract_by_hand() {
    let libraries = Library::ALL.map(|l| (l.stem(), l.source()));
    let bodies = SHADERS.iter().map(|s| (s.stem, s.body)).chain(libraries);
    let forbidden = [
        "@workgroup_size(6",
        "@workgroup_size(8",
        "0xffffffff",
        "4294967295",
        "== 6u",
        "0.2126",
        "0.7152",
        "@group(",
        "@binding(",
        "struct GpuLight",
        "struct IndirectParams",
        "fn luminance",
        "fn range_window",
        "fn spot_falloff",
        "const PI",
        "3.14159",
    ];
    for (stem, body) in bodies {
        for f in forbidden {
            assert!(!body.contains(f), "shaders/{stem}.wgsl writes `{f}`: take it from the prelude");
        }
    }
}

/// A helper function is written in one WGSL file: where two passes need it, it goes into a
/// [`Library`] both include (entry points, `*_main`, are each pass's own).
#[test]
fn no_wgsl_function_is_written_twice() {
    let libraries = Library::ALL.map(|l| (l.stem(), l.source()));
    let mut seen: BTreeMap<&str, &str> = BTreeMap::new();
    for (stem, body) in SHADERS.iter().map(|s| (s.stem, s.body)).chain(libraries) {
        for line in body.lines() {
            let Some(rest) = line.strip_prefix("fn ") else { continue };
            let name = rest.split('(').next().unwrap_or(rest).trim();
            if name.ends_with("_main") {
                continue;
            }
            if let Some(first) = seen.insert(name, stem) {
                panic!(
                    "fn {name} is written in shaders/{first}.wgsl and shaders/{stem}.wgsl: make it a Library"
                );
            }
        }
    }
    assert!(seen.contains_key("polygon_form_factor"), "the form factor library was not read");
}

#[test]
fn the_shading_vertex_inputs_are_the_rust_vertex_attributes() {
    // Rust: each attribute's offset is its field's, and they end at the struct's end.
    let offsets = [
        offset_of!(ShadeVertex, position),
        offset_of!(ShadeVertex, normal),
        offset_of!(ShadeVertex, uv1),
        offset_of!(ShadeVertex, albedo),
        offset_of!(ShadeVertex, emissive),
        offset_of!(ShadeVertex, double_sided),
    ];
    for (a, off) in ShadeVertex::ATTRIBUTES.iter().zip(offsets) {
        assert_eq!(a.offset as usize, off, "vertex attribute {}", a.shader_location);
    }
    let last = ShadeVertex::ATTRIBUTES.last().unwrap();
    assert_eq!(last.offset as usize + last.format.size() as usize, size_of::<ShadeVertex>());
    // WGSL: vs_main's inputs have the attributes' locations, component counts and kinds.
    let (m, _) = assembled(&crate::shade::SHADER);
    let vs = m.entry_points.iter().find(|e| e.name == "vs_main").expect("shade.wgsl has vs_main");
    let TypeInner::Struct { members, .. } = &m.types[vs.function.arguments[0].ty].inner else {
        panic!("vs_main takes a struct")
    };
    let mut wgsl = Vec::new();
    for f in members {
        let Some(naga::Binding::Location { location, .. }) = f.binding else { continue };
        let (n, kind) = match m.types[f.ty].inner {
            TypeInner::Scalar(s) => (1, s.kind),
            TypeInner::Vector { size, scalar } => (size as u32, scalar.kind),
            ref other => panic!("vertex input {other:?}"),
        };
        wgsl.push((location, n, kind));
    }
    let rust: Vec<(u32, u32, ScalarKind)> = ShadeVertex::ATTRIBUTES
        .iter()
        .map(|a| {
            let (n, kind) = match a.format {
                wgpu::VertexFormat::Float32x2 => (2, ScalarKind::Float),
                wgpu::VertexFormat::Float32x3 => (3, ScalarKind::Float),
                wgpu::VertexFormat::Uint32 => (1, ScalarKind::Uint),
                other => panic!("add {other:?} here"),
            };
            (a.shader_location, n, kind)
        })
        .collect();
    assert_eq!(wgsl, rust);
}

// The checkers catch what they are for.

#[test]
fn a_wrong_binding_table_is_caught() {
    use crate::bindings::{b, COMPUTE, FRAGMENT};
    let shader = crate::compose::SHADER;
    let (m, info) = assembled(&shader);
    let table = crate::compose::BINDINGS;
    assert!(check_bindings(&m, &info, &[table]).is_empty());
    // Read-write where the shader reads only.
    let mut access = table.to_vec();
    access[1] = b("selected", Res::ReadWrite("array<vec4f>"), COMPUTE);
    // A binding the shader does not declare.
    let mut extra = table.to_vec();
    extra.push(b("spare", Res::Read("array<u32>"), COMPUTE));
    // Visible to the wrong stage.
    let mut stages = table.to_vec();
    stages[0] = b("params", Res::Uniform("ComposeParams"), FRAGMENT);
    // A texture where the shader has a buffer.
    let mut kind = table.to_vec();
    kind[4] = b("slots", Res::Texture2d, COMPUTE);
    // Another storage-texture format.
    let mut format = table.to_vec();
    format[6] = b("lightmap", Res::WriteTexture2dArray(wgpu::TextureFormat::Rgba16Float), COMPUTE);
    for (what, wrong) in
        [("access", access), ("extra", extra), ("stages", stages), ("kind", kind), ("format", format)]
    {
        assert!(!check_bindings(&m, &info, &[&wrong]).is_empty(), "a wrong {what} passed");
    }
    // A binding the tables lack, declared by a shader itself.
    let src = format!("{}\n@group(0) @binding(10) var<storage, read> stray: array<u32>;\n", shader.source());
    let (m, info) = parse("compose + stray", &src);
    assert!(!check_bindings(&m, &info, &[table]).is_empty(), "an undeclared binding passed");
}

#[test]
fn a_wrong_workgroup_size_or_entry_point_is_caught() {
    let (m, _) = assembled(&crate::compose::SHADER);
    let right = crate::compose::SHADER.compute;
    assert!(check_compute(&m, right).is_empty());
    let mut size = right.to_vec();
    size[0].workgroup = [32, 1, 1];
    assert!(!check_compute(&m, &size).is_empty());
    assert!(!check_compute(&m, &right[..1]).is_empty());
}

#[test]
fn a_wrong_struct_layout_is_caught() {
    let (m, _) = assembled(&crate::tonemap::SHADER);
    let fields = [
        Field { name: "exposure", wgsl: "f32", offset: 0 },
        Field { name: "encode", wgsl: "u32", offset: 4 },
        Field { name: "_pad0", wgsl: "u32", offset: 8 },
        Field { name: "_pad1", wgsl: "u32", offset: 12 },
    ];
    assert!(check_struct(&m, "TonemapParams", 16, &fields).is_empty());
    assert!(!check_struct(&m, "TonemapParams", 12, &fields[..3]).is_empty());
    let mut moved = fields;
    moved[1].offset = 8;
    assert!(!check_struct(&m, "TonemapParams", 16, &moved).is_empty());
    // vec3f is 16-aligned in WGSL: a u32 then a vec3f is not at 4 as repr(C) would put it.
    let src = "struct S { a: u32, b: vec3f }";
    let (m, _) = parse("S", src);
    let repr_c = [Field { name: "a", wgsl: "u32", offset: 0 }, Field { name: "b", wgsl: "vec3f", offset: 4 }];
    assert!(!check_struct(&m, "S", 16, &repr_c).is_empty());
}
