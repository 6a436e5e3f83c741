//! `prm bake-reference`: the static reference lightmap with virtual polygon lights (paper 000).

use prm_precompute::parallel::Control;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use glam::Vec3;
use prm::exr_io::Channels;
use prm::{Bvh, TexelSet};
use prm_precompute::reference::bake::{evaluate, to_obj, virtual_lights_of_sources, BakeParams};
use prm_precompute::reference::vpl::emissive_sources;

use crate::common::{cancel_flag, progress_bar, AtlasArgs, RigArgs, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    rig: RigArgs,
    /// Output EXR: bare R G B = direct + indirect (indirect only with --indirect-only),
    /// layers direct.*, indirect.*, and mask.
    #[arg(short, long)]
    output: PathBuf,
    /// Photons (VPL paths) per light, and per glowing mesh (its polygon lights share them by flux).
    #[arg(long, default_value_t = 40_000)]
    vpls: usize,
    /// Bounces traced (the light left beyond the last is reported).
    #[arg(long, default_value_t = 12)]
    bounces: u32,
    /// VPLs per virtual light at the first bounce (doubling with each bounce).
    #[arg(long, default_value_t = 64)]
    cluster_size: usize,
    /// Shadow rays per texel and virtual light.
    #[arg(long, default_value_t = 2)]
    visibility_samples: u32,
    #[command(flatten)]
    lightmap: AtlasArgs,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Bake only the indirect light.
    #[arg(long)]
    indirect_only: bool,
    /// Also write the virtual lights as an OBJ file to look at.
    #[arg(long)]
    debug_lights: Option<PathBuf>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> Result<()> {
    let rig = a.rig.rig.as_deref().unwrap_or(&a.scene.scene);
    crate::common::check_output_file(&a.output, &[&a.scene.scene, rig])?;
    // Both outputs are checked before the bake: a bad --debug-lights path found after it
    // left the lightmap written and the command failed.
    if let Some(obj) = &a.debug_lights {
        crate::common::check_output_file(obj, &[&a.scene.scene, rig])?;
        if crate::common::same_file(obj, &a.output) {
            anyhow::bail!("--debug-lights {} is the output lightmap too", obj.display());
        }
    }
    let (mut scene, atlas) = a.lightmap.load(&a.scene, a.json)?;
    let p = BakeParams {
        photons: a.vpls,
        bounces: a.bounces,
        cluster_size: a.cluster_size,
        visibility_samples: a.visibility_samples,
        atlas,
        seed: a.seed,
        indirect_only: a.indirect_only,
        ..BakeParams::default()
    };
    p.validate().map_err(|e| anyhow!("bad parameter: {e}"))?;
    let start = Instant::now();
    scene.lights = a.rig.lights(&scene)?;
    // Emissive surfaces light the bake as polygon lights (the ground truth meets them itself),
    // each glowing mesh's lights one photon source.
    let glow = prm::emitters::emitters(&scene, |_| true);
    let sources = emissive_sources(&scene, scene.lights.len(), &glow);
    scene.lights.extend(glow.into_iter().map(|e| e.light));
    let bvh = Bvh::build_with_rooms(&scene);
    crate::common::warn_spheres_in_geometry(&scene, &bvh);
    let set = TexelSet::build_visible(&scene, &bvh, atlas.width(), atlas.height());
    let t = Instant::now();
    let vl = virtual_lights_of_sources(&scene, &bvh, &scene.lights, &sources, &p);
    let lights_s = t.elapsed().as_secs_f64();
    let bar = progress_bar(set.len() as u64, "texels");
    if a.json {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let t = Instant::now();
    let baked = {
        let on_texels = |d: usize| bar.set_position(d as u64);
        evaluate(
            &scene,
            &bvh,
            &set,
            &scene.lights,
            &vl,
            &p,
            Control { progress: &on_texels, cancel: cancel_flag() },
        )
    };
    bar.finish_and_clear();
    let baked = baked.map_err(|_| anyhow!("stopped by Ctrl-C; {} not written", a.output.display()))?;
    let eval_s = t.elapsed().as_secs_f64();
    let total: Vec<Vec3> = baked.direct.iter().zip(&baked.indirect).map(|(d, i)| *d + *i).collect();
    let mut ch = Channels::paged(set.width as usize, set.height as usize, atlas.pages as usize);
    ch.insert_rgb("", &set.to_image(if a.indirect_only { &baked.indirect } else { &total }, Vec3::ZERO));
    ch.insert_rgb("direct", &set.to_image(&baked.direct, Vec3::ZERO));
    ch.insert_rgb("indirect", &set.to_image(&baked.indirect, Vec3::ZERO));
    ch.insert("mask", set.mask().iter().map(|&m| m as u8 as f32).collect());
    ch.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    if let Some(obj) = &a.debug_lights {
        prm::fsutil::write_bytes_atomic(obj, to_obj(&vl).as_bytes())
            .with_context(|| format!("writing {}", obj.display()))?;
    }
    let emitted = vl.budgets.iter().fold(Vec3::ZERO, |s, b| s + b.emitted);
    let beyond = vl.budgets.iter().fold(Vec3::ZERO, |s, b| s + b.beyond_last_bounce);
    let summary = serde_json::json!({
        "scene": a.scene.scene.display().to_string(),
        "output": a.output.display().to_string(),
        "vpls": vl.vpl_count,
        "photon_sources": sources.len(),
        "polygon_lights": vl.polygons.len(),
        "sphere_lights": vl.spheres.len(),
        "vpl_power": vl.vpl_power.to_array(),
        "virtual_light_power": vl.light_power.to_array(),
        "emitted_power": emitted.to_array(),
        "power_beyond_last_bounce": beyond.to_array(),
        "seconds_virtual_lights": lights_s,
        "seconds_evaluation": eval_s,
        "seconds_total": start.elapsed().as_secs_f64(),
        "rays": baked.rays,
        "rays_per_second": baked.rays as f64 / eval_s.max(1e-9),
        "texels": set.len(),
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{} -> {}: {} VPLs -> {} polygon + {} sphere lights in {:.2} s, evaluated at {} texels in {:.2} \
                s ({:.2} Mrays/s)",
            a.scene.scene.display(),
            a.output.display(),
            vl.vpl_count,
            vl.polygons.len(),
            vl.spheres.len(),
            lights_s,
            set.len(),
            eval_s,
            baked.rays as f64 / eval_s.max(1e-9) / 1e6
        );
    }
    Ok(())
}
