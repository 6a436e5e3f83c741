//! `prm bench`: what indirect light costs at run time, measured side by side in one run on one
//! device (DESIGN.md §9: a frame with indirect light <= 1.10 x a direct-only frame).
//!
//! - Frame times: blocks of `--frames` frames over the rig, alternating direct-only (shadow
//!   maps + shading) and full (shadow maps + entry irradiance + weights + selection + compose,
//!   then shading), `--rounds` of each; every frame waits for the GPU, wall-clock. Median, p95
//!   and the ratio of medians. With lights that do not move the runtime would compose once
//!   and never again (that is the design), which measures nothing: then every full frame is
//!   made to recompose (`Runtime::invalidate`), and the bench says so and how many composes
//!   it did.
//! - Per-pass GPU times from timestamp queries, where the adapter has them.
//! - Compose: bytes moved per compose (see `ComposePass::bytes`) and the time, against the
//!   device's copy bandwidth measured in the same run (a 256 MiB buffer-to-buffer copy, 8x).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use prm::prm_file::Prm;
use prm::rig::Rig;
use prm::Light;
use prm_runtime::PassTimer;
use prm_runtime::{Gpu, Renderer, Runtime, RuntimeParams};
use serde::Serialize;

use crate::common::{load_rig, ComposeArgs, MapArgs};
use crate::render::camera;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub(crate) scene: crate::common::SceneArgs,
    /// The level's .prm (--mode prm).
    #[arg(long)]
    pub(crate) prm: Option<PathBuf>,
    /// What to measure: the PRM runtime's frames, or (cssm) the moving-objects radiosity over
    /// the visibility file --vis.
    #[arg(long, value_enum, default_value = "prm")]
    pub(crate) mode: crate::render::Mode,
    /// The level's visibility file (--mode cssm).
    #[arg(long)]
    pub(crate) vis: Option<PathBuf>,
    /// Light rig (JSON); without one the level's glTF lights (which do not move).
    #[arg(long)]
    pub(crate) rig: Option<PathBuf>,
    /// Frames per block.
    #[arg(long, default_value_t = 60)]
    pub(crate) frames: usize,
    /// Blocks of each kind (direct-only, full), alternated.
    #[arg(long, default_value_t = 3)]
    pub(crate) rounds: usize,
    /// Frame width in pixels.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    #[command(flatten)]
    compose: ComposeArgs,
    /// Shadow-map texels per side and layer.
    #[arg(long, default_value_t = 1024)]
    pub(crate) shadow_size: u32,
    /// Print the figures as JSON.
    #[arg(long)]
    pub(crate) json: bool,
}

#[derive(Serialize, Default)]
pub(crate) struct Stats {
    pub(crate) median_ms: f64,
    pub(crate) p95_ms: f64,
    pub(crate) mean_ms: f64,
}

