//! `prm bench --mode cssm`: what the moving-objects radiosity costs per frame, measured side by
//! side in one run: the GPU pass (where an adapter exists) and the CPU twin over the rig's
//! frames, alternated in `--rounds` blocks, median and p95: the direct light at the texels
//! (on the GPU from `--shadow-size` shadow maps of the posed level, waited for; on the CPU by
//! rays) and the radiosity from it, and the two together.

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
    shadow_size: u32,
    direct_cpu: Stats,
    radiosity_cpu: Stats,
    frame_cpu: Stats,
    direct_gpu: Option<Stats>,
    radiosity_gpu: Option<Stats>,
    frame_gpu: Option<Stats>,
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
    // Milliseconds per frame: [direct, radiosity, both], CPU then GPU.
    let mut ms: [Vec<f64>; 6] = Default::default();
    let mut push = |at: usize, e: &crate::moving::FrameEval| {
        ms[at].push(e.direct_s * 1e3);
        ms[at + 1].push(e.radiosity_s * 1e3);
        ms[at + 2].push((e.direct_s + e.radiosity_s) * 1e3);
    };
    for _ in 0..a.rounds {
        for f in 0..a.frames {
            let time = level.rig.frame_time(f, a.frames);
            push(0, &level.frame(time, &params, None, None, 0, None)?);
        }
        if let (Some(g), Some(p)) = (gpu.as_ref(), pass.as_mut()) {
            for f in 0..a.frames {
                let time = level.rig.frame_time(f, a.frames);
                let on = crate::moving::GpuFrame { gpu: g, pass: &mut *p, shadow_size: a.shadow_size };
                push(3, &level.frame(time, &params, Some(on), None, 0, None)?);
            }
        }
    }
    let [direct, cpu, frame_cpu, direct_gpu, on_gpu, frame_gpu] = ms;
    let some = |v: Vec<f64>| (!v.is_empty()).then(|| stats(v));
    let report = Report {
        device: gpu.as_ref().map_or("none".into(), |g| g.describe()),
        scene: a.scene.scene.display().to_string(),
        texels: level.texels.len(),
        hierarchy_nodes: level.hierarchy.nodes.len(),
        visibility_bytes: level.vis.bytes(),
        frames_per_block: a.frames,
        rounds: a.rounds,
        shadow_size: a.shadow_size,
        direct_cpu: stats(direct),
        radiosity_cpu: stats(cpu),
        frame_cpu: stats(frame_cpu),
        direct_gpu: some(direct_gpu),
        radiosity_gpu: some(on_gpu),
        frame_gpu: some(frame_gpu),
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
            "{what:<46} median {:9.1} ms, p95 {:9.1} ms, mean {:9.1} ms",
            s.median_ms, s.p95_ms, s.mean_ms
        )
    };
    let threads = report.cpu_threads;
    line(&format!("direct light at the texels, CPU rays ({threads} threads)"), &report.direct_cpu);
    line(&format!("radiosity, CPU twin ({threads} threads)"), &report.radiosity_cpu);
    line("both, CPU", &report.frame_cpu);
    if let (Some(d), Some(r), Some(f)) = (&report.direct_gpu, &report.radiosity_gpu, &report.frame_gpu) {
        line(&format!("direct light, GPU ({}² shadow maps)", report.shadow_size), d);
        line("radiosity, GPU (with its readback)", r);
        line("both, GPU", f);
        println!("GPU / CPU (both): {:.3}", f.median_ms / report.frame_cpu.median_ms.max(1e-9));
    }
    Ok(())
}
