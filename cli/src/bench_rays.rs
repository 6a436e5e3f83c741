//! `prm bench-rays`: closest-hit and occlusion throughput on a level, in rays per second.
//!
//! The rays are the ones the bakers trace: closest-hit rays leave surface points in
//! cosine-distributed directions; occlusion rays join two random surface points. Points are
//! uniform over the surfaces' area (as texels are), so no lightmap UVs are needed.

use std::time::Instant;

use anyhow::{bail, Result};
use glam::Vec3;
use prm::Bvh;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde_json::json;

use crate::common::{load_for_rays, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// Rays per measurement.
    #[arg(long, default_value_t = 1_000_000)]
    rays: usize,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> Result<()> {
    if a.rays == 0 || a.rays > 1_000_000_000 {
        bail!("--rays {} is out of range (1 to 1e9)", a.rays);
    }
    // The rays need points on the surfaces, not lightmap texels: the level's lightmap UVs are
    // neither generated nor checked (a level that needs several pages is measured as it is).
    let scene = load_for_rays(&a.scene, a.json)?;
    let start = Instant::now();
    let bvh = Bvh::build(&scene);
    let build = start.elapsed().as_secs_f64();
    // The same level with its rooms' own trees (what the precompute traces).
    let start = Instant::now();
    let local = Bvh::build(&scene);
    local.localise(&scene, &prm::rooms::Rooms::of_scene(&scene));
    let local_build = start.elapsed().as_secs_f64();
    // Start points stratified by area, as the precompute samples its entries; each ray's other
    // point is a start point picked at random.
    let points = prm_precompute::entries::sample_entries(&scene, a.rays, 7);
    if points.is_empty() {
        bail!("the level has no surface to start rays from");
    }
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    // Each ray: start point and normal, a cosine direction, and another point and its normal.
    let rays: Vec<(Vec3, Vec3, Vec3, Vec3, Vec3)> = points
        .iter()
        .map(|p| {
            let q = &points[rng.random_range(0..points.len())];
            let d = prm::sampling::cosine_direction(p.normal, rng.random(), rng.random());
            (p.position, p.normal, d, q.position, q.normal)
        })
        .collect();

    let time = |f: &dyn Fn() -> usize| {
        let s = Instant::now();
        let hits = f();
        (a.rays as f64 / s.elapsed().as_secs_f64(), hits)
    };
    let measure = |bvh: &Bvh| {
        let (closest_1, hits) =
            time(&|| rays.iter().filter(|r| bvh.trace_from_surface(r.0, r.1, r.2).is_some()).count());
        let (closest_n, _) =
            time(&|| rays.par_iter().filter(|r| bvh.trace_from_surface(r.0, r.1, r.2).is_some()).count());
        let (occl_1, visible) = time(&|| rays.iter().filter(|r| bvh.visible(r.0, r.1, r.3, r.4)).count());
        let (occl_n, _) = time(&|| rays.par_iter().filter(|r| bvh.visible(r.0, r.1, r.3, r.4)).count());
        (closest_1, closest_n, hits, occl_1, occl_n, visible)
    };
    let (closest_1, closest_n, hits, occl_1, occl_n, visible) = measure(&bvh);
    let (local_closest_1, local_closest_n, _, local_occl_1, local_occl_n, _) = measure(&local);

    // Rays whose closest hit the two name differently (an edge grazed within round-off).
    let differ = rays
        .par_iter()
        .filter(|r| bvh.trace_from_surface(r.0, r.1, r.2) != local.trace_from_surface(r.0, r.1, r.2))
        .count();
    let threads = rayon::current_num_threads();
    let out = json!({
        "scene": a.scene.scene.display().to_string(),
        "triangles": scene.triangles.len(),
        "bvh_build_seconds": build,
        "rays": a.rays,
        "threads": threads,
        "closest_hit_rays_per_s_1_thread": closest_1,
        "closest_hit_rays_per_s": closest_n,
        "closest_hit_fraction_hit": hits as f64 / a.rays as f64,
        "occlusion_rays_per_s_1_thread": occl_1,
        "occlusion_rays_per_s": occl_n,
        "occlusion_fraction_visible": visible as f64 / a.rays as f64,
        "rooms_trees": local.local_regions(),
        "rooms_build_seconds": local_build,
        "rooms_closest_hit_rays_per_s_1_thread": local_closest_1,
        "rooms_closest_hit_rays_per_s": local_closest_n,
        "rooms_occlusion_rays_per_s_1_thread": local_occl_1,
        "rooms_occlusion_rays_per_s": local_occl_n,
        "rooms_closest_hits_differing": differ,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "{}: {} triangles, BVH built in {:.4} s",
            a.scene.scene.display(),
            scene.triangles.len(),
            build
        );
        println!(
            "  closest hit  {:>8.2} Mrays/s on 1 thread, {:>8.2} Mrays/s on {threads} ({:.1} % hit)",
            closest_1 / 1e6,
            closest_n / 1e6,
            100.0 * hits as f64 / a.rays as f64
        );
        println!(
            "  occlusion    {:>8.2} Mrays/s on 1 thread, {:>8.2} Mrays/s on {threads} ({:.1} % visible)",
            occl_1 / 1e6,
            occl_n / 1e6,
            100.0 * visible as f64 / a.rays as f64
        );
        println!(
            "  with {} rooms' own trees (built with the rooms in {:.4} s): closest hit {:.2} / {:.2} Mrays/s, occlusion {:.2} / {:.2} Mrays/s (1 / {threads} threads); {differ} closest hits named differently",
            local.local_regions(),
            local_build,
            local_closest_1 / 1e6,
            local_closest_n / 1e6,
            local_occl_1 / 1e6,
            local_occl_n / 1e6
        );
    }
    Ok(())
}
