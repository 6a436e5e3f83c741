//! The report's scale section (issue 13): the bundled large level's family of pillared halls at
//! 1, 4 and 16 halls, each precomputed as a user would (`prm precompute LEVEL.glb` with the
//! default preset and generated UVs in pages), and per size:
//!
//! - precompute time, peak memory (the child process's own high-water mark) and `.prm` size;
//! - the runtime's GPU memory ([`GpuMemory::estimate`]);
//! - the error of the default runtime selection (top-32 picked locally + groups) and of all
//!   panes against the ground truth, its noise removed in quadrature;
//! - a direct-only frame and a frame that recomposes, on the GPU when there is one.
//!
//! Each precompute runs as its own `prm precompute` process, so its peak memory is its own and
//! not the report's.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use prm_runtime::{Gpu, GpuMemory};
use serde_json::Value;

use super::measure::{compare, ground_truth, runtime_lightmap, Level};
use super::rig::report_runtime;
use super::sweeps::frame_ms;
use crate::common::{load_with_prm, SceneArgs};

/// What the scale section spends.
pub struct ScaleBudget {
    /// Halls across and deep, per level size.
    pub grids: Vec<(u32, u32)>,
    /// Pillar facets and bands (32 x 8 is the bundled level's).
    pub pillars: (u32, u32),
    /// Extra `prm precompute` arguments (none: the default preset, as a user runs it).
    pub precompute_args: Vec<String>,
    pub gt_spp: u32,
    pub frame_width: u32,
    pub frame_reps: usize,
}

impl ScaleBudget {
    pub fn new(quick: bool, smoke: bool) -> ScaleBudget {
        if smoke {
            return ScaleBudget {
                grids: vec![(1, 1), (2, 1)],
                // One hall fits a 64^2 page; two need pages (at 1 m texels).
                pillars: (6, 1),
                precompute_args: [
                    "--texel-size",
                    "1",
                    "--page-size",
                    "64",
                    "--entries",
                    "256",
                    "--paths",
                    "8",
                    "--clusters",
                    "16",
                ]
                .map(String::from)
                .to_vec(),
                gt_spp: 8,
                frame_width: 32,
                frame_reps: 2,
            };
        }
        ScaleBudget {
            grids: vec![(1, 1), (2, 2), (4, 4)],
            pillars: (32, 8),
            precompute_args: Vec::new(),
            gt_spp: if quick { 64 } else { 256 },
            frame_width: 640,
            frame_reps: 9,
        }
    }
}

/// One level size, measured.
pub struct ScaleRow {
    pub grid: (u32, u32),
    pub triangles: usize,
    pub lights: usize,
    pub texels: usize,
    pub pages: u32,
    pub page_size: u32,
    pub entries: usize,
    pub clusters: usize,
    pub precompute_s: f64,
    /// The precompute process's peak resident memory, where the system tells it.
    pub peak_bytes: Option<u64>,
    pub file_bytes: u64,
    pub gpu_bytes: u64,
    pub gt_s: f64,
    pub gt_noise: f64,
    /// (error, bias) of the default selection (top-32, local, groups) and of all panes.
    pub top: (f64, f64),
    pub all: (f64, f64),
    /// Median direct-only and recomposing frame times (ms) on the GPU; none without one.
    pub frame_ms: Option<(f64, f64)>,
}

impl ScaleRow {
    pub fn rooms(&self) -> u32 {
        self.grid.0 * self.grid.1
    }

    /// The peak memory in bytes (NaN where the system does not tell it).
    pub fn peak(&self) -> f64 {
        self.peak_bytes.map_or(f64::NAN, |b| b as f64)
    }

    /// `figure` of this row per hall over the same of `first` per hall (linear growth: 1).
    pub fn per_hall(&self, first: &ScaleRow, figure: fn(&ScaleRow) -> f64) -> f64 {
        (figure(self) / self.rooms() as f64) / (figure(first) / first.rooms() as f64)
    }