pub(crate) fn stats(mut v: Vec<f64>) -> Stats {
    if v.is_empty() {
        return Stats::default();
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    Stats { median_ms: at(0.5), p95_ms: at(0.95), mean_ms: v.iter().sum::<f64>() / v.len() as f64 }
}

#[derive(Serialize)]
struct Report {
    device: String,
    scene: String,
    width: u32,
    height: u32,
    top_k: usize,
    shadow_size: u32,
    lights: usize,
    clusters: usize,
    frames_per_block: usize,
    rounds: usize,
    direct_frame: Stats,
    full_frame: Stats,
    ratio_median: f64,
    composes: u64,
    /// The lights do not move, so every full frame was made to recompose.
    composes_forced: bool,
    gpu_pass_ms: Option<PassTimes>,
    compose_ms_gpu: Option<f64>,
    compose_ms_wall: f64,
    compose_bytes: u64,
    compose_bytes_detail: ComposeBytesJson,
    copy_bandwidth_gb_s: f64,
    compose_at_bandwidth_ms: f64,
    /// Whether the entry pass skipped lights their shadow maps hide from a whole cell.
    light_culling: bool,
    /// The last update's (entry, light) pairs, and those not probed (the light hidden).
    entry_light_pairs: u64,
    hidden_light_pairs: u64,
    /// The last update's entries, and those it did not run again (every light that changed
    /// since the update before hidden from their whole cells).
    entries: u64,
    unchanged_entries: u64,
    /// Whether a compose works only the atlas tiles whose light may have changed, and the
    /// share of its magnitude a weight or sum may move and count as unchanged.
    recompose_changed_only: bool,
    recompose_tolerance: f32,
    /// The atlas tiles the last full frame's compose wrote, of all the atlas tiles.
    composed_tiles: u32,
    atlas_tiles: u32,
}

#[derive(Serialize)]
struct PassTimes {
    entry_irradiance: f64,
    weights_selection: f64,
    compose: f64,
    shading: f64,
    /// Where cells are hot (the near field's concentration; 0 when no cell is).
    concentration: f64,
    /// The near field and its echo.
    near_field: f64,
    far_field: f64,
    /// Which atlas tiles the compose works (`compose` is the rest of it).
    tile_changes: f64,
}

#[derive(Serialize)]
struct ComposeBytesJson {
    pane_data: u64,
    headers: u64,
    tables: u64,
    written: u64,
    /// Stored tiles summed over all atlas tiles, and the most one atlas tile summed.
    records: u64,
    most_per_tile: u32,
}

pub fn run(a: Args) -> Result<()> {
    if a.frames == 0 || a.frames > 100_000 || a.rounds == 0 || a.rounds > 100 {
        bail!("--frames must be 1 to 100000 and --rounds 1 to 100");
    }
    if a.width == 0 || a.width > 8192 {
        bail!("--width must be 1 to 8192");
    }
    if a.mode == crate::render::Mode::Cssm {
        return crate::bench_cssm::run(&a);
    }
    let params = a.compose.runtime(a.shadow_size)?;
    let mut bench = Bench::new(&a, params)?;
    bench.warm_up()?;
    let times = bench.frame_times(a.rounds)?;
    let tiles = bench.rt.composed_tiles()?;
    let compose = bench.compose_alone()?;
    let bandwidth = copy_bandwidth(&bench.g);
    let hidden = (bench.rt.hidden_pairs()?, bench.rt.unchanged_entries()?);
    let report = bench.report(&a, times, compose, bandwidth, hidden, tiles);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    print_text(&report);
    Ok(())
}

/// The level, its map and rig on the GPU: what every measurement plays.
struct Bench {
    g: Gpu,
    rt: Runtime,
    renderer: Renderer,
    timer: Option<PassTimer>,
    params: RuntimeParams,
    prm_file: Prm,
    rig: Rig,
    frames: usize,
    size: (u32, u32),
    /// No light of the rig moves: every full frame is made to recompose.
    still: bool,
}

/// Wall-clock frame times (ms) of every block, the per-pass GPU times of the full frames that
/// composed, and how many composes the full frames did.
struct FrameTimes {
    direct: Vec<f64>,
    full: Vec<f64>,
    passes: Vec<Vec<f64>>,
    composes: u64,
}

/// Compose alone: what it moves for the last frame's selection, and its wall-clock time (ms).
struct ComposeAlone {
    bytes: ComposeBytesJson,
    wall_ms: f64,
}

impl Bench {
    fn new(a: &Args, mut params: RuntimeParams) -> Result<Bench> {
        if a.vis.is_some() {
            bail!("--vis is for --mode cssm");
        }
        let Some(prm) = a.prm.clone() else { bail!("--mode prm needs the level's map: give --prm FILE") };
        let (scene, prm_file) = MapArgs { scene: a.scene.clone(), prm }.load()?;
        let rig = load_rig(a.rig.as_deref(), &scene)?;
        let cam = camera(&scene, None)?;
        let (w, h) = cam.image_size(a.width);
        let lights = rig.frame(0, a.frames);
        let aspect = w as f32 / h as f32;
        let prm_file = crate::budget::fit_params(
            a.compose.gpu_budget,
            &scene,
            prm_file,
            &cam,
            aspect,
            &lights,
            &mut params,
        )?;
        let g = Gpu::new()?;
        let rt = Runtime::new(&g.device, &g.queue, &scene, &prm_file, params)?;
        let renderer = Renderer::new(&g.device, &g.queue, &scene, &rt, &cam, w, h)?;
        let timer = PassTimer::new(&g.device, &g.queue);
        let still = (1..a.frames).all(|f| rig.frame(f, a.frames) == rig.frame(0, a.frames));
        Ok(Bench { g, rt, renderer, timer, params, prm_file, rig, frames: a.frames, size: (w, h), still })
    }

    fn lights_at(&self, f: usize) -> Vec<Light> {
        self.rig.frame(f, self.frames)
    }

    /// Pipelines, first allocations.
    fn warm_up(&mut self) -> Result<()> {
        for f in 0..3.min(self.frames) {
            self.rt.update(&self.lights_at(f))?;
            self.renderer.draw(&self.rt, true, None);
            self.renderer.wait();
        }
        Ok(())
    }

    /// `rounds` blocks of direct-only frames, each followed by a block of full frames.
    fn frame_times(&mut self, rounds: usize) -> Result<FrameTimes> {
        let mut t = FrameTimes { direct: Vec::new(), full: Vec::new(), passes: Vec::new(), composes: 0 };
        let composes_before = self.rt.composes();
        for _ in 0..rounds {
            for f in 0..self.frames {
                t.direct.push(self.direct_frame(f)?);
            }
            for f in 0..self.frames {
                let (ms, passes) = self.full_frame(f)?;
                t.full.push(ms);
                t.passes.extend(passes);
            }
        }
        t.composes = self.rt.composes() - composes_before;
        Ok(t)
    }

    /// One direct-only frame (shadow maps + shading), in ms.
    fn direct_frame(&mut self, f: usize) -> Result<f64> {
        let t = Instant::now();
        self.rt.update_direct(&self.lights_at(f))?;
        self.renderer.draw(&self.rt, false, None);
        self.renderer.wait();
        Ok(t.elapsed().as_secs_f64() * 1e3)
    }

    /// One full frame, in ms, and its per-pass GPU times if it composed and timestamps exist.
    fn full_frame(&mut self, f: usize) -> Result<(f64, Option<Vec<f64>>)> {
        if self.still {
            self.rt.invalidate();
        }
        let t = Instant::now();
        let up = self.rt.update_timed(&self.lights_at(f), self.timer.as_ref())?;
        self.renderer.draw(&self.rt, true, self.timer.as_ref());
        self.renderer.wait();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        match (&self.timer, up.composed) {
            (Some(tm), true) => Ok((ms, Some(tm.read_ms(&self.g.device, &self.g.queue)?))),
            _ => Ok((ms, None)),
        }
    }

    /// The weights of the last frame, composed again and again, every atlas tile each time.
    fn compose_alone(&mut self) -> Result<ComposeAlone> {
        let bytes = self.rt.compose_bytes()?;
        let weights: Vec<glam::Vec3> = {
            let e = self.rt.read_entry_irradiance()?;
            prm_runtime::cpu::pane_weights(&self.prm_file, &e)
        };
        let reps = 20;
        let t = Instant::now();
        for _ in 0..reps {
            self.rt.invalidate();
            self.rt.compose_weights(&weights)?;
        }
        self.renderer.wait();
        let wall_ms = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
        let bytes = ComposeBytesJson {
            pane_data: bytes.pane_data,
            headers: bytes.headers,
            tables: bytes.tables,
            written: bytes.written,
            records: bytes.records,
            most_per_tile: bytes.most_per_tile,
        };
        Ok(ComposeAlone { bytes, wall_ms })
    }

    /// Every figure, with what was measured; `bandwidth` in bytes per second.
    /// `hidden`: the last update's (entry, light) pairs not probed, and its entries not run;
    /// `tiles`: the atlas tiles its compose wrote, of all.
    fn report(
        &self,
        a: &Args,
        times: FrameTimes,
        compose: ComposeAlone,
        bandwidth: f64,
        (hidden, unchanged): (u64, u64),
        (composed_tiles, atlas_tiles): (u32, u32),
    ) -> Report {
        let b = &compose.bytes;
        let total_bytes = b.pane_data + b.headers + b.tables + b.written;
        let gpu_pass_ms = pass_medians(&times.passes);
        Report {
            device: self.g.describe(),
            scene: a.scene.scene.display().to_string(),
            width: self.size.0,
            height: self.size.1,
            top_k: self.params.top_k,
            shadow_size: a.shadow_size,
            lights: self.lights_at(0).len(),
            clusters: self.prm_file.clusters().len(),
            frames_per_block: a.frames,
            rounds: a.rounds,
            ratio_median: stats(times.full.clone()).median_ms
                / stats(times.direct.clone()).median_ms.max(1e-9),
            direct_frame: stats(times.direct),
            full_frame: stats(times.full),
            composes: times.composes,
            composes_forced: self.still,
            compose_ms_gpu: gpu_pass_ms.as_ref().map(|p| p.compose),
            gpu_pass_ms,
            compose_ms_wall: compose.wall_ms,
            compose_bytes: total_bytes,
            compose_bytes_detail: compose.bytes,
            copy_bandwidth_gb_s: bandwidth / 1e9,
            compose_at_bandwidth_ms: total_bytes as f64 / bandwidth * 1e3,
            light_culling: self.params.cull_hidden_lights,
            entry_light_pairs: self.prm_file.entries().len() as u64
                * self.lights_at(self.frames - 1).len() as u64,
            hidden_light_pairs: hidden,
            entries: self.prm_file.entries().len() as u64,
            unchanged_entries: unchanged,
            recompose_changed_only: self.params.recompose_changed_only,
            recompose_tolerance: self.params.recompose_tolerance,
            composed_tiles,
            atlas_tiles,
        }
    }
}

/// Median time of each GPU pass over the frames that composed; None without timestamps.
fn pass_medians(passes: &[Vec<f64>]) -> Option<PassTimes> {
    let pass_median = |i: usize| stats(passes.iter().map(|p: &Vec<f64>| p[i]).collect()).median_ms;
    (!passes.is_empty()).then(|| PassTimes {
        entry_irradiance: pass_median(0),
        weights_selection: pass_median(1),
        compose: pass_median(2),
        shading: pass_median(3),
        concentration: pass_median(4),
        near_field: pass_median(5),
        far_field: pass_median(6),
        tile_changes: pass_median(7),
    })
}

/// The figures as text.
fn print_text(r: &Report) {
    let bytes = &r.compose_bytes_detail;
    println!("device: {}", r.device);
    println!(
        "{} at {}x{}, {} lights, {} clusters, top-{}, shadow maps {}², {} x {} frames per kind",
        r.scene,
        r.width,
        r.height,
        r.lights,
        r.clusters,
        r.top_k,
        r.shadow_size,
        r.rounds,
        r.frames_per_block
    );
    println!(
        "direct-only frame: median {:.3} ms, p95 {:.3} ms",
        r.direct_frame.median_ms, r.direct_frame.p95_ms
    );
    println!(
        "full frame:        median {:.3} ms, p95 {:.3} ms ({} composes{})",
        r.full_frame.median_ms,
        r.full_frame.p95_ms,
        r.composes,
        if r.composes_forced { ", forced every frame: no light moves" } else { "" }
    );
    println!("ratio (medians):   {:.3} (target <= 1.10)", r.ratio_median);
    if let Some(p) = &r.gpu_pass_ms {
        println!(
            "GPU passes (median): entry irradiance {:.3} ms, concentration {:.3} ms, weights+selection \
            {:.3} ms, near field {:.3} ms, far field {:.3} ms, tile changes {:.3} ms, compose {:.3} ms, \
            shading {:.3} ms",
            p.entry_irradiance,
            p.concentration,
            p.weights_selection,
            p.near_field,
            p.far_field,
            p.tile_changes,
            p.compose,
            p.shading
        );
    } else {
        println!("GPU passes: this adapter has no timestamp queries");
    }
    println!(
        "entry pass: {} of {} (entry, light) pairs not probed, the light's shadow maps hiding the whole cell{}",
        r.hidden_light_pairs,
        r.entry_light_pairs,
        if r.light_culling { "" } else { " (culling off: --no-light-culling)" }
    );
    println!(
        "entry pass: {} of {} entries kept their light, every light that moved hidden from their cells",
        r.unchanged_entries, r.entries
    );
    println!(
        "compose: the last frame wrote {} of {} atlas tiles{}",
        r.composed_tiles,
        r.atlas_tiles,
        if r.recompose_changed_only { ", the rest unchanged" } else { " (every tile: --recompose-all)" }
    );
    println!(
        "compose: {:.3} ms wall (submit + wait), {:.2} MB moved ({} stored tiles summed, at most {} per \
            atlas tile: pane data {:.2} MB, headers {:.2} MB, tables {:.2} MB, lightmap written {:.2} MB)",
        r.compose_ms_wall,
        r.compose_bytes as f64 / 1e6,
        bytes.records,
        bytes.most_per_tile,
        bytes.pane_data as f64 / 1e6,
        bytes.headers as f64 / 1e6,
        bytes.tables as f64 / 1e6,
        bytes.written as f64 / 1e6
    );
    println!(
        "copy bandwidth: {:.1} GB/s -> compose at bandwidth {:.3} ms",
        r.copy_bandwidth_gb_s, r.compose_at_bandwidth_ms
    );
}

/// Bytes per second of a device-local buffer-to-buffer copy (read + write counted).
fn copy_bandwidth(g: &Gpu) -> f64 {
    let size: u64 = 256 << 20;
    let mk = |usage| {
        g.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bandwidth"),
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    let (src, dst) =
        (mk(wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST), mk(wgpu::BufferUsages::COPY_DST));
    let run = |n: u32| {
        let mut enc = g.device.create_command_encoder(&Default::default());
        for _ in 0..n {
            enc.copy_buffer_to_buffer(&src, 0, &dst, 0, size);
        }
        let t = Instant::now();
        g.queue.submit([enc.finish()]);
        let _ = g.device.poll(wgpu::PollType::wait_indefinitely());
        t.elapsed().as_secs_f64()
    };
    run(1);
    let n = 8;
    let best = (0..3).map(|_| run(n)).fold(f64::INFINITY, f64::min);
    2.0 * size as f64 * n as f64 / best
}
