//! The report's moving-objects part (paper 003): per frame of an objects rig (a door that
//! opens, a block that slides), the error of hierarchical radiosity over precomputed visibility
//! and of the PRM baked with the objects at rest (it cannot see them move), both against the
//! ground truth of the posed level on the same texels, with the radiosity's time.

use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use prm::rig::Rig;
use prm::Bvh;
use prm_precompute::parallel::Control;
use prm_precompute::precompute::{precompute, PrecomputeParams};
use prm_precompute::visibility::{build_visibility, moving_texel_set, VisibilityParams};
use prm_runtime::cpu::radiosity::RadiosityParams;
use prm_runtime::cpu::CpuTwin;
use prm_runtime::radiosity::RadiosityPass;
use prm_runtime::Gpu;

use super::{Budget, Figures};
use crate::moving::MovingLevel;

/// The atlas the part runs at (but for `--smoke`): paper 003's Cornell box resolution, and the
/// doorway level's own.
pub const ATLAS: u32 = 128;

/// One frame.
pub struct MovingRow {
    pub time: f64,
    pub error: f64,
    pub bias: f64,
    pub noise: f64,
    pub prm_error: f64,
    pub prm_bias: f64,
    pub radiosity_ms: f64,
    /// Direct light at the texels (GPU: shadow maps; CPU: rays).
    pub direct_ms: f64,
}

/// The part's figures.
pub struct Moving {
    pub rig: PathBuf,
    pub atlas: u32,
    pub texels: usize,
    pub vis_bytes: usize,
    pub occluder_bytes: usize,
    pub vis_uncompressed: usize,
    pub vis_seconds: f64,
    pub device: String,
    pub spp: u32,
    pub rows: Vec<MovingRow>,
}

/// `<level>_rig.json` beside the level, when it moves objects.
pub fn objects_rig_beside(level: &Path) -> Option<PathBuf> {
    let stem = level.file_stem()?.to_str()?;
    let p = level.with_file_name(format!("{stem}_rig.json"));
    let text = std::fs::read_to_string(&p).ok()?;
    text.contains("\"objects\"").then_some(p)
}

/// Shadow-map texels a side for the GPU's direct light at the texels (the runtime's default).
const SHADOW_SIZE: u32 = 1024;

/// The part, on `level` (its glTF) with the objects rig `rig_path`; `None` when the level has
/// no movable objects.
pub fn moving(
    b: &Budget,
    args: &crate::common::SceneArgs,
    rig_path: &Path,
    gpu: Option<&Gpu>,
    seed: u64,
) -> Result<Option<Moving>> {
    let atlas = b.moving_atlas;
    let scene = crate::common::load(args, atlas, true)?;
    if scene.movables.is_empty() {
        return Ok(None);
    }
    eprintln!("moving objects: visibility, map at rest, {} frames...", b.rig_frames);
    let rig = Rig::load(rig_path, &scene.lights)?;
    let texels = moving_texel_set(&scene, atlas, atlas);
    let t = Instant::now();
    let vis = build_visibility(&scene, &texels, &VisibilityParams::default(), Control::none())
        .map_err(|_| anyhow!("visibility stopped"))?;
    let vis_seconds = t.elapsed().as_secs_f64();
    let (vis_bytes, vis_uncompressed) = (vis.bytes(), vis.uncompressed_bytes());
    let occluder_bytes = vis.objects.iter().filter_map(|o| o.occluder.as_ref()).map(|c| c.bytes()).sum();
    let rest_bvh = Bvh::build(&scene);
    let p = PrecomputeParams {
        atlas: prm::density::Atlas::single(atlas),
        seed,
        ..PrecomputeParams::production()
    };
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let (map, _) =
        precompute(&scene, &rest_bvh, &p, &|_, _, _| {}, &cancel).map_err(|e| anyhow!("precompute: {e}"))?;
    let mut twin = CpuTwin::new(&map, &rest_bvh, 32);
    let level = MovingLevel::new(scene, texels, vis, rig, rig_path)?;
    let mut pass = match gpu {
        Some(g) => {
            Some(RadiosityPass::new(&g.device, &level.scene, &level.texels, &level.hierarchy, &level.vis)?)
        }
        None => None,
    };
    let params = RadiosityParams::default();
    let mut rows = Vec::new();
    for f in 0..b.rig_frames {
        let time = level.rig.frame_time(f, b.rig_frames);
        let on_gpu = gpu.zip(pass.as_mut()).map(|(g, p)| crate::moving::GpuFrame {
            gpu: g,
            pass: p,
            shadow_size: SHADOW_SIZE,
        });
        let e = level.frame(time, &params, on_gpu, Some(b.rig_gt_spp), seed, Some(&mut twin))?;
        let ((error, bias, noise), (prm_error, prm_bias)) =
            (e.error.unwrap_or_default(), e.prm_error.unwrap_or_default());
        rows.push(MovingRow {
            time,
            error,
            bias,
            noise,
            prm_error,
            prm_bias,
            radiosity_ms: e.radiosity_s * 1e3,
            direct_ms: e.direct_s * 1e3,
        });
    }
    Ok(Some(Moving {
        rig: rig_path.to_path_buf(),
        atlas,
        texels: level.texels.len(),
        vis_bytes,
        occluder_bytes,
        vis_uncompressed,
        vis_seconds,
        device: gpu
            .map_or(format!("CPU, {} threads (direct light by rays)", rayon::current_num_threads()), |g| {
                format!("{} (direct light from {SHADOW_SIZE}² shadow maps)", g.info.name)
            }),
        spp: b.rig_gt_spp,
        rows,
    }))
}

