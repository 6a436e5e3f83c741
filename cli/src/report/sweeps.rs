//! The report's budget sweeps: the PRM's precompute budget, its runtime budget (top-K, with and
//! without groups) and the reference baker's budget, each point an error against a time.

use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{anyhow, Result};
use glam::Vec3;
use prm::prm_file::Prm;
use prm_precompute::precompute::{precompute, PrecomputeParams};
use prm_runtime::cpu::CpuTwin;
use prm_runtime::{Budget as RtBudget, Gpu, Renderer, Runtime, RuntimeParams};

use super::measure::{compare, compare_texels, reference, Level};
use super::Budget;
use crate::render::camera;

/// A lightmap's error against the ground truth, and the time it took.
pub struct Point {
    pub label: String,
    pub seconds: f64,
    pub error: f64,
    pub bias: f64,
}

/// Error and time per precompute budget (all panes, exact weights), and the map of the
/// production budget.
pub fn precompute_sweep(b: &Budget, level: &Level, gt: &[Vec3], seed: u64) -> Result<(Vec<Point>, Prm)> {
    let cancel = AtomicBool::new(false);
    let mut points = Vec::new();
    let mut production: Option<Prm> = None;
    for (k, &(entries, paths, clusters)) in b.prm.iter().enumerate() {
        eprintln!("precompute {entries} entries, {paths} paths, {clusters} clusters...");
        let p = PrecomputeParams {
            entries,
            paths,
            clusters,
            atlas: prm::density::Atlas::single(b.atlas),
            seed,
            ..PrecomputeParams::production()
        };
        let t = Instant::now();
        let (map, _) = precompute(&level.scene, &level.bvh, &p, &|_, _, _| {}, &cancel)
            .map_err(|e| anyhow!("precompute: {e}"))?;
        let seconds = t.elapsed().as_secs_f64();
        let mut twin = CpuTwin::new(&map, &level.bvh, usize::MAX);
        let img = twin.frame(&level.scene.lights).to_vec();
        let c = compare(&level.set, &img, gt);
        points.push(Point {
            label: format!("N={entries} M={paths} C={clusters}"),
            seconds,
            error: c.0,
            bias: c.1,
        });
        if k == b.production {
            production = Some(map);
        }
    }
    let map = production.ok_or_else(|| anyhow!("no production configuration"))?;
    Ok((points, map))
}

/// Error and time per reference bake budget.
pub fn reference_sweep(b: &Budget, level: &Level, gt: &[Vec3], seed: u64) -> Result<Vec<Point>> {
    let mut points = Vec::new();
    for &(photons, cluster) in &b.reference {
        eprintln!("reference {photons} photons, {cluster} VPLs per light...");
        let t = Instant::now();
        let ind = reference(level, &level.scene.lights, (photons, cluster), b.atlas, seed)?;
        let seconds = t.elapsed().as_secs_f64();
        let c = compare_texels(&ind, gt);
        points.push(Point {
            label: format!("{photons} photons, {cluster}/light"),
            seconds,
            error: c.0,
            bias: c.1,
        });
    }
    Ok(points)
}

/// The runtime budget: error and frame time per top-K, K picked locally with the groups for
/// each tile's others (the runtime's default), K over the whole map with the groups, and K
/// over the map alone.
pub struct RuntimeSweep {
    pub tile: Vec<Point>,
    pub with: Vec<Point>,
    pub without: Vec<Point>,
    /// Median direct-only frame time; NaN without a GPU (the times are then the CPU twin's).
    pub direct_ms: f64,
}

