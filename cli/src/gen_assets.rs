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
}

pub fn run(a: Args) -> Result<()> {
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
