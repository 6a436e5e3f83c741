//! `prm report`: how right each method is and what it costs, on one level, in one run.
//!
//! Every error is DESIGN.md §3's normalised luminance RMSE of the indirect irradiance over the
//! covered texels, against `prm ground-truth` computed in the same run (its own noise is given
//! beside it). The report sweeps:
//! - the PRM's precompute budget (entries, paths, clusters): error of all panes with exact
//!   (ray-traced) weights against precompute time;
//! - its runtime budget (top-K, with and without the groups standing in for the left-out
//!   clusters): error of the runtime's lightmap against frame time, on the GPU when an adapter
//!   exists (else the CPU twin, said so);
//! - the reference baker (photons, hence VPLs, and VPLs per virtual light);
//! - a moving-light rig: per frame, the error of PRM top-32, PRM all panes and the reference,
//!   and their flicker: the RMS change of the error image from one frame to the next, over the
//!   mean ground truth. Every frame's ground truth uses the same seed (common random numbers),
//!   so its noise changes little between frames and the flicker is mostly the method's own.
//!
//! Output: `report.md` (machine, device, seeds, the command, every figure) and PNG plots made
//! with `plotters` (labels need a TrueType font: DejaVu, Liberation or Noto, as Debian's
//! `fonts-dejavu-core` installs).

use prm_precompute::parallel::Control;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;
use plotters::prelude::*;
use prm::prm_file::Prm;
use prm::rig::Rig;
use prm::{luminance, Bvh, Light, Scene, TexelSet};
use prm_precompute::ground_truth::{GtParams, Tracer};
use prm_precompute::precompute::{precompute, PrecomputeParams};
use prm_precompute::reference::bake::{evaluate, virtual_lights, BakeParams};
use prm_runtime::cpu::CpuTwin;
use prm_runtime::{Gpu, Renderer, Runtime, RuntimeParams};

use crate::common::{load, SceneArgs};
use crate::render::camera;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// Light rig for the moving-light part (default: the level's first light moving across
    /// the middle 40 % of the level's width).
    #[arg(long)]
    rig: Option<PathBuf>,
    /// A smaller budget: under 15 minutes per bundled scene on 2 cores.
    #[arg(long)]
    quick: bool,
    /// A tiny budget, for tests of the report itself.
    #[arg(long, hide = true)]
    smoke: bool,
    /// Seed of every stage.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output folder (created).
    #[arg(short, long)]
    output: PathBuf,
}

/// What a report spends.
struct Budget {
    atlas: u32,
    gt_spp: u32,
    rig_gt_spp: u32,
    rig_frames: usize,
    /// (entries, paths, clusters)
    prm: Vec<(u32, u32, u32)>,
    /// The configuration the runtime and rig parts use (index into `prm`).
    production: usize,
    top_k: Vec<usize>,
    /// (photons, VPLs per virtual light at the first bounce)
    reference: Vec<(usize, usize)>,
    rig_reference: (usize, usize),
    frame_width: u32,
    frame_reps: usize,
}

impl Budget {
    fn new(quick: bool, smoke: bool) -> Budget {
        if smoke {
            return Budget {
                atlas: 32,
                gt_spp: 16,
                rig_gt_spp: 8,
                rig_frames: 3,
                prm: vec![(256, 8, 16), (512, 8, 32)],
                production: 1,
                top_k: vec![4, usize::MAX],
                reference: vec![(2000, 64)],
                rig_reference: (2000, 64),
                frame_width: 32,
                frame_reps: 2,
            };
        }
        let mut b = Budget {
            atlas: 256,
            gt_spp: 1024,
            rig_gt_spp: 128,
            rig_frames: 6,
            prm: vec![(1024, 32, 64), (2048, 64, 128), (4096, 128, 256), (4096, 256, 256)],
            production: 2,
            top_k: vec![8, 16, 32, 64, 128, usize::MAX],
            reference: vec![(10_000, 64), (20_000, 64), (40_000, 64)],
            rig_reference: (10_000, 64),
            frame_width: 640,
            frame_reps: 9,
        };
        if !quick {
            b.gt_spp = 2048;
            b.rig_gt_spp = 512;
            b.rig_frames = 12;
            b.prm.push((8192, 256, 512));
            b.reference.extend([(80_000, 64), (40_000, 32)]);
            b.rig_reference = (40_000, 64);
        }
        b
    }
}