/// The part's section of report.md.
pub fn section(s: &mut String, f: &Figures, plots: bool) {
    let Some(m) = &f.moving else { return };
    let _ = writeln!(
        s,
        "\n## Moving objects ({} frames, {})\n\nHierarchical radiosity over precomputed visibility \
        (CSSM, paper 003) at {}², {} texels: visibility {:.1} MB (surface shadow maps {:.1} MB, \
        {:.1} MB uncompressed; occluder maps {:.1} MB), made in {:.1} s. The PRM baseline is baked with the objects at rest (production preset, top-32): it \
        cannot see them move. Errors against the posed level's ground truth at {} spp on the same \
        texels, its noise removed. Times on {}: the direct light at the texels, and the radiosity \
        from it with its readback (the shading is not in them).\n",
        m.rows.len(),
        m.rig.display(),
        m.atlas,
        m.texels,
        m.vis_bytes as f64 / 1e6,
        (m.vis_bytes - m.occluder_bytes) as f64 / 1e6,
        m.vis_uncompressed as f64 / 1e6,
        m.occluder_bytes as f64 / 1e6,
        m.vis_seconds,
        m.spp,
        m.device
    );
    if plots {
        let _ = writeln!(s, "![error per frame, radiosity and PRM](moving.png)\n");
    }
    let _ = writeln!(
        s,
        "| t (s) | radiosity error | bias | PRM error | PRM bias | direct ms | radiosity ms | GT noise |\n\
        | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in &m.rows {
        let _ = writeln!(
            s,
            "| {:.2} | {:.1} % | {:+.1} % | {:.1} % | {:+.1} % | {:.0} | {:.0} | {:.1} % |",
            r.time,
            r.error * 100.0,
            r.bias * 100.0,
            r.prm_error * 100.0,
            r.prm_bias * 100.0,
            r.direct_ms,
            r.radiosity_ms,
            r.noise * 100.0
        );
    }
}

/// moving.png: both errors per frame.
pub fn plot(path: &Path, m: &Moving) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| anyhow!("drawing a plot: {e}");
    let root = BitMapBackend::new(path, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let t_max = m.rows.iter().map(|r| r.time).fold(0.0, f64::max).max(1e-3);
    let e_max = m.rows.iter().map(|r| r.error.max(r.prm_error)).fold(0.0, f64::max).max(0.01) * 110.0;
    let mut chart = ChartBuilder::on(&root)
        .caption("Moving objects: indirect error per frame", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..t_max, 0.0..e_max)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc("rig time (s)")
        .y_desc("error against the ground truth (%)")
        .draw()
        .map_err(|e| err(&e))?;
    let series = [
        (
            "radiosity + CSSM",
            RGBColor(214, 39, 40),
            m.rows.iter().map(|r| (r.time, r.error * 100.0)).collect::<Vec<_>>(),
        ),
        (
            "PRM (objects at rest)",
            RGBColor(31, 119, 180),
            m.rows.iter().map(|r| (r.time, r.prm_error * 100.0)).collect(),
        ),
    ];
    for (label, colour, points) in series {
        chart
            .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(points.iter().map(|&p| Circle::new(p, 4, colour.filled()))).map_err(|e| err(&e))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
