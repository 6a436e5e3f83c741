//! `prm ground-truth`: the independent path tracer's irradiance per texel, or a camera image.

use prm_precompute::parallel::Control;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;
use prm::exr_io::Channels;
use prm::{luminance, Bvh, TexelSet};
use prm_precompute::ground_truth::{GtParams, Tracer};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde_json::json;

use crate::common::{cancel_flag, progress_bar, AtlasArgs, RigArgs, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    rig: RigArgs,
    /// Paths per texel (per pixel with --camera).
    #[arg(long, default_value_t = 256)]
    spp: u32,
    #[command(flatten)]
    lightmap: AtlasArgs,
    /// Hard cap on path length (paths cut there are reported).
    #[arg(long, default_value_t = 1000)]
    max_bounces: u32,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Gather only: no light paths for the first bounce of point and spot lights and suns
    /// (slower to converge near lights and under a sun through a window; kept to cross-check
    /// the two estimators).
    #[arg(long)]
    no_light_paths: bool,
    /// Render this glTF camera's view (linear radiance) instead of the lightmap.
    #[arg(long)]
    camera: Option<String>,
    /// Image width with --camera.
    #[arg(long, default_value_t = 512)]
    width: u32,
    /// Output EXR.
    #[arg(short, long)]
    output: PathBuf,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> Result<()> {
    crate::common::check_output_file(
        &a.output,
        &[&a.scene.scene, a.rig.rig.as_deref().unwrap_or(&a.scene.scene)],
    )?;
    let params = GtParams {
        spp: a.spp,
        max_bounces: a.max_bounces,
        seed: a.seed,
        light_paths: !a.no_light_paths,
        ..GtParams::default()
    };
    params.validate().map_err(|e| anyhow!("bad parameter: {e}"))?;
    let (mut scene, atlas) = a.lightmap.load(&a.scene, a.json)?;
    scene.lights = a.rig.lights(&scene)?;
    let bvh = Bvh::build_with_rooms(&scene);
    let tracer = Tracer::new(&scene, &bvh, params);
    let cancel = cancel_flag();
    let start = Instant::now();
    let summary = match &a.camera {
        Some(name) => camera_image(&a, &tracer, name, cancel)?,
        None => lightmap(&a, atlas, &tracer, cancel)?,
    };
    let seconds = start.elapsed().as_secs_f64();
    let st = &tracer.stats;
    let mut out = json!({
        "scene": a.scene.scene.display().to_string(),
        "output": a.output.display().to_string(),
        "spp": a.spp,
        "seed": a.seed,
        "light_paths": !a.no_light_paths,
        "seconds": seconds,
        "paths": st.paths.load(Ordering::Relaxed),
        "rays": st.rays.load(Ordering::Relaxed),
        "rays_per_second": st.rays.load(Ordering::Relaxed) as f64 / seconds,
        "paths_truncated_at_max_bounces": st.truncated.load(Ordering::Relaxed),
        "threads": rayon::current_num_threads(),
    });
    if let (Some(o), Some(s)) = (out.as_object_mut(), summary.as_object()) {
        o.extend(s.clone());
    }
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

fn lightmap(
    a: &Args,
    atlas: prm::density::Atlas,
    tracer: &Tracer,
    cancel: &std::sync::atomic::AtomicBool,
) -> Result<serde_json::Value> {
    let set = TexelSet::build_visible(tracer.scene, tracer.bvh, atlas.width(), atlas.height());
    if set.is_empty() {
        bail!("the level has no lightmap texels in {atlas}");
    }
    let bar = progress_bar(set.len() as u64, "texels");
    if a.json {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let on_texels = |done: usize| bar.set_position(done as u64);
    let result = tracer.texels(&set.texels, set.width, Control { progress: &on_texels, cancel });
    bar.finish_and_clear();
    let values = result.map_err(|_| anyhow!("stopped by Ctrl-C; {} not written", a.output.display()))?;
    let (w, h) = (set.width as usize, set.height as usize);
    let mut ch = Channels::paged(w, h, atlas.pages as usize);
    let layer = |f: &dyn Fn(&prm_precompute::ground_truth::Irradiance) -> Vec3| {
        let v: Vec<Vec3> = values.iter().map(f).collect();
        set.to_image(&v, Vec3::ZERO)
    };
    // Bare R G B is the lightmap's main quantity (DESIGN.md §8): here the indirect light,
    // also stored as `indirect.*` so tools can name the layer.
    let indirect = layer(&|r| r.indirect);
    ch.insert_rgb("", &indirect);
    ch.insert_rgb("indirect", &indirect);
    ch.insert_rgb("direct", &layer(&|r| r.direct));
    ch.insert_rgb("stderr", &layer(&|r| r.indirect_stderr));
    ch.insert_rgb("stderr_direct", &layer(&|r| r.direct_stderr));
    ch.insert("mask", set.mask().iter().map(|&m| m as u8 as f32).collect());
    ch.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;

    // Noise figures of the indirect layer: normalised like the error metric, and the mean of
    // per-texel relative standard errors.
    let (mut rel_sum, mut rel_n) = (0.0f64, 0usize);
    let mut mean = Vec3::ZERO;
    for v in &values {
        let (y, s) = (luminance(v.indirect) as f64, luminance(v.indirect_stderr) as f64);
        if y > 0.0 {
            rel_sum += s / y;
            rel_n += 1;
        }
        mean += v.indirect / values.len() as f32;
    }
    Ok(json!({
        "atlas": atlas.side,
        "pages": atlas.pages,
        "texels": set.len(),
        "mean_indirect": mean.to_array(),
        "indirect_noise_normalised": prm_precompute::ground_truth::indirect_noise(&values),
        "indirect_mean_relative_stderr": rel_sum / rel_n.max(1) as f64,
    }))
}

fn camera_image(
    a: &Args,
    tracer: &Tracer,
    name: &str,
    cancel: &std::sync::atomic::AtomicBool,
) -> Result<serde_json::Value> {
    let scene = tracer.scene;
    let cam = scene.cameras.iter().find(|c| c.name == name).ok_or_else(|| {
        anyhow!(
            "no camera named '{name}' (the level has: {})",
            scene.cameras.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")
        )
    })?;
    if a.width == 0 || a.width > 16384 {
        bail!("--width {} is out of range (1 to 16384)", a.width);
    }
    let (w, h) = cam.image_size(a.width);
    let (w, h) = (w as usize, h as usize);
    let bar = progress_bar(h as u64, "rows");
    if a.json {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let rows: Vec<Option<Vec<Vec3>>> = (0..h)
        .into_par_iter()
        .map(|j| {
            if cancel.load(Ordering::Relaxed) {
                return None;
            }
            let row = (0..w)
                .map(|i| {
                    let mut rng = Pcg64Mcg::seed_from_u64(
                        a.seed ^ ((j * w + i) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                    );
                    let mut sum = Vec3::ZERO;
                    for _ in 0..a.spp {
                        let (origin, d) = cam.ray(
                            i as f32 + rng.random::<f32>(),
                            j as f32 + rng.random::<f32>(),
                            w as u32,
                            h as u32,
                        );
                        sum += tracer.radiance(origin, d, &mut rng);
                    }
                    sum / a.spp as f32
                })
                .collect();
            bar.inc(1);
            Some(row)
        })
        .collect();
    bar.finish_and_clear();
    let mut pixels = Vec::with_capacity(w * h);
    for r in rows {
        pixels.extend(r.ok_or_else(|| anyhow!("stopped by Ctrl-C; {} not written", a.output.display()))?);
    }
    let mut ch = Channels::new(w, h);
    ch.insert_rgb("", &pixels);
    ch.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    Ok(json!({"camera": name, "width": w, "height": h}))
}
