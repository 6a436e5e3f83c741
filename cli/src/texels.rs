//! `prm texels`: the exit-point texel set as EXR.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use prm::exr_io::texel_channels;
use prm::TexelSet;

use crate::common::{check_atlas, load, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// Atlas width and height in texels.
    #[arg(long, default_value_t = 256)]
    atlas: u32,
    /// Output EXR.
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    check_atlas(a.atlas)?;
    crate::common::check_output_file(&a.output, &[&a.scene.scene])?;
    let scene = load(&a.scene, a.atlas, false)?;
    let start = Instant::now();
    let set = TexelSet::build_visible(&scene, &prm::Bvh::build(&scene), a.atlas, a.atlas);
    let built = start.elapsed();
    texel_channels(&set).write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    println!(
        "{}: {} of {}x{} texels covered ({:.1} %), {} dilated, {} buried points moved, {} buried texels dropped, built in {:.3} s -> {}",
        a.scene.scene.display(),
        set.len(),
        a.atlas,
        a.atlas,
        100.0 * set.len() as f64 / (a.atlas as f64 * a.atlas as f64),
        set.dilation.len(),
        set.buried.moved,
        set.buried.dropped,
        built.as_secs_f64(),
        a.output.display()
    );
    Ok(())
}
