//! `prm info`: what a level contains and what its lightmap will look like.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use prm::prm_file::Prm;
use prm::{Light, LightKind, Scene, TexelSet};
use serde_json::{json, Value};

use crate::common::{load_for, AtlasArgs, SceneArgs};
use crate::precompute::Preset;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    lightmap: AtlasArgs,
    /// A .prm baked for this level: the lightmap facts are the map's atlas, and the GPU memory
    /// the runtime needs for it is stated.
    #[arg(long)]
    prm: Option<PathBuf>,
    /// Shadow-map size (texels a side) the GPU memory is stated at.
    #[arg(long, default_value_t = 1024)]
    shadow_size: u32,
    /// With --prm: what a GPU memory budget of this many MB (1e6 bytes) would leave out, seen
    /// from the level's first camera (as `prm render --gpu-budget` does).
    #[arg(long, requires = "prm")]
    gpu_budget: Option<f64>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// The lightmap side of the facts: the texel set over `atlas`, its UV charts and build time.
struct Lightmap {
    set: TexelSet,
    atlas: prm::density::Atlas,
    /// The texel size asked for, and which option set the atlas.
    texel_size: f32,
    atlas_from: &'static str,
    charts: u32,
    build_seconds: f64,
}

impl Lightmap {
    /// Atlas texels in all (covered or not).
    fn total(&self) -> f64 {
        self.atlas.texels() as f64
    }
}

