//! `prm render`: frames of a level under a (moving) light rig, shaded with direct light and the
//! PRM's indirect lightmap, `L = emission + albedo / pi x (E_direct + E_indirect)`.
//!
//! - `--backend gpu` (default): the wgpu runtime (`prm_runtime::Runtime` + `Renderer`):
//!   shadow-mapped direct light, GPU compose. Without an adapter `prm` says so and uses the CPU.
//! - `--backend cpu`: the CPU twin's lightmap (`prm_runtime::cpu`), the frame by ray casting
//!   (first hit, shadow rays, bilinear indirect lookup).
//!
//! - `--mode cssm`: moving objects too (`crate::render_cssm`).
//!
//! Frames are EXR (linear radiance) and PNG (tone-mapped); `--lightmap-out` adds each frame's
//! indirect lightmap as EXR (R G B irradiance, W/m², atlas layout).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use glam::{Vec2, Vec3};
use prm::density::Atlas;
use prm::exr_io::Channels;
use prm::{Bvh, Camera, Scene};
use prm_runtime::cpu::CpuTwin;
use prm_runtime::{Gpu, Renderer, Runtime};
use rayon::prelude::*;

use crate::common::{load_rig, ComposeArgs, MapArgs};

#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum Backend {
    Cpu,
    Gpu,
}

/// What gives the indirect light.
#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum Mode {
    /// The precomputed radiance map (--prm): static geometry, moving lights.
    Prm,
    /// Hierarchical radiosity over precomputed visibility (--vis, `prm visibility`): the
    /// rig's objects move too (paper 003). Direct light at the texels and the radiosity run on
    /// either backend (GPU: from --shadow-size shadow maps); the shading on the CPU.
    Cssm,
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub(crate) scene: crate::common::SceneArgs,
    /// The level's .prm (--mode prm).
    #[arg(long)]
    pub(crate) prm: Option<PathBuf>,
    /// The level's visibility file (--mode cssm).
    #[arg(long)]
    pub(crate) vis: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "prm")]
    pub(crate) mode: Mode,
    #[command(flatten)]
    pub(crate) radiosity: crate::render_cssm::RadiosityArgs,
    /// Light rig (JSON); without one the level's glTF lights, unmoving.
    #[arg(long)]
    pub(crate) rig: Option<PathBuf>,
    /// Frames over the rig's duration.
    #[arg(long, default_value_t = 30)]
    pub(crate) frames: usize,
    /// glTF camera to render from (default: the first).
    #[arg(long)]
    pub(crate) camera: Option<String>,
    /// Image width in pixels (height from the camera's aspect).
    #[arg(long, default_value_t = 320)]
    pub(crate) width: u32,
    #[command(flatten)]
    pub(crate) compose: ComposeArgs,
    /// Shadow-map texels per side and layer (GPU backend).
    #[arg(long, default_value_t = 1024)]
    pub(crate) shadow_size: u32,
    /// gpu: the wgpu runtime (falls back to cpu, saying so, without an adapter).
    #[arg(long, value_enum, default_value = "gpu")]
    pub(crate) backend: Backend,
    /// Also write each frame's indirect lightmap as EXR.
    #[arg(long)]
    pub(crate) lightmap_out: bool,
    /// Output folder (created).
    #[arg(short, long)]
    pub(crate) output: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    if a.frames == 0 || a.frames > 100_000 {
        bail!("--frames {} is out of range (1 to 100000)", a.frames);
    }
    if a.width == 0 || a.width > 8192 {
        bail!("--width {} is out of range (1 to 8192)", a.width);
    }
    if a.mode == Mode::Cssm {
        return crate::render_cssm::run(a);
    }
    if a.vis.is_some() {
        bail!("--vis is for --mode cssm");
    }
    let Some(prm) = a.prm.clone() else { bail!("--mode prm needs the level's map: give --prm FILE") };
    let map = MapArgs { scene: a.scene.clone(), prm };
    let mut params = a.compose.runtime(a.shadow_size)?;
    let (scene, prm_file) = map.load()?;
    let rig = load_rig(a.rig.as_deref(), &scene)?;
    let cam = camera(&scene, a.camera.as_deref())?;
    let (iw, ih) = cam.image_size(a.width);
    let lights = rig.frame(0, a.frames);
    let prm_file = crate::budget::fit_params(
        a.compose.gpu_budget,
        &scene,
        prm_file,
        &cam,
        iw as f32 / ih as f32,
        &lights,
        &mut params,
    )?;
    let gpu = match a.backend {
        Backend::Cpu => None,
        Backend::Gpu => match Gpu::new() {
            Ok(g) => Some(g),
            Err(e) => {
                eprintln!("note: {e}\nnote: rendering with the CPU twin instead");
                None
            }
        },
    };
    let folder = crate::common::OutputFolder::create(&a.output)?;
    let out = Output {
        dir: &a.output,
        lightmap: a.lightmap_out.then_some(prm_file.header().atlas()),
        size: (iw as usize, ih as usize),
    };
    match gpu {
        Some(g) => {
            println!("device: {}", g.describe());
            let mut rt = Runtime::new(&g.device, &g.queue, &scene, &prm_file, params)?;
            let renderer = Renderer::new(&g.device, &g.queue, &scene, &rt, &cam, iw, ih)?;
            let mut total = 0.0;
            for f in 0..a.frames {
                let lights = rig.frame(f, a.frames);
                let t = Instant::now();
                let update = rt.update(&lights)?;
                renderer.draw(&rt, true, None);
                renderer.wait();
                let ms = t.elapsed().as_secs_f64() * 1e3;
                total += ms;
                let lightmap = if a.lightmap_out { Some(rt.read_lightmap()?) } else { None };
                out.write(f, &renderer.read_frame()?, lightmap.as_deref())?;
                println!(
                    "frame {f:4}: {ms:7.2} ms ({})",
                    if update.composed {
                        "lights changed: shadow maps, weights, compose, shading"
                    } else {
                        "lights unchanged: shading only"
                    }
                );
            }
            println!(
                "{} frames, {} composes, mean frame {:.2} ms on {} -> {}",
                a.frames,
                rt.composes(),
                total / a.frames as f64,
                g.info.name,
                a.output.display()
            );
        }
        None => {
            let bvh = Bvh::build(&scene);
            let mut twin = CpuTwin::new(&prm_file, &bvh, params.top_k);
            twin.set_residual(params.residual);
            twin.set_budget(params.budget);
            let atlas = prm_file.header().atlas();
            let mut totals = (0.0, 0.0);
            for f in 0..a.frames {
                let lights = rig.frame(f, a.frames);
                let t = Instant::now();
                let lightmap = twin.frame(&lights).to_vec();
                let compose_s = t.elapsed().as_secs_f64();
                let t = Instant::now();
                let img = shade(&scene, &bvh, &cam, &lights, &lightmap, atlas, out.size);
                let shade_s = t.elapsed().as_secs_f64();
                totals.0 += compose_s;
                totals.1 += shade_s;
                out.write(f, &img, Some(&lightmap).filter(|_| a.lightmap_out).map(|v| &v[..]))?;
                println!(
                    "frame {f:4}: lightmap {:7.2} ms ({} panes), shading {:7.2} ms",
                    compose_s * 1e3,
                    twin.last_selected,
                    shade_s * 1e3
                );
            }
            println!(
                "{} frames, {} composes: mean lightmap {:.2} ms, mean shading {:.2} ms (CPU twin, {} \
                    threads) -> {}",
                a.frames,
                twin.composes,
                totals.0 * 1e3 / a.frames as f64,
                totals.1 * 1e3 / a.frames as f64,
                rayon::current_num_threads(),
                a.output.display()
            );
        }
    }
    folder.keep();
    Ok(())
}