/// A lightmap's error against the ground truth, and the time it took.
struct Point {
    label: String,
    seconds: f64,
    error: f64,
    bias: f64,
}

struct Frame {
    gt_noise: f64,
    /// (PRM top-32, PRM all, reference) error
    errors: [f64; 3],
    /// Per-texel signed luminance error of each, for flicker.
    residuals: [Vec<f32>; 3],
    gt_mean: f64,
    gt: Vec<f32>,
}

pub fn run(a: Args) -> Result<()> {
    let b = Budget::new(a.quick, a.smoke);
    let start = Instant::now();
    std::fs::create_dir_all(&a.output).with_context(|| format!("creating {}", a.output.display()))?;
    let scene = load(&a.scene, b.atlas, true)?;
    let rig = match &a.rig {
        Some(p) => Rig::load(p, &scene.lights)?,
        None => default_rig(&scene)?,
    };
    let bvh = Bvh::build(&scene);
    let set = TexelSet::build(&scene, b.atlas, b.atlas);
    if set.is_empty() {
        bail!("the level has no lightmap texels at {}^2", b.atlas);
    }
    let gpu = Gpu::new().ok();
    let device = gpu
        .as_ref()
        .map_or("none found: runtime figures from the CPU twin (ray-traced visibility)".to_string(), |g| {
            g.describe()
        });
    let cancel = AtomicBool::new(false);

    eprintln!("ground truth ({} spp)...", b.gt_spp);
    let t = Instant::now();
    let (gt, gt_noise) = ground_truth(&scene, &bvh, &set, &scene.lights, b.gt_spp, a.seed)?;
    let gt_seconds = t.elapsed().as_secs_f64();

    // PRM: precompute budget.
    let mut prm_points = Vec::new();
    let mut production: Option<Prm> = None;
    for (k, &(entries, paths, clusters)) in b.prm.iter().enumerate() {
        eprintln!("precompute {entries} entries, {paths} paths, {clusters} clusters...");
        let p = PrecomputeParams {
            entries,
            paths,
            clusters,
            atlas: b.atlas,
            seed: a.seed,
            ..PrecomputeParams::production()
        };
        let t = Instant::now();
        let (map, _) =
            precompute(&scene, &bvh, &p, &|_, _, _| {}, &cancel).map_err(|e| anyhow!("precompute: {e}"))?;
        let seconds = t.elapsed().as_secs_f64();
        let mut twin = CpuTwin::new(&map, &bvh, usize::MAX);
        let img = twin.frame(&scene.lights).to_vec();
        let c = compare(&set, &img, &gt);
        prm_points.push(Point {
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
    let prod = b.prm[b.production];

    // PRM: runtime budget.
    eprintln!("runtime top-K sweep...");
    let (runtime_points, runtime_plain, direct_ms) =
        runtime_sweep(&b, &scene, &bvh, &set, &map, &gt, gpu.as_ref())?;

    // Reference baker.
    let mut ref_points = Vec::new();
    for &(photons, cluster) in &b.reference {
        eprintln!("reference {photons} photons, {cluster} VPLs per light...");
        let t = Instant::now();
        let ind = reference(&scene, &bvh, &set, &scene.lights, photons, cluster, b.atlas, a.seed)?;
        let seconds = t.elapsed().as_secs_f64();
        let c = compare_texels(&ind, &gt);
        ref_points.push(Point {
            label: format!("{photons} photons, {cluster}/light"),
            seconds,
            error: c.0,
            bias: c.1,
        });
    }

    // The moving-light rig.
    let mut frames = Vec::new();
    let mut rt = match &gpu {
        Some(g) => Some(Runtime::new(
            &g.device,
            &g.queue,
            &scene,
            &map,
            RuntimeParams { top_k: 32, shadow_size: 1024, residual: true },
        )?),
        None => None,
    };
    for f in 0..b.rig_frames {
        eprintln!("rig frame {} of {}...", f + 1, b.rig_frames);
        let lights = rig.frame(f, b.rig_frames);
        let (g, g_noise) = ground_truth(&scene, &bvh, &set, &lights, b.rig_gt_spp, a.seed)?;
        let top = runtime_lightmap(rt.as_mut(), &map, &bvh, &lights, 32)?;
        let all = runtime_lightmap(rt.as_mut(), &map, &bvh, &lights, usize::MAX)?;
        let rf =
            reference(&scene, &bvh, &set, &lights, b.rig_reference.0, b.rig_reference.1, b.atlas, a.seed)?;
        let top = at_texels(&set, &top);
        let all = at_texels(&set, &all);
        let res =
            |x: &[Vec3]| x.iter().zip(&g).map(|(a, b)| luminance(*a) - luminance(*b)).collect::<Vec<f32>>();
        frames.push(Frame {
            gt_noise: g_noise,
            errors: [compare_texels(&top, &g).0, compare_texels(&all, &g).0, compare_texels(&rf, &g).0],
            residuals: [res(&top), res(&all), res(&rf)],
            gt_mean: g.iter().map(|v| luminance(*v) as f64).sum::<f64>() / g.len() as f64,
            gt: g.iter().map(|v| luminance(*v)).collect(),
        });
    }

    let fonts = register_font();
    let plots = if fonts {
        plot_precompute(&a.output.join("precompute.png"), &prm_points, &ref_points)?;
        plot_runtime(
            &a.output.join("runtime.png"),
            &runtime_points,
            &runtime_plain,
            direct_ms,
            gpu.is_some(),
        )?;
        plot_rig(&a.output.join("rig.png"), &frames)?;
        true
    } else {
        eprintln!(
            "note: no TrueType font found (install fonts-dejavu-core); report.md written without plots"
        );
        false
    };
    let md = markdown(
        &a,
        &b,
        &scene,
        &device,
        gt_seconds,
        gt_noise,
        prod,
        &prm_points,
        &runtime_points,
        &runtime_plain,
        direct_ms,
        &ref_points,
        &frames,
        plots,
        start.elapsed().as_secs_f64(),
    );
    prm::fsutil::write_bytes_atomic(&a.output.join("report.md"), md.as_bytes())
        .with_context(|| "writing report.md")?;
    println!("report -> {} ({:.0} s)", a.output.join("report.md").display(), start.elapsed().as_secs_f64());
    Ok(())
}

/// The level's first light sweeping across the middle 40 % of the level's width.
fn default_rig(scene: &Scene) -> Result<Rig> {
    let Some(first) = scene.lights.first() else { bail!("the level has no lights; give a --rig") };
    let (lo, hi) = scene.bounds();
    let dx = (hi.x - lo.x) * 0.2;
    let json = if first.is_positional() {
        let p = first.position;
        format!(
            r#"{{"lights": [{{"name": {:?}, "keyframes": [{{"time": 0, "position": [{}, {}, {}]}}, {{"time": 1, "position": [{}, {}, {}]}}]}}]}}"#,
            first.name,
            p.x - dx,
            p.y,
            p.z,
            p.x + dx,
            p.y,
            p.z
        )
    } else {
        let d = first.direction;
        format!(
            r#"{{"lights": [{{"name": {:?}, "keyframes": [{{"time": 0, "direction": [{}, {}, {}]}}, {{"time": 1, "direction": [{}, {}, {}]}}]}}]}}"#,
            first.name,
            d.x - 0.2,
            d.y,
            d.z,
            d.x + 0.2,
            d.y,
            d.z
        )
    };
    Ok(Rig::parse(Path::new("(default rig)"), &json, &scene.lights)?)
}

/// Ground-truth indirect irradiance per covered texel, and its noise in the metric's units.
fn ground_truth(
    scene: &Scene,
    bvh: &Bvh,
    set: &TexelSet,
    lights: &[Light],
    spp: u32,
    seed: u64,
) -> Result<(Vec<Vec3>, f64)> {
    let mut lit = scene.clone();
    lit.lights = lights.to_vec();
    let tracer = Tracer::new(&lit, bvh, GtParams { spp, seed, ..GtParams::default() });
    let v = tracer
        .texels(&set.texels, set.width, Control::none())
        .map_err(|_| anyhow!("ground truth stopped"))?;
    Ok((v.iter().map(|r| r.indirect).collect(), prm_precompute::ground_truth::indirect_noise(&v)))
}

fn at_texels(set: &TexelSet, img: &[Vec3]) -> Vec<Vec3> {
    set.texels.iter().map(|t| img[(t.j * set.width + t.i) as usize]).collect()
}

fn compare(set: &TexelSet, img: &[Vec3], gt: &[Vec3]) -> (f64, f64) {
    compare_texels(&at_texels(set, img), gt)
}

fn compare_texels(a: &[Vec3], gt: &[Vec3]) -> (f64, f64) {
    let c = prm::metric::compare(a, gt, None);
    (c.error, c.bias)
}

#[allow(clippy::too_many_arguments)]
fn reference(
    scene: &Scene,
    bvh: &Bvh,
    set: &TexelSet,
    lights: &[Light],
    photons: usize,
    cluster: usize,
    atlas: u32,
    seed: u64,
) -> Result<Vec<Vec3>> {
    let p = BakeParams {
        photons,
        cluster_size: cluster,
        atlas,
        seed,
        indirect_only: true,
        ..BakeParams::default()
    };
    p.validate().map_err(|e| anyhow!("bad reference parameter: {e}"))?;
    let vl = virtual_lights(scene, bvh, lights, &p);
    let baked = evaluate(scene, bvh, set, lights, &vl, &p, Control::none())
        .map_err(|_| anyhow!("reference stopped"))?;
    Ok(baked.indirect)
}

/// The runtime's lightmap for these lights and top-K: the GPU's if there is one.
fn runtime_lightmap(
    rt: Option<&mut Runtime>,
    map: &Prm,
    bvh: &Bvh,
    lights: &[Light],
    k: usize,
) -> Result<Vec<Vec3>> {
    match rt {
        Some(rt) => {
            rt.set_top_k(k)?;
            rt.update(lights)?;
            Ok(rt.read_lightmap()?)
        }
        None => Ok(CpuTwin::new(map, bvh, k).frame(lights).to_vec()),
    }
}

type Sweep = (Vec<Point>, Vec<Point>, f64);

/// Error and frame time per top-K (with groups, then without), and the direct-only frame time.
fn runtime_sweep(
    b: &Budget,
    scene: &Scene,
    bvh: &Bvh,
    set: &TexelSet,
    map: &Prm,
    gt: &[Vec3],
    gpu: Option<&Gpu>,
) -> Result<Sweep> {
    let (mut with, mut without) = (Vec::new(), Vec::new());
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let label = |k: usize| if k >= map.clusters().len() { "all".to_string() } else { k.to_string() };
    let Some(g) = gpu else {
        for &k in &b.top_k {
            for (residual, out) in [(true, &mut with), (false, &mut without)] {
                let mut twin = CpuTwin::new(map, bvh, k);
                twin.set_residual(residual);
                let t = Instant::now();
                let img = twin.frame(&scene.lights).to_vec();
                let c = compare(set, &img, gt);
                out.push(Point {
                    label: label(k),
                    seconds: t.elapsed().as_secs_f64(),
                    error: c.0,
                    bias: c.1,
                });
            }
        }
        return Ok((with, without, f64::NAN));
    };
    let mut rt = Runtime::new(
        &g.device,
        &g.queue,
        scene,
        map,
        RuntimeParams { top_k: 32, shadow_size: 1024, residual: true },
    )?;
    let cam = camera(scene, None)?;
    let (w, h) = cam.image_size(b.frame_width);
    let renderer = Renderer::new(&g.device, &g.queue, scene, &rt, cam, w, h)?;
    let mut direct = Vec::new();
    for _ in 0..b.frame_reps {
        let t = Instant::now();
        rt.update_direct(&scene.lights)?;
        renderer.draw(&rt, false, None);
        renderer.wait();
        direct.push(t.elapsed().as_secs_f64() * 1e3);
    }
    for &k in &b.top_k {
        for (residual, out) in [(true, &mut with), (false, &mut without)] {
            rt.set_residual(residual);
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
            let c = compare(set, &rt.read_lightmap()?, gt);
            out.push(Point { label: label(k), seconds: median(times) / 1e3, error: c.0, bias: c.1 });
        }
    }
    Ok((with, without, median(direct)))
}

/// Registers the first TrueType font found as plotters' "sans-serif".
fn register_font() -> bool {
    let candidates = [
        "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
        "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
        "/usr/share/fonts/truetype/noto/NotoSans-Regular.ttf",
        "/usr/share/fonts/TTF/DejaVuSans.ttf",
        "/Library/Fonts/Arial.ttf",
        "C:\\Windows\\Fonts\\arial.ttf",
    ];
    for c in candidates {
        if let Ok(bytes) = std::fs::read(c) {
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                return true;
            }
        }
    }
    false
}

const PRM_COLOUR: RGBColor = RGBColor(31, 119, 180);
const REF_COLOUR: RGBColor = RGBColor(214, 39, 40);
const PLAIN_COLOUR: RGBColor = RGBColor(150, 150, 150);
const ALL_COLOUR: RGBColor = RGBColor(44, 160, 44);

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("drawing a plot: {e}")
}

fn bounds(points: &[&Point], f: impl Fn(&Point) -> f64) -> (f64, f64) {
    let v: Vec<f64> = points.iter().map(|p| f(p)).filter(|x| x.is_finite() && *x > 0.0).collect();
    let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = v.iter().cloned().fold(0.0, f64::max);
    if lo.is_finite() && hi > 0.0 {
        (lo, hi)
    } else {
        (1e-3, 1.0)
    }
}

fn plot_precompute(path: &Path, prm: &[Point], reference: &[Point]) -> Result<()> {
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let all: Vec<&Point> = prm.iter().chain(reference).collect();
    let (t0, t1) = bounds(&all, |p| p.seconds);
    let e1 = all.iter().map(|p| p.error * 100.0).filter(|e| e.is_finite()).fold(0.0, f64::max) * 1.15 + 0.5;
    let mut chart = ChartBuilder::on(&root)
        .caption("Indirect error against precompute / bake time", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d((t0 * 0.7..t1 * 1.4).log_scale(), 0.0..e1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("time (s, log)")
        .y_desc("error vs ground truth (%)")
        .draw()
        .map_err(plot_err)?;
    for (points, colour, name) in [
        (prm, PRM_COLOUR, "PRM, all panes (entries N, paths M, clusters C)"),
        (reference, REF_COLOUR, "reference baker (photons, VPLs per light)"),
    ] {
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (p.seconds, p.error * 100.0)),
                colour.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart
            .draw_series(points.iter().map(|p| Circle::new((p.seconds, p.error * 100.0), 4, colour.filled())))
            .map_err(plot_err)?;
        chart
            .draw_series(points.iter().map(|p| {
                Text::new(
                    p.label.clone(),
                    (p.seconds, p.error * 100.0 + e1 * 0.02),
                    ("sans-serif", 12).into_font().color(&colour),
                )
            }))
            .map_err(plot_err)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

fn plot_runtime(path: &Path, with: &[Point], without: &[Point], direct_ms: f64, gpu: bool) -> Result<()> {
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let all: Vec<&Point> = with.iter().chain(without).collect();
    let ms = |p: &Point| p.seconds * 1e3;
    let (t0, t1) = bounds(&all, ms);
    let (t0, t1) = if direct_ms.is_finite() { (t0.min(direct_ms), t1.max(direct_ms)) } else { (t0, t1) };
    let e1 = (all.iter().map(|p| p.error * 100.0).filter(|e| e.is_finite()).fold(0.0, f64::max) * 1.1 + 0.5)
        .min(120.0);
    let caption = if gpu {
        "Indirect error against frame time (GPU runtime, top-K)"
    } else {
        "Indirect error against lightmap time (CPU twin, top-K)"
    };
    let pad = (t1 - t0).max(t1 * 0.05);
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d((t0 - pad * 0.2).max(0.0)..t1 + pad * 0.2, 0.0..e1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(if gpu { "full frame time (ms, median)" } else { "lightmap time (ms)" })
        .y_desc("error vs ground truth (%)")
        .draw()
        .map_err(plot_err)?;
    for (points, colour, name) in
        [(with, PRM_COLOUR, "top-K + groups for the rest"), (without, PLAIN_COLOUR, "top-K alone")]
    {
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (ms(p), p.error * 100.0)),
                colour.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart
            .draw_series(points.iter().map(|p| Circle::new((ms(p), p.error * 100.0), 4, colour.filled())))
            .map_err(plot_err)?;
        chart
            .draw_series(points.iter().map(|p| {
                Text::new(
                    format!("K={}", p.label),
                    (ms(p), (p.error * 100.0 + e1 * 0.02).min(e1 * 0.97)),
                    ("sans-serif", 12).into_font().color(&colour),
                )
            }))
            .map_err(plot_err)?;
    }
    if direct_ms.is_finite() {
        chart
            .draw_series(LineSeries::new([(direct_ms, 0.0), (direct_ms, e1)], BLACK.stroke_width(1)))
            .map_err(plot_err)?
            .label("direct-only frame")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

fn plot_rig(path: &Path, frames: &[Frame]) -> Result<()> {
    let root = BitMapBackend::new(path, (900, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (top, bottom) = root.split_vertically(450);
    let names = ["PRM top-32 + groups", "PRM all panes", "reference baker"];
    let colours = [PRM_COLOUR, ALL_COLOUR, REF_COLOUR];
    let n = frames.len().max(2) as f64;
    let e1 =
        frames.iter().flat_map(|f| f.errors).map(|e| e * 100.0).filter(|e| e.is_finite()).fold(0.0, f64::max)
            * 1.15
            + 0.5;
    let mut chart = ChartBuilder::on(&top)
        .caption("Error per frame of the moving-light rig", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.2..n - 0.8, 0.0..e1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_labels(frames.len())
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("frame")
        .y_desc("error (%)")
        .draw()
        .map_err(plot_err)?;
    for m in 0..3 {
        let c = colours[m];
        chart
            .draw_series(LineSeries::new(
                frames.iter().enumerate().map(|(f, fr)| (f as f64, fr.errors[m] * 100.0)),
                c.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label(names[m])
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    chart
        .draw_series(LineSeries::new(
            frames.iter().enumerate().map(|(f, fr)| (f as f64, fr.gt_noise * 100.0)),
            BLACK.stroke_width(1),
        ))
        .map_err(plot_err)?
        .label("ground truth's own noise (error plot); lighting change (flicker plot)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    let flick = flicker(frames);
    let f1 = flick
        .iter()
        .flat_map(|(v, floor)| v.iter().copied().chain([*floor]))
        .map(|e| e * 100.0)
        .filter(|e| e.is_finite())
        .fold(0.0, f64::max)
        * 1.15
        + 0.5;
    let mut chart = ChartBuilder::on(&bottom)
        .caption("Flicker: RMS change of the error image between frames", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.8..n - 0.8, 0.0..f1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_labels(frames.len())
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("frame (change from the previous)")
        .y_desc("flicker (% of mean)")
        .draw()
        .map_err(plot_err)?;
    for m in 0..3 {
        let c = colours[m];
        chart
            .draw_series(LineSeries::new(
                flick.iter().enumerate().map(|(f, (v, _))| ((f + 1) as f64, v[m] * 100.0)),
                c.stroke_width(2),
            ))
            .map_err(plot_err)?;
    }
    chart
        .draw_series(LineSeries::new(
            flick.iter().enumerate().map(|(f, (_, floor))| ((f + 1) as f64, floor * 100.0)),
            BLACK.stroke_width(1),
        ))
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// Per transition f-1 -> f: each method's flicker, and how much the ground truth itself changed
/// (RMS, over its mean): the real change of the lighting.
fn flicker(frames: &[Frame]) -> Vec<([f64; 3], f64)> {
    frames
        .windows(2)
        .map(|w| {
            let mean = 0.5 * (w[0].gt_mean + w[1].gt_mean);
            let rms = |a: &[f32], b: &[f32]| {
                (a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len().max(1) as f64)
                    .sqrt()
            };
            let v = [0, 1, 2].map(|m| {
                if mean > 0.0 {
                    rms(&w[1].residuals[m], &w[0].residuals[m]) / mean
                } else {
                    0.0
                }
            });
            let change = rms(&w[1].gt, &w[0].gt);
            (v, if mean > 0.0 { change / mean } else { 0.0 })
        })
        .collect()
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!("{cpu}, {} threads used", rayon::current_num_threads())
}

#[allow(clippy::too_many_arguments)]
fn markdown(
    a: &Args,
    b: &Budget,
    scene: &Scene,
    device: &str,
    gt_seconds: f64,
    gt_noise: f64,
    prod: (u32, u32, u32),
    prm: &[Point],
    with: &[Point],
    without: &[Point],
    direct_ms: f64,
    reference: &[Point],
    frames: &[Frame],
    plots: bool,
    total: f64,
) -> String {
    let mut s = String::new();
    let pct = |x: f64| format!("{:.2} %", x * 100.0);
    let _ = writeln!(s, "# Accuracy and cost: {}\n", a.scene.scene.display());
    let _ = writeln!(s, "Made by `{}` in {:.0} s.\n", std::env::args().collect::<Vec<_>>().join(" "), total);
    let _ = writeln!(s, "- Machine: {}", machine());
    let _ = writeln!(s, "- GPU device: {device}");
    let _ = writeln!(
        s,
        "- Level: {} triangles, {} lights; atlas {}²",
        scene.triangles.len(),
        scene.lights.len(),
        b.atlas
    );
    let _ = writeln!(
        s,
        "- Seeds: {} for every stage, every rig frame's ground truth included (common random numbers)",
        a.seed
    );
    let _ = writeln!(
        s,
        "- Error: DESIGN.md §3 normalised luminance RMSE of the indirect irradiance over \
        covered texels against `prm ground-truth` at {} spp ({:.1} s), whose own noise is **{}**: an error \
        figure includes it (remove it in quadrature for the method's own).\n",
        b.gt_spp,
        gt_seconds,
        pct(gt_noise)
    );
    let _ = writeln!(
        s,
        "Each figure can be re-made alone: `prm ground-truth SCENE --spp {} --seed {} -o \
        gt.exr`, `prm precompute SCENE --entries N --paths M --clusters C --seed {} -o s.prm`, `prm evaluate \
        SCENE --prm s.prm [--top-k K] -o e.exr` (CPU twin) or `prm render ... --lightmap-out` (GPU), `prm \
        bake-reference SCENE --vpls P --cluster-size K --indirect-only -o r.exr`, then `prm compare X.exr \
        gt.exr`.\n",
        b.gt_spp, a.seed, a.seed
    );
    let _ = writeln!(s, "## PRM: precompute budget (all panes, exact weights)\n");
    if plots {
        let _ = writeln!(s, "![error against precompute time](precompute.png)\n");
    }
    let _ = writeln!(
        s,
        "| entries N, paths M, clusters C | precompute | error | bias |\n| --- | --- | --- | --- |"
    );
    for p in prm {
        let _ =
            writeln!(s, "| {} | {:.2} s | {} | {:+.2} % |", p.label, p.seconds, pct(p.error), p.bias * 100.0);
    }
    let _ = writeln!(
        s,
        "\n## PRM: runtime budget (N={} M={} C={}, the level's lights)\n",
        prod.0, prod.1, prod.2
    );
    if plots {
        let _ = writeln!(s, "![error against frame time](runtime.png)\n");
    }
    if direct_ms.is_finite() {
        let _ = writeln!(
            s,
            "Frame: {} px wide, shadow maps 1024², median of {} frames each recomposing \
            (lights still, so shadow maps are not re-rendered). Direct-only frame: **{:.2} ms**.\n",
            b.frame_width, b.frame_reps, direct_ms
        );
    } else {
        let _ = writeln!(
            s,
            "No GPU adapter: times are the CPU twin's lightmap (ray-traced entry visibility, \
            weights, selection, compose).\n"
        );
    }
    let _ = writeln!(
        s,
        "| top-K | frame (ms) | error, + groups | bias | error, top-K alone | bias |\n| --- \
        | --- | --- | --- | --- | --- |"
    );
    for (p, q) in with.iter().zip(without) {
        let ratio = if direct_ms.is_finite() {
            format!(" ({:.2}x direct)", p.seconds * 1e3 / direct_ms)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "| {} | {:.2}{} | {} | {:+.2} % | {} | {:+.2} % |",
            p.label,
            p.seconds * 1e3,
            ratio,
            pct(p.error),
            p.bias * 100.0,
            pct(q.error),
            q.bias * 100.0
        );
    }
    let _ = writeln!(s, "\n## Reference baker (virtual polygon lights)\n");
    let _ = writeln!(s, "| photons, VPLs per light | bake | error | bias |\n| --- | --- | --- | --- |");
    for p in reference {
        let _ =
            writeln!(s, "| {} | {:.2} s | {} | {:+.2} % |", p.label, p.seconds, pct(p.error), p.bias * 100.0);
    }
    let _ = writeln!(
        s,
        "\n## Moving-light rig ({} frames{})\n",
        frames.len(),
        a.rig.as_ref().map_or(
            ", the level's first light sweeping across the middle 40 % of its width".to_string(),
            |r| format!(", {}", r.display())
        )
    );
    if plots {
        let _ = writeln!(s, "![error and flicker per frame](rig.png)\n");
    }
    let _ = writeln!(
        s,
        "Ground truth per frame at {} spp; reference at {} photons. Flicker: RMS over texels \
        of the change of the (signed luminance) error from the previous frame, over the mean ground truth. \
        Every frame's ground truth has the same seed, so its noise is largely common to consecutive frames \
        and cancels in the change; \"lighting change\" is how much the ground truth itself moved.\n",
        b.rig_gt_spp, b.rig_reference.0
    );
    let _ = writeln!(
        s,
        "| frame | GT noise | PRM top-32 | PRM all | reference | flicker top-32 | flicker \
        all | flicker reference | lighting change |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    let fl = flicker(frames);
    for (f, fr) in frames.iter().enumerate() {
        let flick = if f == 0 {
            "| - | - | - | - |".to_string()
        } else {
            let (v, floor) = fl[f - 1];
            format!("| {} | {} | {} | {} |", pct(v[0]), pct(v[1]), pct(v[2]), pct(floor))
        };
        let _ = writeln!(
            s,
            "| {f} | {} | {} | {} | {} {flick}",
            pct(fr.gt_noise),
            pct(fr.errors[0]),
            pct(fr.errors[1]),
            pct(fr.errors[2])
        );
    }
    s
}
