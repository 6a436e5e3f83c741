//! Every WGSL struct the runtime shares with Rust has the size and field offsets of its
//! `layout.rs` twin (STYLE.md §2), checked by parsing the shaders with naga.

use std::mem::{offset_of, size_of};

use naga::{Module, TypeInner};
use prm_runtime::layout::*;

fn parse(name: &str, src: &str) -> Module {
    naga::front::wgsl::parse_str(src).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)))
}

/// (size, [(field, offset)]) of the WGSL struct `name`, laid out by naga.
fn wgsl_struct(m: &Module, name: &str) -> (u32, Vec<(String, u32)>) {
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(m.to_ctx()).unwrap();
    for (h, ty) in m.types.iter() {
        if ty.name.as_deref() == Some(name) {
            if let TypeInner::Struct { members, span } = &ty.inner {
                let _ = h;
                return (
                    *span,
                    members.iter().map(|f| (f.name.clone().unwrap_or_default(), f.offset)).collect(),
                );
            }
        }
    }
    panic!("no struct {name}");
}

macro_rules! check {
    ($module:expr, $wgsl:literal, $rust:ty, [$(($wf:literal, $rf:ident)),* $(,)?]) => {{
        let (size, fields) = wgsl_struct(&$module, $wgsl);
        assert_eq!(size as usize, size_of::<$rust>(), "size of {} vs {}", $wgsl, stringify!($rust));
        $(
            let off = fields.iter().find(|f| f.0 == $wf).unwrap_or_else(|| panic!("{} has no field {}", $wgsl, $wf)).1;
            assert_eq!(off as usize, offset_of!($rust, $rf), "{}.{} vs {}.{}", $wgsl, $wf, stringify!($rust), stringify!($rf));
        )*
    }};
}

#[test]
fn every_shader_parses_and_its_structs_match_the_rust_layouts() {
    let irr = parse("irradiance.wgsl", &prm_runtime::irradiance::source());
    let shade = parse("shade.wgsl", &prm_runtime::shade::source());
    let weights = parse("weights.wgsl", prm_runtime::weights::SOURCE);
    let compose = parse("compose.wgsl", prm_runtime::compose::SOURCE);
    parse("shadow.wgsl", include_str!("../../shaders/shadow.wgsl"));
    let tonemap = parse("tonemap.wgsl", prm_runtime::tonemap::SOURCE);
    check!(tonemap, "TonemapParams", TonemapParams, [("exposure", exposure), ("encode", encode)]);
    for m in [&irr, &shade] {
        check!(
            m,
            "Light",
            GpuLight,
            [
                ("position", position),
                ("kind", kind),
                ("direction", direction),
                ("range", range),
                ("intensity", intensity),
                ("first_layer", first_layer),
                ("cos_inner", cos_inner),
                ("cos_outer", cos_outer),
                ("texel", texel),
                ("layers", layers),
            ]
        );
    }
    check!(irr, "Entry", GpuEntry, [("position", position), ("normal", normal)]);
    for m in [&irr, &weights] {
        check!(
            m,
            "Params",
            IndirectParams,
            [
                ("entry_count", entry_count),
                ("light_count", light_count),
                ("cluster_count", cluster_count),
                ("top_k", top_k),
                ("group_count", group_count),
                ("residual", residual)
            ]
        );
    }
    check!(
        compose,
        "Params",
        ComposeParams,
        [
            ("atlas_width", atlas_width),
            ("atlas_height", atlas_height),
            ("tile_size", tile_size),
            ("tiles_x", tiles_x),
            ("tile_count", tile_count),
            ("active_stride", active_stride)
        ]
    );
    check!(
        compose,
        "ActiveRecord",
        ActiveRecord,
        [("weighted_scale", weighted_scale), ("data_offset", data_offset)]
    );
    check!(
        compose,
        "TileRecord",
        TileRecord,
        [("scale", scale), ("cluster", cluster), ("data_offset", data_offset)]
    );
    check!(
        shade,
        "ShadeParams",
        ShadeParams,
        [
            ("view_proj", view_proj),
            ("light_count", light_count),
            ("indirect_scale", indirect_scale),
            ("atlas_width", atlas_width),
            ("atlas_height", atlas_height)
        ]
    );
    // Vertex attributes: each location's offset is the Rust field's.
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
}