/// The named camera, or the level's first; a level without cameras is framed by
/// [`default_camera`], and a note says so.
pub fn camera(scene: &Scene, name: Option<&str>) -> Result<Camera> {
    match name {
        Some(n) => scene
            .cameras
            .iter()
            .find(|c| c.name == n)
            .cloned()
            .ok_or_else(|| anyhow!("no camera named '{n}'")),
        None => Ok(match scene.cameras.first() {
            Some(c) => c.clone(),
            None => {
                let c = default_camera(scene, &Bvh::build(scene));
                let eye = c.to_world.col(3).truncate();
                let look = -c.to_world.col(2).truncate();
                eprintln!(
                    "note: the level has no camera; viewing it from {:.2?} along {:.2?} (add a camera to \
                        the glTF to choose the view)",
                    eye.to_array(),
                    look.to_array()
                );
                c
            }
        }),
    }
}

/// A view of a level that has no camera: from its first positional light (inside a room, in
/// a level of rooms), or the middle of its bounds, looking level along whichever of 16
/// directions sees farthest before a surface (a miss counts as the level's diagonal), 16:9.
pub fn default_camera(scene: &Scene, bvh: &Bvh) -> Camera {
    let (lo, hi) = scene.bounds();
    let diag = scene.diagonal().max(1e-3);
    let eye = scene.lights.iter().find(|l| l.is_positional()).map_or(0.5 * (lo + hi), |l| l.position);
    let reach = |d: Vec3| bvh.closest_hit(eye, d, diag).map_or(diag, |h| h.t);
    let dirs = (0..16).map(|k| {
        let a = std::f32::consts::TAU * k as f32 / 16.0;
        Vec3::new(a.cos(), -0.15, a.sin()).normalize()
    });
    let look =
        dirs.fold((Vec3::Z, -1.0f32), |best, d| if reach(d) > best.1 { (d, reach(d)) } else { best }).0;
    let rotation = glam::Quat::from_array(prm::glb::look_rotation(look, Vec3::Y));
    Camera {
        name: "default".into(),
        to_world: glam::Mat4::from_rotation_translation(rotation, eye),
        yfov: 1.0,
        aspect: Some(16.0 / 9.0),
    }
}