pub fn run(a: Args) -> Result<()> {
    let map = match &a.prm {
        Some(path) => Some(Prm::read(path, None).with_context(|| "reading the radiance map failed")?),
        None => None,
    };
    let (scene, atlas) = match (&map, &a.prm) {
        (Some(map), Some(path)) => {
            let scene = load_for(&a.scene, map.header(), a.json)?;
            map.check_scene(path, &scene)?;
            (scene, map.header().atlas())
        }
        _ => a.lightmap.load(&a.scene, a.json)?,
    };
    let start = Instant::now();
    let bvh = prm::Bvh::build(&scene);
    let set = TexelSet::build_visible(&scene, &bvh, atlas.width(), atlas.height());
    let build_seconds = start.elapsed().as_secs_f64();
    let charts = prm::uv::charts(&scene).iter().max().map_or(0, |m| m + 1);
    let atlas_from = if a.lightmap.atlas.is_some() { "--atlas" } else { "--texel-size" };
    let lm = Lightmap { set, atlas, texel_size: a.lightmap.texel_size, atlas_from, charts, build_seconds };
    let mut summary = summary(&a.scene.scene, &scene, &bvh, &lm);
    if let Some(map) = &map {
        let file_bytes = a.prm.as_ref().and_then(|p| std::fs::metadata(p).ok()).map_or(0, |m| m.len());
        summary["gpu_memory"] = gpu_memory(map, &scene, a.shadow_size, file_bytes);
        // The rooms the runtime keeps the near field's energy in (prm_runtime::cpu::rooms).
        let rooms = prm_runtime::cpu::rooms::room_count(&prm_runtime::cpu::rooms::cluster_rooms(map));
        summary["runtime_rooms"] = Value::from(rooms);
        summary["stay_shares"] = stay_shares(map);
        // Each pane scaled to the power its cells send (`prm_precompute::precompute::
        // match_power`): the least and most scale, absent for a map made without it.
        summary["power_scale"] = map.header().provenance.get("power_scale").cloned().unwrap_or(Value::Null);
        if let Some(mb) = a.gpu_budget {
            let camera = crate::render::camera(&scene, None)?;
            let aspect = camera.aspect.unwrap_or(1.0);
            let (_, outcome) = crate::budget::fit_for_camera(
                &scene,
                map.clone(),
                &camera,
                aspect,
                &scene.lights,
                &prm_runtime::RuntimeParams { shadow_size: a.shadow_size, ..Default::default() },
                mb,
            )?;
            summary["gpu_memory"]["budget"] = serde_json::to_value(&outcome)?;
            summary["gpu_memory"]["budget"]["text"] = Value::String(crate::budget::describe(&outcome));
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    print_level(&a.scene.scene, &scene, &summary);
    print_lightmap(&scene, &lm, &summary);
    if map.is_some() {
        println!(
            "runtime rooms: {} (clusters joined by entries that see each other; the near field's \
            energy is kept room by room)",
            summary["runtime_rooms"]
        );
        let st = &summary["stay_shares"];
        println!(
            "stay shares: {} of {} entries lose more than {:.0} % of their light through openings (mean share {:.3}, \
            lowest {:.2})",
            st["losing"],
            st["entries"],
            100.0 * (1.0 - LOSING_SHARE),
            st["mean"].as_f64().unwrap_or(1.0),
            st["lowest"].as_f64().unwrap_or(1.0)
        );
        println!(
            "bounce gains: {:.2} to {:.2}, mean {:.2} (light landing over every bounce per unit a cell reflects, \
            luminance; how each entry's light counts in its cluster's weight)",
            st["gain_lowest"].as_f64().unwrap_or(1.0),
            st["gain_highest"].as_f64().unwrap_or(1.0),
            st["gain_mean"].as_f64().unwrap_or(1.0)
        );
        match summary["power_scale"]
            .as_array()
            .map(|r| r.iter().filter_map(Value::as_f64).collect::<Vec<_>>())
        {
            Some(r) if r.len() == 2 => println!(
                "pane power: each pane scaled by {:.3} to {:.3} to deliver what its cells send to the level",
                r[0], r[1]
            ),
            _ => {
                println!("pane power: the panes as walked (baked with --no-power-match or before session 84)")
            }
        }
        print_gpu_memory(&summary["gpu_memory"]);
        if let Some(text) = summary["gpu_memory"]["budget"]["text"].as_str() {
            println!("  {text}");
        }
    }
    Ok(())
}

/// An entry whose stay share is under this loses light through an opening (`prm info --prm`).
const LOSING_SHARE: f32 = 0.95;

/// The map's stay shares (`prm::prm_file::Prm::stay`): how many entries lose light through an
/// opening (a share under [`LOSING_SHARE`]), their mean and the lowest. A closed level's are
/// all 1; a window's reveals and a façade's show here. And the bounce gains'
/// (`Prm::gain`, in luminance) range and mean: about `1 / (1 - albedo)` in a closed room.
fn stay_shares(map: &Prm) -> Value {
    let n = map.entries().len();
    let shares: Vec<f32> = (0..n).map(|j| map.stay(j)).collect();
    let gains: Vec<f32> = (0..n).map(|j| prm::luminance(map.gain(j))).collect();
    let mean = |v: &[f32]| if n > 0 { v.iter().map(|&s| s as f64).sum::<f64>() / n as f64 } else { 1.0 };
    json!({
        "entries": n,
        "losing": shares.iter().filter(|&&s| s < LOSING_SHARE).count(),
        "mean": mean(&shares),
        "lowest": shares.iter().copied().fold(1.0f32, f32::min),
        "gain_mean": mean(&gains),
        "gain_lowest": gains.iter().copied().reduce(f32::min).unwrap_or(1.0),
        "gain_highest": gains.iter().copied().reduce(f32::max).unwrap_or(1.0),
    })
}

/// The device memory the runtime needs for `map` (`prm_runtime::GpuMemory::estimate`), and the
/// shadow maps of the level's own lights at `shadow_size`.
fn gpu_memory(map: &Prm, scene: &Scene, shadow_size: u32, file_bytes: u64) -> Value {
    let tables = prm_runtime::GpuMemory::estimate(map);
    let sun_tiles = prm_runtime::memory::sun_tiles(scene, prm_runtime::memory::SUN_TILES_MAX);
    let shadows = prm_runtime::memory::shadow_bytes(&scene.lights, shadow_size, sun_tiles);
    let mut items = tables.items.clone();
    items.sort_by_key(|(_, b)| std::cmp::Reverse(*b));
    json!({
        "tables_bytes": tables.total(),
        "tables": items.iter().map(|(n, b)| json!({"name": n, "bytes": b})).collect::<Vec<_>>(),
        "shadow_maps_bytes": shadows,
        "shadow_size": shadow_size,
        // Tiles per side of a directional light's map over this level (the runtime's default).
        "sun_tiles": sun_tiles,
        "total_bytes": tables.total() + shadows,
        "file_bytes": file_bytes,
    })
}

fn print_gpu_memory(m: &Value) {
    let mb = |v: &Value| v.as_f64().unwrap_or(0.0) / 1e6;
    let largest: Vec<String> = m["tables"]
        .as_array()
        .map(|t| {
            t.iter()
                .take(5)
                .map(|i| format!("{} {:.1}", i["name"].as_str().unwrap_or(""), mb(&i["bytes"])))
                .collect()
        })
        .unwrap_or_default();
    let tiles = m["sun_tiles"].as_u64().unwrap_or(1);
    println!(
        "  gpu memory  {:.1} MB: the map's tables {:.1} MB (largest: {} MB), the level's lights' shadow maps \
            {:.1} MB at {}^2{} (the .prm file is {:.1} MB)",
        mb(&m["total_bytes"]),
        mb(&m["tables_bytes"]),
        largest.join(", "),
        mb(&m["shadow_maps_bytes"]),
        m["shadow_size"],
        if tiles > 1 { format!(", a sun's in {tiles} x {tiles} tiles") } else { String::new() },
        mb(&m["file_bytes"])
    );
}

/// A light as JSON, its kind and aperture in words, the unit of its intensity, and for a
/// sphere light that reaches into the level's geometry how close that comes to its centre.
fn light_json(l: &Light, bvh: &prm::Bvh) -> Value {
    let kind = match l.kind {
        LightKind::Point => "point".to_string(),
        LightKind::Directional => "directional".to_string(),
        LightKind::Spot { inner, outer } => {
            format!("spot {:.1}/{:.1} deg", inner.to_degrees(), outer.to_degrees())
        }
    };
    let aperture = match &l.aperture {
        prm::light::Aperture::Point => "point".to_string(),
        prm::light::Aperture::Sphere { radius } => format!("sphere of radius {radius:.4} m"),
        prm::light::Aperture::Polygon { corners } => format!(
            "polygon of {} corners, {:.4} m2",
            corners.len(),
            0.5 * prm::light::polygon_twice_area(corners).length()
        ),
    };
    json!({
        "name": l.name, "kind": kind, "aperture": aperture, "position": l.position.to_array(),
        "direction": l.direction.to_array(), "intensity": l.intensity.to_array(),
        "unit": if l.is_positional() {"W/sr"} else {"W/m2"},
        "geometry_inside": bvh.geometry_inside_sphere(l),
    })
}

/// Every fact, as `--json` prints it.
fn summary(path: &Path, scene: &Scene, bvh: &prm::Bvh, lm: &Lightmap) -> Value {
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
        "lights": scene.lights.iter().map(|l| light_json(l, bvh)).collect::<Vec<_>>(),
        "cameras": scene.cameras.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
        "uv": {
            "generated": r.uv1_generated,
            "charts": lm.charts,
            "triangles_out_of_range": r.uv_out_of_range,
            "overlapping_pairs": r.uv_overlapping_pairs,
            "zero_area_triangles": set.zero_uv_area_triangles,
        },
        "texels": {
            "atlas": lm.atlas.side,
            "pages": lm.atlas.pages,
            "covered": set.len(),
            "coverage": set.len() as f64 / lm.total(),
            "dilated": set.dilation.len(),
            "gutter_texels_shared_by_charts": set.shared_gutter_texels,
            "buried_points_moved": set.buried.moved,
            "buried_texels_dropped": set.buried.dropped,
            "world_texel_size": (scene.total_area() / set.len().max(1) as f64).sqrt(),
            "build_seconds": lm.build_seconds,
        },
        "density": density_json(scene, lm),
        "notes": r.notes,
    })
}

