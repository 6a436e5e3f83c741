//! `prm export-panes`: the pane atlases of a `.prm` as EXR pages to look at, one pane per tile
//! of a page grid, or every pane as its own full-atlas image.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use glam::Vec3;
use prm::exr_io::Channels;
use prm::prm_file::Prm;

#[derive(clap::Args)]
pub struct Args {
    /// The .prm file.
    prm: PathBuf,
    /// Output folder (created).
    #[arg(short, long)]
    output: PathBuf,
    /// Panes per page side: a page holds side^2 panes at full atlas size.
    #[arg(long, default_value_t = 4)]
    grid: u32,
}

pub fn run(a: Args) -> Result<()> {
    if a.grid == 0 || a.grid > 64 {
        bail!("--grid {} is out of range (1 to 64)", a.grid);
    }
    let prm = Prm::read(&a.prm, None).with_context(|| "reading the radiance map failed")?;
    let folder = crate::common::OutputFolder::create(&a.output)?;
    let (w, h) = (prm.header().atlas_width as usize, prm.header().atlas_height as usize);
    let g = a.grid as usize;
    let layout = prm.layout();
    let per_page = g * g;
    let pages = prm.clusters().len().div_ceil(per_page);
    for page in 0..pages {
        let (pw, ph) = (w * g, h * g);
        let mut img = vec![Vec3::ZERO; pw * ph];
        for slot in 0..per_page {
            let c = page * per_page + slot;
            if c >= prm.clusters().len() {
                break;
            }
            let mut pane = vec![Vec3::ZERO; w * h];
            prm_runtime::cpu::add_pane(&prm, c, Vec3::ONE, &mut pane, &layout);
            let (ox, oy) = ((slot % g) * w, (slot / g) * h);
            for y in 0..h {
                img[(oy + y) * pw + ox..(oy + y) * pw + ox + w].copy_from_slice(&pane[y * w..(y + 1) * w]);
            }
        }
        let mut ch = Channels::new(pw, ph);
        ch.insert_rgb("", &img);
        let path = a.output.join(format!("panes_{page:03}.exr"));
        ch.write(&path).with_context(|| format!("writing {}", path.display()))?;
    }
    println!("{} panes in {} pages of {}x{} -> {}", prm.clusters().len(), pages, g, g, a.output.display());
    folder.keep();
    Ok(())
}
