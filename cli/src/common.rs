//! Arguments and helpers shared by subcommands.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use prm::{load_scene, LoadOptions, Scene};

/// How to read the level.
#[derive(clap::Args, Clone, Debug)]
pub struct SceneArgs {
    /// The level: glTF 2.0, .gltf or .glb.
    pub scene: PathBuf,
    /// Fail when a primitive has no TEXCOORD_1 instead of generating lightmap UVs.
    #[arg(long)]
    pub require_uv1: bool,
    /// Accept overlapping lightmap UVs (surfaces then share texels, and lighting).
    #[arg(long)]
    pub allow_overlap: bool,
}

/// Largest accepted atlas side: 16384^2 texels is already a 4 GiB texel set.
pub const MAX_ATLAS: u32 = 16384;

/// Check an atlas size given on the command line.
pub fn check_atlas(atlas: u32) -> Result<()> {
    if atlas == 0 || atlas > MAX_ATLAS {
        bail!("--atlas {atlas} is out of range: use 1 to {MAX_ATLAS}");
    }
    Ok(())
}

/// Load the level, printing what the loader had to fix or generate.
pub fn load(args: &SceneArgs, atlas: u32, quiet: bool) -> Result<Scene> {
    let opts = LoadOptions {
        require_uv1: args.require_uv1,
        allow_overlap: args.allow_overlap,
        unwrap_resolution: atlas.clamp(16, 4096),
    };
    let scene = load_scene(&args.scene, &opts).with_context(|| "loading the level failed")?;
    if !quiet {
        for note in &scene.report.notes {
            eprintln!("note: {note}");
        }
        if scene.report.degenerate_dropped > 0 {
            eprintln!("note: {} zero-area triangle(s) dropped", scene.report.degenerate_dropped);
        }
    }
    Ok(scene)
}
