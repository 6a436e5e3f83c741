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
}

pub fn run(a: Args) -> Result<()> {
    if let Some(grid) = &a.halls {
        let parsed =
            grid.split_once('x').and_then(|(x, z)| Some((x.parse::<u32>().ok()?, z.parse::<u32>().ok()?)));
        let (nx, nz) = match parsed {
            Some((nx, nz)) if (1..=16).contains(&nx) && (1..=16).contains(&nz) => (nx, nz),
            _ => bail!("--halls {grid}: give NXxNZ with each 1 to 16, e.g. 2x2"),
        };
        let bytes = prm_precompute::scenes::halls(nx, nz, 32, 8).to_glb();
        let path = a.output.join(format!("halls_{nx}x{nz}.glb"));
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
