//! `prm compare`: the DESIGN.md §3 error of one EXR against a reference.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;
use prm::exr_io::Channels;
use prm::metric::compare;

#[derive(clap::Args)]
pub struct Args {
    /// The image or lightmap to judge.
    a: PathBuf,
    /// The reference (usually `prm ground-truth` output).
    b: PathBuf,
    /// Texel set whose mask selects the texels compared (default: B's `mask` channel if any,
    /// else every pixel).
    #[arg(long)]
    texels: Option<PathBuf>,
    /// Layer of A to read (default: `indirect` if present, else bare R G B).
    #[arg(long)]
    layer_a: Option<String>,
    /// Layer of B to read (default: `indirect` if present, else bare R G B).
    #[arg(long)]
    layer_b: Option<String>,
    /// Write a false-colour PNG of |Y_a - Y_b| / mean(Y_b) (blue 0, red >= 25 %).
    #[arg(long)]
    diff_png: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

fn rgb_layer(ch: &Channels, path: &Path, layer: Option<&str>) -> Result<(Vec<Vec3>, String)> {
    let pick = match layer {
        Some(l) => l.to_string(),
        None if ch.get("indirect.R").is_some() => "indirect".into(),
        None => String::new(),
    };
    let v = ch.rgb(&pick).ok_or_else(|| {
        anyhow!(
            "{}: no RGB layer '{}' (channels: {})",
            path.display(),
            pick,
            ch.channels.keys().cloned().collect::<Vec<_>>().join(" ")
        )
    })?;
    Ok((v, pick))
}

pub fn run(a: Args) -> Result<()> {
    let ca = Channels::read(&a.a).with_context(|| format!("reading {}", a.a.display()))?;
    let cb = Channels::read(&a.b).with_context(|| format!("reading {}", a.b.display()))?;
    if (ca.width, ca.height) != (cb.width, cb.height) {
        bail!(
            "{} is {}x{} but {} is {}x{}",
            a.a.display(),
            ca.width,
            ca.height,
            a.b.display(),
            cb.width,
            cb.height
        );
    }
    let (va, la) = rgb_layer(&ca, &a.a, a.layer_a.as_deref())?;
    let (vb, lb) = rgb_layer(&cb, &a.b, a.layer_b.as_deref())?;
    let mask: Option<Vec<bool>> = match &a.texels {
        Some(t) => {
            let ct = Channels::read(t).with_context(|| format!("reading {}", t.display()))?;
            if (ct.width, ct.height) != (cb.width, cb.height) {
                bail!(
                    "texel set {} is {}x{}, images are {}x{}",
                    t.display(),
                    ct.width,
                    ct.height,
                    cb.width,
                    cb.height
                );
            }
            Some(ct.require(t, "mask")?.iter().map(|&m| m > 0.5).collect())
        }
        None => cb.get("mask").map(|m| m.iter().map(|&v| v > 0.5).collect()),
    };
    let c = compare(&va, &vb, mask.as_deref());
    // A is judged (its non-finite texels are counted as errors); the reference must be sound.
    if c.reference_non_finite > 0 {
        let bad = c.reference_non_finite;
        bail!("the reference {} has {bad} non-finite texels (layer {lb}): it cannot judge", a.b.display());
    }
    if let Some(png) = &a.diff_png {
        write_diff_png(png, &va, &vb, mask.as_deref(), ca.width, ca.height)?;
    }
    if a.json {
        let mut v = serde_json::to_value(&c)?;
        v["a"] = a.a.display().to_string().into();
        v["b"] = a.b.display().to_string().into();
        v["layer_a"] = la.into();
        v["layer_b"] = lb.into();
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "error {:.2} % (R {:.2} G {:.2} B {:.2}), bias {:+.2} %, max |dY| {:.4e} ({:.1} % of mean), {} \
                compared, {} non-finite, {} negative",
            100.0 * c.error,
            100.0 * c.error_rgb[0],
            100.0 * c.error_rgb[1],
            100.0 * c.error_rgb[2],
            100.0 * c.bias,
            c.max_abs,
            100.0 * c.max_rel_to_mean,
            c.count,
            c.non_finite,
            c.negative
        );
    }
    Ok(())
}

fn write_diff_png(
    path: &Path,
    a: &[Vec3],
    b: &[Vec3],
    mask: Option<&[bool]>,
    w: usize,
    h: usize,
) -> Result<()> {
    let on = |k: usize| mask.is_none_or(|m| m[k]);
    let (sum, n) = (0..b.len())
        .filter(|&k| on(k))
        .fold((0.0f64, 0usize), |(s, n), k| (s + prm::luminance(b[k]) as f64, n + 1));
    let mean = (sum / n.max(1) as f64).max(1e-30) as f32;
    let mut img = image::RgbImage::new(w as u32, h as u32);
    for k in 0..a.len() {
        let px = if !on(k) {
            [0, 0, 0]
        } else {
            let ya = if a[k].is_finite() { prm::luminance(a[k]) } else { f32::INFINITY };
            let t = ((ya - prm::luminance(b[k])).abs() / mean / 0.25).clamp(0.0, 1.0);
            // Blue -> green -> red.
            let (r, g, bl) =
                if t < 0.5 { (0.0, 2.0 * t, 1.0 - 2.0 * t) } else { (2.0 * t - 1.0, 2.0 - 2.0 * t, 0.0) };
            [(r * 255.0) as u8, (g * 255.0) as u8, (bl * 255.0) as u8]
        };
        img.put_pixel((k % w) as u32, (k / w) as u32, image::Rgb(px));
    }
    let tmp = prm::fsutil::temp_path(path);
    img.save_with_format(&tmp, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", path.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
