//! `prm render --mode cssm`: frames of a level whose objects move, lit by hierarchical radiosity
//! over precomputed visibility (paper 003; `prm_runtime::cpu::radiosity`).
//!
//! Per frame: the rig's lights and object poses at the frame's time; the level posed (movables
//! moved); direct irradiance at every texel; the radiosity's indirect lightmap; the frame shaded
//! as in `--mode prm`. With `--backend gpu` (the default) the direct light comes from shadow
//! maps of the posed level (`--shadow-size`) and the radiosity runs on the GPU
//! (`prm_runtime::radiosity`; its readback is in the frame time); with `--backend cpu` both are
//! the CPU twin's (rays). The shading stays on the CPU here. `--ground-truth-spp N` also path-traces each frame's indirect lightmap
//! in the posed level and prints the error (noise removed in quadrature); `--baseline-prm`
//! adds the PRM's error on the same texels (its CPU twin, the level at rest: what a PRM alone
//! shows while objects move).

use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::Vec3;
use prm::density::Atlas;
use prm::Bvh;
use prm_precompute::ground_truth::GtParams;
use prm_runtime::cpu::radiosity::RadiosityParams;
use prm_runtime::radiosity::RadiosityPass;

use crate::moving::MovingLevel;
use crate::render::{camera, shade, Args, Backend, Output};

