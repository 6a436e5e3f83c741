//! `prm visibility`: precompute a level's visibility for moving objects (paper 003 §3): a CSSM
//! per object and occluder maps per movable, into a checksummed `.vis` file.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use prm_precompute::parallel::Control;
use prm_precompute::visibility::{build_visibility, moving_texel_set, VisibilityParams};

use crate::common::{cancel_flag, progress_bar, AtlasArgs, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    atlas: AtlasArgs,
    /// Pixels per side of each cube face of the surface shadow maps.
    #[arg(long, default_value_t = VisibilityParams::default().res)]
    res: u32,
    /// Directions per cube face side of each movable's occluder maps.
    #[arg(long, default_value_t = VisibilityParams::default().occluder_dirs)]
    occluder_dirs: u32,
    /// Pixels per side of each occluder map.
    #[arg(long, default_value_t = VisibilityParams::default().occluder_res)]
    occluder_res: u32,
    /// Output .vis file.
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let params =
        VisibilityParams { res: a.res, occluder_dirs: a.occluder_dirs, occluder_res: a.occluder_res };
    params.validate().map_err(|e| anyhow::anyhow!("bad parameter: {e}"))?;
    crate::common::check_output_file(&a.output, &[&a.scene.scene])?;
    let (scene, atlas) = a.atlas.load(&a.scene, false)?;
    if atlas.pages != 1 {
        bail!(
            "the level needs {} lightmap pages; visibility works on one page for now (give --atlas)",
            atlas.pages
        );
    }
    let t0 = Instant::now();
    let texels = moving_texel_set(&scene, atlas.width(), atlas.height());
    let bar = progress_bar(texels.len() as u64, "cube maps");
    let progress = |done: usize| bar.set_position(done as u64);
    let control = Control { progress: &progress, cancel: cancel_flag() };
    let vis = build_visibility(&scene, &texels, &params, control).context("stopped")?;
    bar.finish_and_clear();
    let seconds = t0.elapsed().as_secs_f64();
    let bytes =
        prm::visibility::write_visibility(&a.output, &vis, prm::fingerprint::geometry_fingerprint(&scene))?;
    let cube_maps: usize = vis.objects.iter().map(|o| o.cssm.len()).sum();
    let runs: usize = vis.objects.iter().map(|o| o.cssm.runs()).sum();
    let occluders: usize = vis.objects.iter().filter_map(|o| o.occluder.as_ref()).map(|c| c.bytes()).sum();
    println!(
        "{} objects ({} movable), {cube_maps} cube maps of 6 x {}², {runs} depth runs; CSSM {:.1} MB \
         ({:.1} MB uncompressed, {:.1} : 1), occluder maps {:.1} MB; file {:.1} MB; {seconds:.1} s ({} threads) -> {}",
        vis.objects.len(),
        scene.movables.len(),
        params.res,
        (vis.bytes() - occluders) as f64 / 1e6,
        vis.uncompressed_bytes() as f64 / 1e6,
        vis.uncompressed_bytes() as f64 / (vis.bytes() - occluders).max(1) as f64,
        occluders as f64 / 1e6,
        bytes as f64 / 1e6,
        rayon::current_num_threads(),
        a.output.display()
    );
    Ok(())
}
