//! `prm gen-assets`: (re)write the bundled scenes, or check the committed ones are current.

use std::path::PathBuf;

use anyhow::{anyhow, bail, Context, Result};

#[derive(clap::Args)]
pub struct Args {
    /// Folder to write into.
    #[arg(short, long, default_value = "assets")]
    output: PathBuf,
    /// Compare with the files there instead of writing; fail if any differs.
    #[arg(long)]
    check: bool,
    /// Write only a grid of NX x NZ halls (like the bundled 4x4 halls.glb), as halls_NXxNZ.glb:
    /// levels of any size for scale measurements.
    #[arg(long, value_name = "NXxNZ", conflicts_with = "check")]
    halls: Option<String>,
    /// Write only NX x NZ copies of the bundled chamber side by side, without lightmap UVs, as
    /// chambers_NXxNZ.glb (issue 13's scale target: 16 chambers).
    #[arg(long, value_name = "NXxNZ", conflicts_with_all = ["check", "halls"])]
    chambers: Option<String>,
    /// Write only NX x NZ copies of the bundled sunroom under its one sun, without lightmap
    /// UVs, as sunrooms_NXxNZ.glb (a sunlit level wider than one shadow map resolves).
    #[arg(long, value_name = "NXxNZ", conflicts_with_all = ["check", "halls", "chambers"])]
    sunrooms: Option<String>,
}

/// `NXxNZ` with each 1 to 16.
fn grid(flag: &str, grid: &str) -> Result<(u32, u32)> {
    let parsed =
        grid.split_once('x').and_then(|(x, z)| Some((x.parse::<u32>().ok()?, z.parse::<u32>().ok()?)));
    match parsed {
        Some((nx, nz)) if (1..=16).contains(&nx) && (1..=16).contains(&nz) => Ok((nx, nz)),
        _ => bail!("--{flag} {grid}: give NXxNZ with each 1 to 16, e.g. 2x2"),
    }
}

pub fn run(a: Args) -> Result<()> {
    let one = match (&a.halls, &a.chambers, &a.sunrooms) {
        (Some(g), _, _) => {
            let (nx, nz) = grid("halls", g)?;
            Some((prm_precompute::scenes::halls(nx, nz, 32, 8), format!("halls_{nx}x{nz}.glb")))
        }
        (None, Some(g), _) => {
            let (nx, nz) = grid("chambers", g)?;
            let scene = prm_precompute::scenes::chambers(nx, nz).map_err(|e| anyhow!("generating: {e}"))?;
            Some((scene, format!("chambers_{nx}x{nz}.glb")))
        }
        (None, None, Some(g)) => {
            let (nx, nz) = grid("sunrooms", g)?;
            let scene = prm_precompute::scenes::sunrooms(nx, nz).map_err(|e| anyhow!("generating: {e}"))?;
            Some((scene, format!("sunrooms_{nx}x{nz}.glb")))
        }
        (None, None, None) => None,
    };
    if !a.check {
        std::fs::create_dir_all(&a.output)
            .with_context(|| format!("making the folder {}", a.output.display()))?;
    }
    if let Some((scene, name)) = one {
        let bytes = scene.to_glb();
        let path = a.output.join(name);
        prm::fsutil::write_bytes_atomic(&path, &bytes)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {} ({} bytes)", path.display(), bytes.len());
        return Ok(());
    }
    let mut stale = Vec::new();
    for (name, make) in prm_precompute::scenes::all() {
        let bytes = make().map_err(|e| anyhow!("generating {name}: {e}"))?.to_glb();
        let path = a.output.join(name);
        if a.check {
            let on_disk = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
            if on_disk != bytes {
                stale.push(name);
            }
            continue;
        }
        prm::fsutil::write_bytes_atomic(&path, &bytes)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {} ({} bytes)", path.display(), bytes.len());
    }
    if !stale.is_empty() {
        bail!("out of date with the generator: {} (run `prm gen-assets`)", stale.join(", "));
    }
    if a.check {
        println!("assets match the generator");
    }
    Ok(())
}
