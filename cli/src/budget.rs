//! `--gpu-budget`: fit a map and its shadow maps into a GPU memory budget for one camera
//! (`prm_runtime::budget`), saying what was left out.

use anyhow::{bail, Result};
use glam::{Vec3, Vec4Swizzles};
use prm::prm_file::Prm;
use prm::texels::TexelSet;
use prm::{Camera, Light, Scene};
use prm_runtime::budget::{fit, Fit, TilePlace};

/// Largest budget accepted, MB: more than any GPU has.
const MAX_BUDGET_MB: f64 = 1e7;

/// Check a `--gpu-budget` in MB and give it in bytes.
pub fn budget_bytes(mb: f64) -> Result<u64> {
    if !(mb.is_finite() && mb > 0.0 && mb <= MAX_BUDGET_MB) {
        bail!("--gpu-budget {mb} is out of range: give megabytes (1e6 bytes), above 0 and at most {MAX_BUDGET_MB}");
    }
    Ok((mb * 1e6) as u64)
}

/// Where each atlas tile of `prm`'s grid is from `camera` (whose image is `aspect` wide over
/// high): its nearest covered texel's distance, and whether any covered texel lies in the view
/// frustum. Tiles with no covered texel are infinitely far and out of view.
pub fn tile_places(scene: &Scene, prm: &Prm, camera: &Camera, aspect: f32) -> Vec<TilePlace> {
    let (w, h) = prm.atlas();
    let ts = prm.header().tile_size;
    let tx = prm.tiles_x() as usize;
    let mut places = vec![TilePlace { distance: f32::INFINITY, in_view: false }; tx * prm.tiles_y() as usize];
    let set = TexelSet::build(scene, w, h);
    let to_camera = camera.to_world.inverse();
    let eye = camera.to_world.col(3).xyz();
    let tan = (camera.yfov * 0.5).tan();
    let in_view = |p: Vec3| {
        let c = to_camera.transform_point3(p);
        let depth = -c.z;
        depth > 0.0 && c.x.abs() <= depth * tan * aspect && c.y.abs() <= depth * tan
    };
    for t in &set.texels {
        let place = &mut places[(t.j / ts) as usize * tx + (t.i / ts) as usize];
        place.distance = place.distance.min(t.position.distance(eye));
        place.in_view |= in_view(t.position);
    }
    places
}

/// Fit `prm` for `lights` at `shadow_size` into `budget_mb` seen from `camera`, printing what
/// was left out; gives the map to run and the shadow-map size.
pub fn fit_map(
    scene: &Scene,
    prm: Prm,
    camera: &Camera,
    aspect: f32,
    lights: &[Light],
    shadow_size: u32,
    budget_mb: f64,
) -> Result<(Prm, u32)> {
    let budget = budget_bytes(budget_mb)?;
    let places = tile_places(scene, &prm, camera, aspect);
    let fitted = fit(&prm, &places, lights, shadow_size, budget)?;
    println!("{}", describe(&fitted, &prm, budget, shadow_size));
    Ok(match fitted.reduced {
        Some(r) => (r.prm, fitted.shadow_size),
        None => (prm, fitted.shadow_size),
    })
}

/// One paragraph on a fit: the budget, what the whole map needed, what was left out.
pub fn describe(f: &Fit, whole: &Prm, budget: u64, asked_shadow: u32) -> String {
    let mb = |b: u64| b as f64 / 1e6;
    let mut s = format!(
        "gpu budget  {:.1} MB: the whole map and its shadow maps need {:.1} MB",
        mb(budget),
        mb(f.before)
    );
    match &f.reduced {
        None if f.shadow_size == asked_shadow => s += "; everything fits",
        _ => {
            if let Some(r) = &f.reduced {
                let stored = whole.layout().texels.iter().filter(|t| !t.is_empty()).count();
                s += &format!(
                    "; left out {} of {} atlas tiles ({} texels, {:.1} % of the panes' light), {}, the \
                     nearest {:.1} m from the camera",
                    r.atlas_tiles,
                    stored,
                    r.texels,
                    100.0 * r.energy_share,
                    match f.in_view {
                        0 => "none in the camera's view".to_string(),
                        n => format!("{n} IN THE CAMERA'S VIEW (their indirect light is missing)"),
                    },
                    f.nearest
                );
            }
            if f.shadow_size != asked_shadow {
                s += &format!("; shadow maps at {}^2 instead of {asked_shadow}^2", f.shadow_size);
            }
            s += &format!("; now {:.1} MB", mb(f.after));
        }
    }
    s
}
