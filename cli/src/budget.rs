//! `--gpu-budget`: fit a map and its shadow maps into a GPU memory budget for one camera
//! (`prm_runtime::budget`), saying what was left out.

use anyhow::{bail, Result};
use glam::Vec4Swizzles;
use prm::prm_file::Prm;
use prm::texels::TexelSet;
use prm::{Camera, Light, Scene};
use prm_runtime::budget::{fit, Fit, TilePlace};
use rayon::prelude::*;

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
/// high): its nearest covered texel's distance, and whether the camera sees any covered texel
/// of it (in the view frustum, facing the camera and not hidden: a ray to the eye). Tiles with
/// no covered texel are infinitely far and out of view.
pub fn tile_places(scene: &Scene, prm: &Prm, camera: &Camera, aspect: f32) -> Vec<TilePlace> {
    let (w, h) = prm.atlas();
    let grid = (prm.tiles_x() * prm.tiles_y()) as usize;
    let mut places = vec![TilePlace { distance: f32::INFINITY, in_view: false }; grid];
    let set = TexelSet::build(scene, w, h);
    let bvh = prm::Bvh::build(scene);
    let to_camera = camera.to_world.inverse();
    let eye = camera.to_world.col(3).xyz();
    let tan = (camera.yfov * 0.5).tan();
    let seen = |t: &prm::Texel| {
        let c = to_camera.transform_point3(t.position);
        let depth = -c.z;
        depth > 0.0
            && c.x.abs() <= depth * tan * aspect
            && c.y.abs() <= depth * tan
            && t.normal.dot(eye - t.position) > 0.0
            && bvh.visible_point(t.position, t.normal, eye)
    };
    let seen: Vec<bool> = set.texels.par_iter().map(seen).collect();
    let mut mark = |k: u32, distance: f32, seen: bool| {
        let place = &mut places[prm.atlas_tile_of(k)];
        place.distance = place.distance.min(distance);
        place.in_view |= seen;
    };
    for (t, &s) in set.texels.iter().zip(&seen) {
        mark(t.j * w + t.i, t.position.distance(eye), s);
    }
    // A dilated texel is read by bilinear lookups at its sources' chart edges: its tile is where
    // they are, and seen when they are.
    for d in &set.dilation {
        for &src in &d.sources[..d.count as usize] {
            let k = set.index[src as usize];
            if let Some(t) = set.texels.get(k as usize) {
                mark(d.target, t.position.distance(eye), seen[k as usize]);
            }
        }
    }
    places
}

/// What a budget did to a map: the figures `prm` prints and `prm info --json` gives.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Outcome {
    pub budget_bytes: u64,
    /// The whole map's tables and its shadow maps at the size asked for.
    pub before_bytes: u64,
    /// What the runtime now needs (at most the budget).
    pub after_bytes: u64,
    pub shadow_size_asked: u32,
    pub shadow_size: u32,
    /// Atlas tiles left out, of those that store texels.
    pub atlas_tiles_left_out: usize,
    pub atlas_tiles_stored: usize,
    pub texels_left_out: usize,
    /// The share of the panes' light in the tiles left out.
    pub energy_share_left_out: f64,
    /// Left-out tiles in the camera's view: a loss the viewer sees.
    pub in_view: usize,
    /// The nearest left-out tile's distance from the camera (m); none when nothing went.
    pub nearest_m: Option<f32>,
    /// The nearest left-out tile in view (m); none when none in view went.
    pub nearest_in_view_m: Option<f32>,
}

/// Fit `prm` for `lights` with the shadow maps `runtime` asks for (its size, a sun's tiles)
/// into `budget_mb` seen from `camera` (an image `aspect` wide over high): the map to run (the
/// whole one when it fits), and what was done.
pub fn fit_for_camera(
    scene: &Scene,
    prm: Prm,
    camera: &Camera,
    aspect: f32,
    lights: &[Light],
    runtime: &prm_runtime::RuntimeParams,
    budget_mb: f64,
) -> Result<(Prm, Outcome)> {
    let budget = budget_bytes(budget_mb)?;
    let places = tile_places(scene, &prm, camera, aspect);
    let shadow_size = runtime.shadow_size;
    let sun_tiles = prm_runtime::memory::sun_tiles(scene, runtime.sun_tiles);
    let f: Fit = fit(&prm, &places, lights, shadow_size, sun_tiles, budget)?;
    let mut outcome = Outcome {
        budget_bytes: budget,
        before_bytes: f.before,
        after_bytes: f.after,
        shadow_size_asked: shadow_size,
        shadow_size: f.shadow_size,
        atlas_tiles_left_out: 0,
        atlas_tiles_stored: prm.layout().texels.iter().filter(|t| !t.is_empty()).count(),
        texels_left_out: 0,
        energy_share_left_out: 0.0,
        in_view: f.in_view,
        nearest_m: None,
        nearest_in_view_m: f.nearest_in_view.is_finite().then_some(f.nearest_in_view),
    };
    let map = match f.reduced {
        Some(r) => {
            outcome.atlas_tiles_left_out = r.atlas_tiles;
            outcome.texels_left_out = r.texels;
            outcome.energy_share_left_out = r.energy_share;
            outcome.nearest_m = f.nearest.is_finite().then_some(f.nearest);
            r.prm
        }
        None => prm,
    };
    Ok((map, outcome))
}

/// The map a command runs under `--gpu-budget` (`budget_mb`; the whole map without one), seen
/// from `camera`: printing what was left out, and setting `params.shadow_size` to the size the
/// budget gives.
pub fn fit_params(
    budget_mb: Option<f64>,
    scene: &Scene,
    prm: Prm,
    camera: &Camera,
    aspect: f32,
    lights: &[Light],
    params: &mut prm_runtime::RuntimeParams,
) -> Result<Prm> {
    let Some(mb) = budget_mb else { return Ok(prm) };
    let (map, outcome) = fit_for_camera(scene, prm, camera, aspect, lights, params, mb)?;
    println!("{}", describe(&outcome));
    params.shadow_size = outcome.shadow_size;
    Ok(map)
}

/// One paragraph on a fit: the budget, what the whole map needed, what was left out.
pub fn describe(o: &Outcome) -> String {
    let mb = prm_runtime::budget::mb;
    let mut s = format!(
        "gpu budget  {:.1} MB: the whole map and its shadow maps need {:.1} MB",
        mb(o.budget_bytes),
        mb(o.before_bytes)
    );
    if o.atlas_tiles_left_out == 0 && o.shadow_size == o.shadow_size_asked {
        return s + "; everything fits";
    }
    if let Some(nearest) = o.nearest_m {
        s += &format!(
            "; left out {} of {} atlas tiles ({} texels, {:.1} % of the panes' light), {}, the nearest \
             {nearest:.1} m from the camera",
            o.atlas_tiles_left_out,
            o.atlas_tiles_stored,
            o.texels_left_out,
            100.0 * o.energy_share_left_out,
            match (o.in_view, o.nearest_in_view_m) {
                (0, _) | (_, None) => "none in the camera's view".to_string(),
                (n, Some(d)) => {
                    format!("{n} IN THE CAMERA'S VIEW (their indirect light is missing; the nearest {d:.1} m away)")
                }
            },
        );
    }
    if o.shadow_size != o.shadow_size_asked {
        s += &format!("; shadow maps at {}^2 instead of {}^2", o.shadow_size, o.shadow_size_asked);
    }
    s + &format!("; now {:.1} MB", mb(o.after_bytes))
}