pub(crate) struct Output<'a> {
    pub(crate) dir: &'a Path,
    pub(crate) lightmap: Option<Atlas>,
    pub(crate) size: (usize, usize),
}

impl Output<'_> {
    pub(crate) fn write(&self, f: usize, img: &[Vec3], lightmap: Option<&[Vec3]>) -> Result<()> {
        let (iw, ih) = self.size;
        let mut ch = Channels::new(iw, ih);
        ch.insert_rgb("", img);
        let stem = self.dir.join(format!("frame_{f:04}"));
        ch.write(&stem.with_extension("exr")).with_context(|| format!("writing {}", stem.display()))?;
        write_png(&stem.with_extension("png"), img, iw, ih)?;
        if let (Some(atlas), Some(lm)) = (self.lightmap, lightmap) {
            let (w, h) = (atlas.width() as usize, atlas.height() as usize);
            let mut ch = Channels::paged(w, h, atlas.pages as usize);
            ch.insert_rgb("", lm);
            let p = self.dir.join(format!("lightmap_{f:04}.exr"));
            ch.write(&p).with_context(|| format!("writing {}", p.display()))?;
        }
        Ok(())
    }
}

/// Bilinear lookup of a full-atlas image at lightmap UV `uv` (texel centres at (i+0.5)/W),
/// clamped to the page `uv` lies in, as the GPU's texture array reads it.
fn bilinear(img: &[Vec3], atlas: Atlas, uv: Vec2) -> Vec3 {
    let (w, side) = (atlas.width() as f32, atlas.side as f32);
    let page = (uv.y * atlas.pages as f32).floor().clamp(0.0, atlas.pages as f32 - 1.0);
    let x = uv.x * w - 0.5;
    let y = uv.y * atlas.height() as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (top, bottom) = (page * side, page * side + side - 1.0);
    let at =
        |i: f32, j: f32| img[j.clamp(top, bottom) as usize * w as usize + i.clamp(0.0, w - 1.0) as usize];
    let upper = at(x0, y0).lerp(at(x0 + 1.0, y0), fx);
    let lower = at(x0, y0 + 1.0).lerp(at(x0 + 1.0, y0 + 1.0), fx);
    upper.lerp(lower, fy)
}

pub(crate) fn shade(
    scene: &Scene,
    bvh: &Bvh,
    cam: &prm::Camera,
    lights: &[prm::Light],
    lightmap: &[Vec3],
    atlas: Atlas,
    (iw, ih): (usize, usize),
) -> Vec<Vec3> {
    (0..iw * ih)
        .into_par_iter()
        .map(|k| {
            let (i, j) = (k % iw, k / iw);
            let (origin, d) = cam.ray(i as f32 + 0.5, j as f32 + 0.5, iw as u32, ih as u32);
            let Some(hit) = bvh.closest_hit(origin, d, f32::INFINITY) else { return Vec3::ZERO };
            let t = hit.triangle as usize;
            let Some(n) = scene.facing_normal(t, d) else { return Vec3::ZERO };
            let m = scene.material(t);
            let b = hit.bary();
            let p = scene.point(t, b);
            let [u0, u1, u2] = scene.uv1_corners(t);
            let uv = u0 * b.x + u1 * b.y + u2 * b.z;
            let direct = prm::bvh::direct_irradiance(bvh, lights, p, n);
            let indirect = bilinear(lightmap, atlas, uv);
            m.emissive + scene.albedo(t, b) / std::f32::consts::PI * (direct + indirect)
        })
        .collect()
}

/// Tone-mapped sRGB PNG (exposure from the frame's mean luminance, Reinhard), written atomically.
pub fn write_png(path: &Path, img: &[Vec3], w: usize, h: usize) -> Result<()> {
    let mean = img.iter().map(|v| prm::luminance(*v) as f64).sum::<f64>() / img.len().max(1) as f64;
    let exposure = if mean > 0.0 { (0.18 / mean) as f32 } else { 1.0 };
    let enc = |c: f32| {
        let c = c * exposure;
        let c = c / (1.0 + c);
        let s = if c <= 0.0031308 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
        (s.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
    };
    let mut out = image::RgbImage::new(w as u32, h as u32);
    for (k, v) in img.iter().enumerate() {
        out.put_pixel((k % w) as u32, (k / w) as u32, image::Rgb([enc(v.x), enc(v.y), enc(v.z)]));
    }
    let tmp = prm::fsutil::temp_path(path);
    out.save_with_format(&tmp, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", path.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