/// Error and frame time per top-K (local, over the map with groups, over the map alone), and
/// the direct-only frame time.
pub fn runtime_sweep(
    b: &Budget,
    level: &Level,
    map: &Prm,
    gt: &[Vec3],
    gpu: Option<&Gpu>,
) -> Result<RuntimeSweep> {
    match gpu {
        Some(g) => gpu_runtime_sweep(b, level, map, gt, g),
        None => Ok(cpu_runtime_sweep(b, level, map, gt)),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn k_label(map: &Prm, k: usize) -> String {
    if k >= map.clusters().len() {
        "all".to_string()
    } else {
        k.to_string()
    }
}

/// The sweep on the CPU twin: the time is one lightmap's (ray-traced entry visibility, weights,
/// selection, compose).
fn cpu_runtime_sweep(b: &Budget, level: &Level, map: &Prm, gt: &[Vec3]) -> RuntimeSweep {
    let (mut tile, mut with, mut without) = (Vec::new(), Vec::new(), Vec::new());
    for &k in &b.top_k {
        for (budget, residual, out) in [
            (RtBudget::Local, true, &mut tile),
            (RtBudget::Global, true, &mut with),
            (RtBudget::Global, false, &mut without),
        ] {
            let mut twin = CpuTwin::new(map, &level.bvh, k);
            twin.set_residual(residual);
            twin.set_budget(budget);
            let t = Instant::now();
            let img = twin.frame(&level.scene.lights).to_vec();
            let c = compare(&level.set, &img, gt);
            out.push(Point {
                label: k_label(map, k),
                seconds: t.elapsed().as_secs_f64(),
                error: c.0,
                bias: c.1,
            });
        }
    }
    RuntimeSweep { tile, with, without, direct_ms: f64::NAN }
}

/// The sweep on the GPU: median full-frame times, each frame recomposing.
fn gpu_runtime_sweep(b: &Budget, level: &Level, map: &Prm, gt: &[Vec3], g: &Gpu) -> Result<RuntimeSweep> {
    let scene = &level.scene;
    let mut rt = Runtime::new(
        &g.device,
        &g.queue,
        scene,
        map,
        RuntimeParams { top_k: 32, shadow_size: 1024, residual: true, ..Default::default() },
    )?;
    let renderer = frame_renderer(g, level, &rt, b.frame_width)?;
    let direct = direct_frames(level, &mut rt, &renderer, b.frame_reps)?;
    let (mut tile, mut with, mut without) = (Vec::new(), Vec::new(), Vec::new());
    for &k in &b.top_k {
        for (budget, residual, out) in [
            (RtBudget::Local, true, &mut tile),
            (RtBudget::Global, true, &mut with),
            (RtBudget::Global, false, &mut without),
        ] {
            rt.set_residual(residual);
            rt.set_budget(budget);
            let mut times = Vec::new();
            for _ in 0..b.frame_reps {
                // Changing K marks the lightmap stale: every repetition recomposes (the shadow
                // maps stay, the lights did not move).
                rt.set_top_k(k)?;
                let t = Instant::now();
                rt.update(&scene.lights)?;
                renderer.draw(&rt, true, None);
                renderer.wait();
                times.push(t.elapsed().as_secs_f64() * 1e3);
            }
            let c = compare(&level.set, &rt.read_lightmap()?, gt);
            out.push(Point { label: k_label(map, k), seconds: median(times) / 1e3, error: c.0, bias: c.1 });
        }
    }
    Ok(RuntimeSweep { tile, with, without, direct_ms: median(direct) })
}

/// A renderer of the level's first camera (or a framing one) at `width`.
fn frame_renderer(g: &Gpu, level: &Level, rt: &Runtime, width: u32) -> Result<Renderer> {
    let cam = camera(&level.scene, None)?;
    let (w, h) = cam.image_size(width);
    Ok(Renderer::new(&g.device, &g.queue, &level.scene, rt, &cam, w, h)?)
}

/// Wall-clock times (ms) of `reps` direct-only frames: shadow maps and direct light, no compose.
fn direct_frames(level: &Level, rt: &mut Runtime, renderer: &Renderer, reps: usize) -> Result<Vec<f64>> {
    let mut direct = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        rt.update_direct(&level.scene.lights)?;
        renderer.draw(rt, false, None);
        renderer.wait();
        direct.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(direct)
}

/// Median wall-clock times (ms) of a direct-only frame and of a full frame that recomposes
/// the top `k` (forced each time: the level's lights do not move), `reps` of each.
pub fn frame_ms(
    g: &Gpu,
    level: &Level,
    rt: &mut Runtime,
    k: usize,
    width: u32,
    reps: usize,
) -> Result<(f64, f64)> {
    let renderer = frame_renderer(g, level, rt, width)?;
    let direct = direct_frames(level, rt, &renderer, reps)?;
    let mut full = Vec::new();
    for _ in 0..reps {
        // Setting K marks the lightmap stale, so the update recomposes.
        rt.set_top_k(k)?;
        let t = Instant::now();
        rt.update(&level.scene.lights)?;
        renderer.draw(rt, true, None);
        renderer.wait();
        full.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok((median(direct), median(full)))
}
