//! `prm evaluate`: the indirect lightmap a `.prm` gives for the level's lights (or a rig frame),
//! on the CPU twin of the runtime: exact weights (entry irradiance ray-traced) and every pane by
//! default, or the top K. What the precompute alone achieves, before the runtime's shadow maps.

use std::path::PathBuf;

use anyhow::{Context, Result};
use prm::exr_io::Channels;
use prm::{Bvh, TexelSet};

use crate::common::{BudgetArg, MapArgs, RigArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    map: MapArgs,
    #[command(flatten)]
    rig: RigArgs,
    /// Compose only the K strongest panes (default: all).
    #[arg(long)]
    top_k: Option<usize>,
    /// With --top-k: where it applies, local (picked at each vertex of the atlas tile grid) or
    /// one list for the whole map.
    #[arg(long, value_enum, default_value_t = BudgetArg::Local)]
    budget: BudgetArg,
    /// With --top-k: drop the left-out clusters' light instead of composing their groups' panes.
    #[arg(long)]
    no_residual: bool,
    /// Output EXR: bare R G B and indirect.* = indirect irradiance (W/m²), mask.
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    if a.top_k == Some(0) {
        anyhow::bail!("--top-k must be at least 1 (leave it out for every pane)");
    }
    crate::common::check_output_file(
        &a.output,
        &[&a.map.scene.scene, &a.map.prm, a.rig.rig.as_deref().unwrap_or(&a.map.prm)],
    )?;
    let (scene, bytes_prm) = a.map.load()?;
    let bvh = Bvh::build_with_rooms(&scene);
    let lights = a.rig.lights(&scene)?;
    let mut twin = prm_runtime::cpu::CpuTwin::new(&bytes_prm, &bvh, a.top_k.unwrap_or(usize::MAX));
    twin.set_residual(!a.no_residual);
    twin.set_budget(a.budget.into());
    let set = TexelSet::build_visible(
        &scene,
        &bvh,
        bytes_prm.header().atlas_width,
        bytes_prm.header().atlas_height,
    );
    let img = twin.frame(&lights).to_vec();
    let (w, h) = (set.width as usize, set.height as usize);
    let mut ch = Channels::paged(w, h, bytes_prm.header().atlas().pages as usize);
    ch.insert_rgb("", &img);
    ch.insert_rgb("indirect", &img);
    ch.insert("mask", set.mask().iter().map(|&m| m as u8 as f32).collect());
    ch.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    println!(
        "{} lights, {} of {} clusters composed -> {}",
        lights.len(),
        twin.last_selected,
        bytes_prm.clusters().len(),
        a.output.display()
    );
    Ok(())
}
