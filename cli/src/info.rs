//! `prm info`: what a level contains and what its lightmap will look like.

use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use prm::{Light, LightKind, Scene, TexelSet};
use serde_json::{json, Value};

use crate::common::{check_atlas, load, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// Atlas width and height in texels for the texel facts.
    #[arg(long, default_value_t = 256)]
    atlas: u32,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// The lightmap side of the facts: the texel set at `atlas`², its UV charts and build time.
struct Lightmap {
    set: TexelSet,
    atlas: u32,
    charts: u32,
    build_seconds: f64,
}

impl Lightmap {
    /// Atlas texels in all (covered or not).
    fn total(&self) -> f64 {
        (self.atlas as f64) * (self.atlas as f64)
    }
}

pub fn run(a: Args) -> Result<()> {
    check_atlas(a.atlas)?;
    let scene = load(&a.scene, a.atlas, a.json)?;
    let start = Instant::now();
    let set = TexelSet::build_visible(&scene, &prm::Bvh::build(&scene), a.atlas, a.atlas);
    let build_seconds = start.elapsed().as_secs_f64();
    let charts = prm::uv::charts(&scene).iter().max().map_or(0, |m| m + 1);
    let lm = Lightmap { set, atlas: a.atlas, charts, build_seconds };
    let summary = summary(&a.scene.scene, &scene, &lm);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    print_level(&a.scene.scene, &scene, &summary);
    print_lightmap(&scene, &lm, &summary);
    Ok(())
}

/// A light as JSON, its kind in words and the unit of its intensity.
fn light_json(l: &Light) -> Value {
    let kind = match l.kind {
        LightKind::Point => "point".to_string(),
        LightKind::Directional => "directional".to_string(),
        LightKind::Spot { inner, outer } => {
            format!("spot {:.1}/{:.1} deg", inner.to_degrees(), outer.to_degrees())
        }
    };
    json!({
        "name": l.name, "kind": kind, "position": l.position.to_array(),
        "direction": l.direction.to_array(), "intensity": l.intensity.to_array(),
        "unit": if l.is_positional() {"W/sr"} else {"W/m2"},
    })
}

/// Every fact, as `--json` prints it.
fn summary(path: &Path, scene: &Scene, lm: &Lightmap) -> Value {
    let (lo, hi) = scene.bounds();
    let (r, set) = (&scene.report, &lm.set);
    json!({
        "scene": path.display().to_string(),
        "triangles": scene.triangles.len(),
        "vertices": scene.positions.len(),
        "materials": scene.materials.len() - 1,
        "degenerate_dropped": r.degenerate_dropped,
        "non_triangle_primitives": r.non_triangle_primitives,
        "bounds_min": lo.to_array(), "bounds_max": hi.to_array(),
        "surface_area": scene.total_area(),
        "lights": scene.lights.iter().map(light_json).collect::<Vec<_>>(),
        "cameras": scene.cameras.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
        "uv": {
            "generated": r.uv1_generated,
            "charts": lm.charts,
            "triangles_out_of_range": r.uv_out_of_range,
            "overlapping_pairs": r.uv_overlapping_pairs,
            "zero_area_triangles": set.zero_uv_area_triangles,
        },
        "texels": {
            "atlas": lm.atlas,
            "covered": set.len(),
            "coverage": set.len() as f64 / lm.total(),
            "dilated": set.dilation.len(),
            "gutter_texels_shared_by_charts": set.shared_gutter_texels,
            "buried_points_moved": set.buried.moved,
            "buried_texels_dropped": set.buried.dropped,
            "world_texel_size": (scene.total_area() / set.len().max(1) as f64).sqrt(),
            "build_seconds": lm.build_seconds,
        },
        "notes": r.notes,
    })
}

/// The text facts about the level itself: geometry, lights and cameras.
fn print_level(path: &Path, scene: &Scene, summary: &Value) {
    let (lo, hi) = scene.bounds();
    println!("{}", path.display());
    println!(
        "  triangles   {} ({} vertices, {} materials), {} zero-area dropped",
        scene.triangles.len(),
        scene.positions.len(),
        scene.materials.len() - 1,
        scene.report.degenerate_dropped
    );
    println!(
        "  bounds      {:.4?} .. {:.4?} (diagonal {:.4}), surface area {:.4}",
        lo.to_array(),
        hi.to_array(),
        scene.diagonal(),
        scene.total_area()
    );
    println!("  lights      {}", scene.lights.len());
    for l in &summary["lights"].as_array().cloned().unwrap_or_default() {
        println!(
            "    {} {}: at {} dir {} intensity {} {}",
            l["kind"].as_str().unwrap_or(""),
            l["name"],
            l["position"],
            l["direction"],
            l["intensity"],
            l["unit"].as_str().unwrap_or("")
        );
    }
    println!(
        "  cameras     {}",
        scene.cameras.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")
    );
}

/// The text facts about the lightmap: UV charts, texels, and the loader's notes.
fn print_lightmap(scene: &Scene, lm: &Lightmap, summary: &Value) {
    let (r, set) = (&scene.report, &lm.set);
    println!(
        "  lightmap UV {} charts{}, {} triangles outside [0,1], {} overlapping pairs, {} with zero UV area",
        lm.charts,
        if r.uv1_generated { " (generated)" } else { " (TEXCOORD_1)" },
        r.uv_out_of_range,
        r.uv_overlapping_pairs,
        set.zero_uv_area_triangles
    );
    println!(
        "  texels      {} of {}^2 covered ({:.1} %), {} dilated, {} gutter texels shared by charts, {} buried \
            points moved and {} buried texels dropped, ~{:.4} units per texel, built in {:.3} s",
        set.len(),
        lm.atlas,
        100.0 * set.len() as f64 / lm.total(),
        set.dilation.len(),
        set.shared_gutter_texels,
        set.buried.moved,
        set.buried.dropped,
        summary["texels"]["world_texel_size"].as_f64().unwrap_or(0.0),
        lm.build_seconds
    );
    for n in &r.notes {
        println!("  note        {n}");
    }
}
