//! `prm report`: how right each method is and what it costs, on one level, in one run.
//!
//! Every error is DESIGN.md §3's normalised luminance RMSE of the indirect irradiance over the
//! covered texels, against `prm ground-truth` computed in the same run (its own noise is given
//! beside it). The report sweeps:
//! - the PRM's precompute budget (entries, paths, clusters): error of all panes with exact
//!   (ray-traced) weights against precompute time;
//! - its runtime budget (top-K picked locally, the default, and over the whole map with and
//!   without the groups standing in for the left-out clusters): error of the runtime's lightmap against frame time, on the GPU when an adapter
//!   exists (else the CPU twin, said so);
//! - the reference baker (photons, hence VPLs, and VPLs per virtual light);
//! - a moving-light rig: per frame, the error of PRM top-32, PRM all panes and the reference,
//!   and their flicker: the RMS change of the error image from one frame to the next, over the
//!   mean ground truth. Every frame's ground truth uses the same seed (common random numbers),
//!   so its noise changes little between frames and the flicker is mostly the method's own;
//! - on a level with movable objects and an objects rig, the moving-objects part (`moving`):
//!   hierarchical radiosity over precomputed visibility against the PRM baked at rest;
//! - light placements from a torch rig, and an edit script (see `editing`): the incremental
//!   baker's error against the time since each edit, beside a full re-bake, and the PRM's
//!   `--update` against a full precompute.
//!
//! Output: `report.md` (machine, device, seeds, the command, every figure) and PNG plots made
//! with `plotters` (labels need a TrueType font: DejaVu, Liberation or Noto, as Debian's
//! `fonts-dejavu-core` installs).

mod editing;
mod markdown;
mod measure;
mod moving;
mod placement;
mod plots;
mod rig;
mod scale;
mod sweeps;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use prm::rig::Rig;
use prm_runtime::Gpu;

use crate::common::{load, SceneArgs};
use measure::{ground_truth, Level};
use rig::{default_rig, rig_frames, Frame};
use scale::ScaleBudget;
use sweeps::{precompute_sweep, reference_sweep, runtime_sweep, Point, RuntimeSweep};

#[derive(clap::Args)]
pub struct Args {
    /// The level: glTF 2.0, .gltf or .glb (optional with --scale, which then reports only the
    /// scale section).
    #[arg(required_unless_present = "scale")]
    scene: Option<PathBuf>,
    /// Fail when a primitive has no TEXCOORD_1 instead of generating lightmap UVs.
    #[arg(long)]
    require_uv1: bool,
    /// Accept overlapping lightmap UVs (surfaces then share texels, and lighting).
    #[arg(long)]
    allow_overlap: bool,
    /// Add the scale section: the bundled large level's halls at 1, 4 and 16 halls, each
    /// precomputed with the default preset (its own process), with precompute time, peak
    /// memory, file size, GPU memory, error and frame times against the level's size.
    #[arg(long)]
    scale: bool,
    /// Light rig for the moving-light part (default: the level's first light moving across
    /// the middle 40 % of the level's width).
    #[arg(long)]
    rig: Option<PathBuf>,
    /// Torch rig for the light placement part (default: `<level>_torches.json` beside the
    /// level; without one the part is left out).
    #[arg(long)]
    torches: Option<PathBuf>,
    /// Edit script for the editing part, in `prm bake --edits`' format (default:
    /// `<level>_edits.json` beside the level; without one the part is left out).
    #[arg(long)]
    edits: Option<PathBuf>,
    /// Objects rig for the moving-objects part (default: `<level>_rig.json` beside the level
    /// when it moves objects; the part runs only on a level with movable nodes).
    #[arg(long)]
    objects_rig: Option<PathBuf>,
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
    /// Heights of the light placement sweep (scene units above the surface).
    placement_heights: Vec<f32>,
    frame_width: u32,
    frame_reps: usize,
    /// Atlas side of the moving-objects part.
    moving_atlas: u32,
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
                placement_heights: vec![0.02, 0.5],
                frame_width: 32,
                frame_reps: 2,
                moving_atlas: 32,
            };
        }
        let mut b = Budget {
            atlas: 256,
            gt_spp: 1024,
            rig_gt_spp: 128,
            rig_frames: 6,
            prm: vec![(1024, 32, 64), (2048, 64, 128), (4096, 64, 256), (4096, 128, 256), (4096, 256, 256)],
            production: 2,
            top_k: vec![8, 16, 32, 64, 128, usize::MAX],
            reference: vec![(10_000, 64), (20_000, 64), (40_000, 64)],
            rig_reference: (10_000, 64),
            placement_heights: vec![0.02, 0.15, 0.5, 2.0],
            frame_width: 640,
            frame_reps: 9,
            moving_atlas: moving::ATLAS,
        };
        if !quick {
            b.gt_spp = 2048;
            b.rig_gt_spp = 512;
            b.rig_frames = 12;
            b.prm.push((8192, 256, 512));
            b.reference.extend([(80_000, 64), (40_000, 32)]);
            b.rig_reference = (40_000, 64);
            b.placement_heights = vec![0.02, 0.05, 0.15, 0.5, 1.0, 2.0];
        }
        b
    }
}