    /// An error with the ground truth's own noise removed in quadrature.
    pub fn clean(&self, error: f64) -> f64 {
        (error * error - self.gt_noise * self.gt_noise).max(0.0).sqrt()
    }
}

/// Every level size of `b`, in order, its files under `dir` (created).
pub fn scale_rows(b: &ScaleBudget, dir: &Path, gpu: Option<&Gpu>, seed: u64) -> Result<Vec<ScaleRow>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    b.grids.iter().map(|&grid| scale_row(b, dir, grid, gpu, seed)).collect()
}

fn scale_row(
    b: &ScaleBudget,
    dir: &Path,
    grid: (u32, u32),
    gpu: Option<&Gpu>,
    seed: u64,
) -> Result<ScaleRow> {
    let name = format!("halls_{}x{}", grid.0, grid.1);
    let glb = dir.join(format!("{name}.glb"));
    let prm_path = dir.join(format!("{name}.prm"));
    let level = prm_precompute::scenes::halls(grid.0, grid.1, b.pillars.0, b.pillars.1);
    prm::fsutil::write_bytes_atomic(&glb, &level.to_glb())
        .with_context(|| format!("writing {}", glb.display()))?;
    eprintln!("scale: precompute {name}...");
    let summary = precompute_process(&glb, &prm_path, &b.precompute_args, seed)?;
    let field = |k: &str| summary.get(k).and_then(Value::as_f64);
    let args = SceneArgs { scene: glb.clone(), require_uv1: false, allow_overlap: false };
    let (scene, map) = load_with_prm(&args, &prm_path)?;
    let header = map.header().clone();
    let level = Level::for_map(scene, &map)?;
    eprintln!("scale: ground truth {name} ({} spp)...", b.gt_spp);
    let t = Instant::now();
    let (gt, gt_noise) = ground_truth(&level, &level.scene.lights, b.gt_spp, seed)?;
    let gt_s = t.elapsed().as_secs_f64();
    eprintln!("scale: runtime {name}...");
    let mut rt = report_runtime(gpu, &level, &map)?;
    let lights = &level.scene.lights;
    let top = compare(&level.set, &runtime_lightmap(rt.as_mut(), &map, &level.bvh, lights, 32)?, &gt);
    let all = compare(&level.set, &runtime_lightmap(rt.as_mut(), &map, &level.bvh, lights, usize::MAX)?, &gt);
    let frame = match (gpu, rt.as_mut()) {
        (Some(g), Some(rt)) => Some(frame_ms(g, &level, rt, 32, b.frame_width, b.frame_reps)?),
        _ => None,
    };
    Ok(ScaleRow {
        grid,
        triangles: level.scene.triangles.len(),
        lights: lights.len(),
        texels: level.set.len(),
        pages: header.pages,
        page_size: header.atlas_width,
        entries: map.entries().len(),
        clusters: map.clusters().len(),
        precompute_s: field("seconds_wall")
            .ok_or_else(|| anyhow!("precompute summary lacks seconds_wall"))?,
        peak_bytes: field("peak_memory_bytes").map(|b| b as u64),
        file_bytes: std::fs::metadata(&prm_path)?.len(),
        gpu_bytes: GpuMemory::estimate(&map).total(),
        gt_s,
        gt_noise,
        top,
        all,
        frame_ms: frame,
    })
}

/// Runs `prm precompute LEVEL -o OUT --json --seed S ARGS` as a child process and returns its
/// summary.
fn precompute_process(glb: &Path, out: &Path, args: &[String], seed: u64) -> Result<Value> {
    let exe = std::env::current_exe().context("finding the prm executable")?;
    let output = Command::new(&exe)
        .arg("precompute")
        .arg(glb)
        .arg("-o")
        .arg(out)
        .args(["--json", "--seed", &seed.to_string()])
        .args(args)
        .output()
        .with_context(|| format!("running {} precompute", exe.display()))?;
    if !output.status.success() {
        bail!(
            "prm precompute {} failed ({}): {}",
            glb.display(),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        );
    }
    serde_json::from_slice(&output.stdout).context("reading prm precompute's JSON summary")
}