/// The densities the presets stand for and the counts they give this level (what
/// `prm precompute` uses when no count is given).
fn density_json(scene: &Scene, lm: &Lightmap) -> Value {
    let area = scene.total_area();
    let counts = |preset: Preset| {
        let (d, mut p) = (preset.density(), preset.params());
        p.fit_to_area(&d, area, [None; 3]);
        json!({
            "entries_per_m2": d.entries_per_m2, "entries_per_cluster": d.entries_per_cluster,
            "clusters_per_group": d.clusters_per_group,
            "entries": p.entries, "clusters": p.clusters, "groups": p.groups,
        })
    };
    json!({
        "texel_size_m": lm.texel_size, "atlas_from": lm.atlas_from,
        "production": counts(Preset::Production), "preview": counts(Preset::Preview),
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
            "    {} {}, {}: at {} dir {} intensity {} {}",
            l["kind"].as_str().unwrap_or(""),
            l["name"],
            l["aperture"].as_str().unwrap_or(""),
            l["position"],
            l["direction"],
            l["intensity"],
            l["unit"].as_str().unwrap_or("")
        );
        if let Some(t) = l["geometry_inside"].as_f64() {
            println!(
                "      warning: geometry {t:.3} m from its centre, inside the sphere: the surfaces there get its \
                 surface brightness"
            );
        }
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
        "  texels      {} of {} covered ({:.1} %), {} dilated, {} gutter texels shared by charts, {} buried \
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
    let d = &summary["density"];
    for preset in ["production", "preview"] {
        let c = &d[preset];
        println!(
            "  {preset:<11} {} entries ({} per m^2), {} clusters, {} groups",
            c["entries"], c["entries_per_m2"], c["clusters"], c["groups"]
        );
    }
    println!(
        "  density     atlas {} from {} ({} m texels asked for)",
        lm.atlas, lm.atlas_from, lm.texel_size
    );
    for n in &r.notes {
        println!("  note        {n}");
    }
}