/// Every figure of the report.
struct Figures {
    gt_seconds: f64,
    gt_noise: f64,
    /// The production precompute budget (entries, paths, clusters).
    prod: (u32, u32, u32),
    prm: Vec<Point>,
    runtime: RuntimeSweep,
    reference: Vec<Point>,
    frames: Vec<Frame>,
    /// The production configuration's map (the rig and the placements use it).
    map: prm::prm_file::Prm,
    /// The torch rig used for the light placement section, and its placements.
    torches: Option<PathBuf>,
    placements: Vec<placement::Placement>,
    /// The editing part, when there is an edit script.
    editing: Option<editing::Editing>,
    /// The moving-objects part, on a level with movables and an objects rig.
    moving: Option<moving::Moving>,
}

pub fn run(a: Args) -> Result<()> {
    let b = Budget::new(a.quick, a.smoke);
    let start = Instant::now();
    let folder = crate::common::OutputFolder::create(&a.output)?;
    let gpu = Gpu::new().ok();
    let level = match &a.scene {
        Some(path) => Some(level_parts(&a, &b, path, gpu.as_ref())?),
        None => None,
    };
    let scale = match a.scale {
        true => Some(scale::scale_rows(
            &ScaleBudget::new(a.quick, a.smoke),
            &a.output.join("scale"),
            gpu.as_ref(),
            a.seed,
        )?),
        false => None,
    };
    let plots = plots::write_plots(&a.output, level.as_ref().map(|l| &l.1), scale.as_deref(), gpu.is_some())?;
    let md = markdown::markdown(
        &a,
        &b,
        level.as_ref().map(|(l, f)| (&l.scene, f)),
        scale.as_deref(),
        &device(gpu.as_ref()),
        plots,
        start.elapsed().as_secs_f64(),
    );
    prm::fsutil::write_bytes_atomic(&a.output.join("report.md"), md.as_bytes())
        .with_context(|| "writing report.md")?;
    println!("report -> {} ({:.0} s)", a.output.join("report.md").display(), start.elapsed().as_secs_f64());
    folder.keep();
    Ok(())
}

/// The GPU adapter the runtime figures come from, or why there is none.
fn device(gpu: Option<&Gpu>) -> String {
    gpu.map_or("none found: runtime figures from the CPU twin (ray-traced visibility)".to_string(), |g| {
        g.describe()
    })
}

/// Every part about the given level: the sweeps, the rig and the light placements.
fn level_parts(a: &Args, b: &Budget, path: &std::path::Path, gpu: Option<&Gpu>) -> Result<(Level, Figures)> {
    let args =
        SceneArgs { scene: path.to_path_buf(), require_uv1: a.require_uv1, allow_overlap: a.allow_overlap };
    let scene = load(&args, b.atlas, true)?;
    let rig = match &a.rig {
        Some(p) => Rig::load(p, &scene.lights)?,
        None => default_rig(&scene)?,
    };
    let level = Level::new(scene, b.atlas)?;
    let torches = a.torches.clone().or_else(|| placement::torch_rig_beside(path));
    let torch_rig = match &torches {
        Some(p) => Some(Rig::load(p, &level.scene.lights)?),
        None => None,
    };
    // The edit script and the objects rig are read before the sweeps: a bad one found after
    // them cost the whole run.
    let script = a.edits.clone().or_else(|| editing::edits_beside(path));
    if let Some(s) = &script {
        crate::bake::parse_script(s, &level.scene)?;
    }
    let objects = a.objects_rig.clone().or_else(|| moving::objects_rig_beside(path));
    if let Some(r) = &objects {
        Rig::load(r, &level.scene.lights)?;
    }
    let mut figures = measure(b, &level, &rig, gpu, a.seed)?;
    if let (Some(path), Some(r)) = (&torches, &torch_rig) {
        figures.placements = placement::placements(b, &level, r, &figures.map, gpu, a.seed)?;
        figures.torches = Some(path.clone());
    }
    if let Some(r) = objects {
        figures.moving = moving::moving(b, &args, &r, gpu, a.seed)?;
    }
    if let Some(script) = script {
        let budget = editing::EditBudget::new(a.quick, a.smoke);
        figures.editing = Some(editing::editing(budget, &level, &script, figures.prod, a.seed)?);
    }
    Ok((level, figures))
}

/// The ground truth, the three sweeps and the rig, in that order.
fn measure(b: &Budget, level: &Level, rig: &Rig, gpu: Option<&Gpu>, seed: u64) -> Result<Figures> {
    eprintln!("ground truth ({} spp)...", b.gt_spp);
    let t = Instant::now();
    let (gt, gt_noise) = ground_truth(level, &level.scene.lights, b.gt_spp, seed)?;
    let gt_seconds = t.elapsed().as_secs_f64();
    let (prm, map) = precompute_sweep(b, level, &gt, seed)?;
    eprintln!("runtime top-K sweep...");
    let runtime = runtime_sweep(b, level, &map, &gt, gpu)?;
    let reference = reference_sweep(b, level, &gt, seed)?;
    let frames = rig_frames(b, level, rig, &map, gpu, seed)?;
    Ok(Figures {
        gt_seconds,
        gt_noise,
        prod: b.prm[b.production],
        prm,
        runtime,
        reference,
        frames,
        map,
        torches: None,
        placements: Vec::new(),
        editing: None,
        moving: None,
    })
}
