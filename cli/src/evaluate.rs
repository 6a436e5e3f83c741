//! `prm evaluate`: the indirect lightmap a `.prm` gives for the level's lights, on the CPU, with
//! exact weights (entry irradiance ray-traced) and every pane. What the precompute alone
//! achieves, before the runtime's shadow maps and top-K.

use std::path::PathBuf;

use anyhow::{Context, Result};
use prm::exr_io::Channels;
use prm::prm_file::Prm;
use prm::{Bvh, TexelSet};

use crate::common::{load, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// The level's .prm.
    #[arg(long)]
    prm: PathBuf,
    /// Output EXR: bare R G B and indirect.* = indirect irradiance (W/m²), mask.
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let bytes_prm = Prm::read(&a.prm, None).with_context(|| "reading the radiance map failed")?;
    let scene = load(&a.scene, bytes_prm.header.atlas_width, false)?;
    bytes_prm.check_scene(&a.prm, &scene)?;
    let bvh = Bvh::build(&scene);
    let img = prm_precompute::relight::indirect_lightmap(&bytes_prm, &bvh, &scene.lights);
    let set = TexelSet::build(&scene, bytes_prm.header.atlas_width, bytes_prm.header.atlas_height);
    let (w, h) = (set.width as usize, set.height as usize);
    let mut ch = Channels::new(w, h);
    ch.insert_rgb("", &img);
    ch.insert_rgb("indirect", &img);
    ch.insert("mask", set.mask().iter().map(|&m| m as u8 as f32).collect());
    ch.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    println!("{} lights, {} clusters -> {}", scene.lights.len(), bytes_prm.clusters.len(), a.output.display());
    Ok(())
}
