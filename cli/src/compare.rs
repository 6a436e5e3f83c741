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
    /// Also list the N texels with the largest squared error in luminance, each with its
    /// share of the whole, and how few texels hold half of it (with --texels, their positions
    /// and normals too): where the error is.
    #[arg(long, value_name = "N")]
    worst: Option<usize>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// One texel of `--worst`: where it is, both values and its share of the squared error.
#[derive(serde::Serialize)]
struct Worst {
    x: u32,
    y: u32,
    a: f32,
    b: f32,
    share: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    position: Option<[f32; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    normal: Option<[f32; 3]>,
}

/// The `n` texels (of `mask`) with the largest squared luminance error, largest first, and the
/// fewest texels that hold half the squared error. `at` gives a texel's position and normal.
fn worst_texels(
    (va, vb): (&[Vec3], &[Vec3]),
    mask: Option<&[bool]>,
    width: usize,
    n: usize,
    at: impl Fn(usize) -> Option<([f32; 3], [f32; 3])>,
) -> (Vec<Worst>, usize) {
    let mut sq: Vec<(f64, usize)> = (0..va.len())
        .filter(|&k| mask.is_none_or(|m| m[k]))
        .map(|k| (((prm::luminance(va[k]) - prm::luminance(vb[k])) as f64).powi(2), k))
        .filter(|(e, _)| e.is_finite())
        .collect();
    sq.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
    let total: f64 = sq.iter().map(|e| e.0).sum();
    let (mut run, mut half) = (0.0, 0);
    for (e, _) in &sq {
        if total > 0.0 && run >= 0.5 * total {
            break;
        }
        run += e;
        half += 1;
    }
    let rows = sq
        .iter()
        .take(n)
        .map(|&(e, k)| {
            let (position, normal) = at(k).map_or((None, None), |(p, n)| (Some(p), Some(n)));
            let (a, b) = (prm::luminance(va[k]), prm::luminance(vb[k]));
            let share = if total > 0.0 { e / total } else { 0.0 };
            Worst { x: (k % width) as u32, y: (k / width) as u32, a, b, share, position, normal }
        })
        .collect();
    (rows, half)
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
    let mut texel_set = None;
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
            let mask = ct.require(t, "mask")?.iter().map(|&m| m > 0.5).collect();
            texel_set = Some(ct);
            Some(mask)
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
    let at = |k: usize| {
        let ct = texel_set.as_ref()?;
        let get = |name: &str| ct.get(name).map(|v| v[k]);
        let xyz = |p: &str| Some([get(&format!("{p}.x"))?, get(&format!("{p}.y"))?, get(&format!("{p}.z"))?]);
        Some((xyz("P")?, xyz("N")?))
    };
    let worst = a.worst.map(|n| worst_texels((&va, &vb), mask.as_deref(), ca.width, n, at));
    if a.json {
        let mut v = serde_json::to_value(&c)?;
        v["a"] = a.a.display().to_string().into();
        v["b"] = a.b.display().to_string().into();
        v["layer_a"] = la.into();
        v["layer_b"] = lb.into();
        if let Some((rows, half)) = &worst {
            v["worst"] = serde_json::to_value(rows)?;
            v["texels_holding_half_the_squared_error"] = (*half).into();
        }
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
        if let Some((rows, half)) = &worst {
            println!("half the squared error lies in {half} of {} texels; the worst:", c.count);
            for w in rows {
                let place = match (w.position, w.normal) {
                    (Some(p), Some(n)) => format!(
                        "  at ({:.3}, {:.3}, {:.3}) facing ({:.2}, {:.2}, {:.2})",
                        p[0], p[1], p[2], n[0], n[1], n[2]
                    ),
                    _ => String::new(),
                };
                println!(
                    "  texel ({}, {}): {:.4e} against {:.4e}, {:.2} % of the squared error{place}",
                    w.x,
                    w.y,
                    w.a,
                    w.b,
                    100.0 * w.share
                );
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Two texels off, by 3 and 4 in luminance (grey), one masked out: the larger first, its
    /// share 16 / 25, half the squared error in one texel, and positions as `at` gives them.
    #[test]
    fn the_worst_texels_come_largest_first_with_their_shares() {
        let b = vec![Vec3::ONE; 6];
        let mut a = b.clone();
        a[1] += Vec3::splat(3.0);
        a[4] -= Vec3::splat(4.0);
        a[5] += Vec3::splat(9.0);
        let mask = [true, true, true, true, true, false];
        let at = |k: usize| Some(([k as f32, 0.0, 0.0], [0.0, 1.0, 0.0]));
        let (rows, half) = worst_texels((&a, &b), Some(&mask), 3, 2, at);
        assert_eq!(half, 1);
        assert_eq!(rows.iter().map(|w| (w.x, w.y)).collect::<Vec<_>>(), [(1, 1), (1, 0)]);
        assert!((rows[0].share - 16.0 / 25.0).abs() < 1e-6 && (rows[1].share - 9.0 / 25.0).abs() < 1e-6);
        assert_eq!(rows[0].position, Some([4.0, 0.0, 0.0]));
        assert!((rows[0].a - (-3.0)).abs() < 1e-5 && (rows[0].b - 1.0).abs() < 1e-5);
    }
}
