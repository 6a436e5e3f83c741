//! `prm bench --mode cssm`: what the moving-objects radiosity costs per frame, measured side by
//! side in one run: the GPU pass (where an adapter exists) and the CPU twin over the rig's
//! frames, alternated in `--rounds` blocks, median and p95, with the direct light at the texels
//! (ray-traced on the CPU: the shadow maps do not light texels yet) for scale.

use anyhow::{bail, Result};
use prm_runtime::cpu::radiosity::RadiosityParams;
use prm_runtime::radiosity::RadiosityPass;
use prm_runtime::Gpu;
use serde::Serialize;

use crate::bench::{stats, Args, Stats};
use crate::moving::MovingLevel;

#[derive(Serialize)]
struct Report {
    device: String,
    scene: String,
    texels: usize,
    hierarchy_nodes: usize,
    visibility_bytes: usize,
    frames_per_block: usize,
    rounds: usize,
    direct_cpu: Stats,
    radiosity_cpu: Stats,
    radiosity_gpu: Option<Stats>,
    cpu_threads: usize,
}

pub fn run(a: &Args) -> Result<()> {
    let Some(vis_path) = a.vis.as_deref() else {
        bail!("--mode cssm needs the level's visibility: give --vis FILE (made by `prm visibility`)")
    };
    if a.prm.is_some() {
        bail!("--prm is for --mode prm");
    }
    let level = MovingLevel::load(&a.scene, vis_path, a.rig.as_deref())?;
    let gpu = match Gpu::new() {
        Ok(g) => Some(g),
        Err(e) => {
            eprintln!("note: {e}\nnote: the CPU twin only");
            None
        }
    };
    let mut pass = match gpu.as_ref() {
        Some(g) => {
            Some(RadiosityPass::new(&g.device, &level.scene, &level.texels, &level.hierarchy, &level.vis)?)
        }
        None => None,
    };
    let params = RadiosityParams::default();
    let (mut direct, mut cpu, mut on_gpu) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..a.rounds {
        for f in 0..a.frames {
            let time = level.rig.frame_time(f, a.frames);
            let e = level.frame(time, &params, None, None, 0, None)?;
            direct.push(e.direct_s * 1e3);
            cpu.push(e.radiosity_s * 1e3);
        }
        if let (Some(g), Some(p)) = (gpu.as_ref(), pass.as_mut()) {
            for f in 0..a.frames {
                let time = level.rig.frame_time(f, a.frames);
                let e = level.frame(time, &params, Some((g, &mut *p)), None, 0, None)?;
                on_gpu.push(e.radiosity_s * 1e3);
            }
        }
    }
    let report = Report {
        device: gpu.as_ref().map_or("none".into(), |g| g.describe()),
        scene: a.scene.scene.display().to_string(),
        texels: level.texels.len(),
        hierarchy_nodes: level.hierarchy.nodes.len(),
        visibility_bytes: level.vis.bytes(),
        frames_per_block: a.frames,
        rounds: a.rounds,
        direct_cpu: stats(direct),
        radiosity_cpu: stats(cpu),
        radiosity_gpu: (!on_gpu.is_empty()).then(|| stats(on_gpu)),
        cpu_threads: rayon::current_num_threads(),
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("device: {}", report.device);
    println!(
        "{}: {} texels, {} hierarchy nodes, visibility {:.1} MB; {} rounds of {} frames",
        report.scene,
        report.texels,
        report.hierarchy_nodes,
        report.visibility_bytes as f64 / 1e6,
        report.rounds,
        report.frames_per_block
    );
    let line = |what: &str, s: &Stats| {
        println!(
            "{what:<34} median {:9.1} ms, p95 {:9.1} ms, mean {:9.1} ms",
            s.median_ms, s.p95_ms, s.mean_ms
        )
    };
    line("direct light at the texels (CPU)", &report.direct_cpu);
    line(&format!("radiosity, CPU twin ({} threads)", report.cpu_threads), &report.radiosity_cpu);
    if let Some(g) = &report.radiosity_gpu {
        line("radiosity, GPU (with its readback)", g);
        println!("GPU / CPU: {:.2}", g.median_ms / report.radiosity_cpu.median_ms.max(1e-9));
    }
    Ok(())
}