/// The radiosity's settings (`--mode cssm`).
#[derive(clap::Args, Clone, Debug)]
pub struct RadiosityArgs {
    /// (--mode cssm) Diffuse bounces before the rest is estimated.
    #[arg(long, default_value_t = RadiosityParams::default().bounces)]
    bounces: u32,
    /// (--mode cssm) Refinement threshold, relative to the level's mean exitance.
    #[arg(long, default_value_t = RadiosityParams::default().threshold)]
    threshold: f32,
    /// (--mode cssm) Also path-trace each frame's indirect lightmap with this many paths per
    /// texel and print the radiosity's error against it.
    #[arg(long)]
    ground_truth_spp: Option<u32>,
    /// (--mode cssm, with --ground-truth-spp) Also compose this .prm of the level at rest (the
    /// CPU twin, --top-k panes) each frame and print its error on the same texels: the
    /// baseline that cannot see objects move.
    #[arg(long)]
    baseline_prm: Option<std::path::PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    if a.prm.is_some() {
        bail!("--prm is for --mode prm; --mode cssm reads --vis (from `prm visibility`)");
    }
    let Some(vis_path) = a.vis.as_deref() else {
        bail!("--mode cssm needs the level's visibility: give --vis FILE (made by `prm visibility`)")
    };
    let r = &a.radiosity;
    if !(1..=64).contains(&r.bounces) {
        bail!("--bounces {} is out of range (1 to 64)", r.bounces);
    }
    if !(r.threshold.is_finite() && r.threshold >= 0.0) {
        bail!("--threshold {} must be a finite number >= 0", r.threshold);
    }
    if let Some(spp) = r.ground_truth_spp {
        GtParams { spp, ..GtParams::preview() }
            .validate()
            .map_err(|e| anyhow::anyhow!("bad parameter: {e}"))?;
    }
    let gpu = match a.backend {
        Backend::Cpu => None,
        Backend::Gpu => match prm_runtime::Gpu::new() {
            Ok(g) => Some(g),
            Err(e) => {
                eprintln!("note: {e}\nnote: rendering with the CPU twin instead");
                None
            }
        },
    };
    if r.baseline_prm.is_some() && r.ground_truth_spp.is_none() {
        bail!("--baseline-prm is compared with the ground truth: give --ground-truth-spp too");
    }
    let level = MovingLevel::load(&a.scene, vis_path, a.rig.as_deref())?;
    let w = level.vis.width;
    let (scene, texels) = (&level.scene, &level.texels);
    let mut pass = match gpu.as_ref() {
        Some(g) => {
            println!("device: {}", g.describe());
            Some(RadiosityPass::new(&g.device, scene, texels, &level.hierarchy, &level.vis)?)
        }
        None => None,
    };
    let cam = camera(scene, a.camera.as_deref())?;
    let (iw, ih) = cam.image_size(a.width);
    let folder = crate::common::OutputFolder::create(&a.output)?;
    let atlas = Atlas::single(w);
    let out = Output {
        dir: &a.output,
        lightmap: a.lightmap_out.then_some(atlas),
        size: (iw as usize, ih as usize),
    };
    let params = RadiosityParams { bounces: r.bounces, threshold: r.threshold, ..Default::default() };
    println!(
        "{} texels, {} movables ({}), {} hierarchy nodes",
        texels.len(),
        scene.movables.len(),
        scene.movables.iter().map(|m| m.name.as_str()).collect::<Vec<_>>().join(", "),
        level.hierarchy.nodes.len()
    );
    let baseline = match &r.baseline_prm {
        Some(p) => {
            let map = prm::prm_file::Prm::read(p, None).context("reading the baseline map failed")?;
            map.check_scene(p, scene)?;
            if map.header().atlas() != atlas {
                bail!(
                    "{}: baked for a {} atlas, the visibility for {atlas}",
                    p.display(),
                    map.header().atlas()
                );
            }
            Some(map)
        }
        None => None,
    };
    let rest_bvh = Bvh::build(scene);
    let compose = a.compose.runtime(a.shadow_size)?;
    let mut twin = baseline.as_ref().map(|m| {
        let mut t = prm_runtime::cpu::CpuTwin::new(m, &rest_bvh, compose.top_k);
        t.set_residual(compose.residual);
        t.set_budget(compose.budget);
        t
    });
    let mut sums = [0.0f64; 3];
    let mut errors = Vec::new();
    let mut baseline_errors = Vec::new();
    for f in 0..a.frames {
        let time = level.rig.frame_time(f, a.frames);
        let gpu_pass = gpu.as_ref().zip(pass.as_mut()).map(|(g, p)| crate::moving::GpuFrame {
            gpu: g,
            pass: p,
            shadow_size: a.shadow_size,
        });
        let e = level.frame(time, &params, gpu_pass, r.ground_truth_spp, 0, twin.as_mut())?;
        let lightmap = texels.to_image(&e.indirect, Vec3::ZERO);
        let t = Instant::now();
        let img = shade(&e.posed, &e.bvh, &cam, &e.lights, &lightmap, atlas, out.size);
        let shade_s = t.elapsed().as_secs_f64();
        out.write(f, &img, Some(&lightmap[..]).filter(|_| a.lightmap_out))?;
        let cut = e.transfers.map_or(String::new(), |n| {
            format!(" ({:.0} transfers a texel)", n as f64 / texels.len().max(1) as f64)
        });
        let mut line = format!(
            "frame {f:4} (t = {time:5.2} s): direct {:7.1} ms, radiosity {:7.1} ms{cut}, shading {:7.1} ms",
            e.direct_s * 1e3,
            e.radiosity_s * 1e3,
            shade_s * 1e3
        );
        if let Some((err, bias, noise)) = e.error {
            errors.push(err);
            line += &format!(
                ", indirect error {:.1} % (bias {:+.1} %, ground-truth noise {:.1} % removed)",
                err * 100.0,
                bias * 100.0,
                noise * 100.0
            );
        }
        if let Some((err, bias)) = e.prm_error {
            baseline_errors.push(err);
            line += &format!("; PRM {:.1} % (bias {:+.1} %)", err * 100.0, bias * 100.0);
        }
        println!("{line}");
        sums[0] += e.direct_s;
        sums[1] += e.radiosity_s;
        sums[2] += shade_s;
    }
    let n = a.frames as f64;
    println!(
        "{} frames: mean direct {:.1} ms, radiosity {:.1} ms ({}), shading {:.1} ms (CPU){} -> {}",
        a.frames,
        sums[0] * 1e3 / n,
        sums[1] * 1e3 / n,
        gpu.as_ref().map_or(format!("CPU, {} threads", rayon::current_num_threads()), |g| format!(
            "{}, direct from {}² shadow maps",
            g.info.name, a.shadow_size
        )),
        sums[2] * 1e3 / n,
        if errors.is_empty() {
            String::new()
        } else {
            format!(
                "; indirect error mean {:.1} %, worst {:.1} %",
                errors.iter().sum::<f64>() / errors.len() as f64 * 100.0,
                errors.iter().cloned().fold(0.0, f64::max) * 100.0
            )
        },
        a.output.display()
    );
    if !baseline_errors.is_empty() {
        println!(
            "baseline PRM (objects at rest): indirect error mean {:.1} %, worst {:.1} %",
            baseline_errors.iter().sum::<f64>() / baseline_errors.len() as f64 * 100.0,
            baseline_errors.iter().cloned().fold(0.0, f64::max) * 100.0
        );
    }
    folder.keep();
    Ok(())
}
