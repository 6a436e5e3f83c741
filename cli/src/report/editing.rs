//! The report's editing part (issue 14): a script of edits (`<level>_edits.json` beside the
//! level, in `prm bake --edits`' format) applied one after the other. Per edit:
//! - the incremental baker's error against the edited level's ground truth, against the time
//!   since the edit, as its updates go (the lightmap an engine would show at that moment);
//! - a full re-bake of the edited level with the same parameters (and the same energy per path
//!   and octree box, so it is the state the incremental baker converges to): until it is done
//!   the old lightmap is all there is, then its own error;
//! - the PRM: `--update` of the last map (its cache) against a full precompute of the edited
//!   level, both timed, both measured against the same ground truth (all panes, exact weights).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use prm::prm_file::Prm;
use prm::{Bvh, Light, Scene};
use prm_precompute::incremental::{Baker, BakerParams, Level as EditLevel};
use prm_precompute::precompute::{precompute_with, Baked, Held, PrecomputeError, PrecomputeParams, Reuse};
use prm_runtime::cpu::CpuTwin;

use super::measure::{compare, compare_texels, ground_truth, Level};
use crate::bake::{follow, parse_script, rebake, relative_rms, summed};

/// What the editing part spends.
pub struct EditBudget {
    /// Light paths of the incremental baker (and of each full re-bake).
    pub paths: usize,
    /// Ground truth of each edited level.
    pub gt_spp: u32,
}

impl EditBudget {
    pub fn new(quick: bool, smoke: bool) -> EditBudget {
        match (smoke, quick) {
            (true, _) => EditBudget { paths: 1_500, gt_spp: 16 },
            (false, true) => EditBudget { paths: 20_000, gt_spp: 256 },
            (false, false) => EditBudget { paths: 40_000, gt_spp: 1024 },
        }
    }
}

/// One edit's figures. Errors are DESIGN.md §3's, against the edited level's ground truth.
pub struct EditRow {
    pub label: String,
    pub vpls_changed: usize,
    pub gt_noise: f64,
    /// The lightmap before the edit, against the edited level.
    pub error_before: f64,
    /// (seconds since the edit, error) while the incremental baker updates.
    pub curve: Vec<(f64, f64)>,
    pub seconds_90: f64,
    /// When no invalid light was left, and the error then.
    pub seconds_valid: f64,
    pub error_valid: f64,
    /// When no update was left (consolidation included), and the error then.
    pub seconds_converged: f64,
    pub error_converged: f64,
    /// The largest error seen while updating.
    pub error_worst: f64,
    pub rebake_seconds: f64,
    pub rebake_error: f64,
    /// One fresh bake's own noise (two seeds' relative RMS distance over sqrt 2, direct +
    /// indirect), and when the updates first came within it of the fresh bake: issue 14's
    /// "converged" (NaN: never, which consolidation rules out).
    pub fresh_noise: f64,
    pub seconds_within_noise: f64,
    pub update: UpdateRow,
}

/// `prm precompute --update` against a full precompute of the edited level.
pub struct UpdateRow {
    pub seconds_update: f64,
    pub seconds_full: f64,
    /// The full precompute keeping its update cache (`--cache`: its walks traced), what an
    /// editing loop that goes on updating runs instead.
    pub seconds_full_cached: f64,
    /// Why the update could not reuse the last map (it then ran a full precompute, timed
    /// with the attempt), as `prm precompute --update` says.
    pub refused: Option<String>,
    pub tiles_hit: usize,
    pub tiles: usize,
    pub texels_walked: usize,
    pub error_update: f64,
    pub error_full: f64,
}

pub struct Editing {
    pub script: PathBuf,
    pub budget: EditBudget,
    /// The incremental baker's first bake of the level.
    pub bake_seconds: f64,
    /// The production precompute with `--cache`.
    pub precompute_seconds: f64,
    pub texels: usize,
    pub rows: Vec<EditRow>,
}

/// `set` on the edited `scene`: each texel where its triangle now puts it (its barycentrics
/// kept), the baker's own receiver frames (`incremental::level::receiver_frames`), as
/// a precompute of the edited level rasterises them (the lightmap UVs do not move). The ground
/// truth of an edited level was traced from the texels where they were: after the Cornell box's
/// red wall moved 5 cm in, its texels lay behind it, and every method came out 36-52 % from
/// that ground truth at every later edit.
fn carried(set: &prm::TexelSet, scene: &Scene) -> prm::TexelSet {
    let mut moved = set.clone();
    let frames = prm_precompute::incremental::level::receiver_frames(scene, set);
    for (t, (position, normal, _)) in moved.texels.iter_mut().zip(frames) {
        (t.position, t.normal) = (position, normal);
    }
    moved
}

/// `<level>_edits.json` beside `scene`, if there is one.
pub fn edits_beside(scene: &Path) -> Option<PathBuf> {
    let stem = scene.file_stem()?.to_str()?;
    let p = scene.with_file_name(format!("{stem}_edits.json"));
    p.exists().then_some(p)
}

/// Run the script on `level`: the incremental baker, full re-bakes and the PRM's updates.
pub fn editing(
    budget: EditBudget,
    level: &Level,
    script_path: &Path,
    prm: (u32, u32, u32),
    seed: u64,
) -> Result<Editing> {
    let script = parse_script(script_path, &level.scene)?;
    let texels = Arc::new(level.set.clone());
    // The baker lights emissive surfaces with polygon lights; the ground truth meets them
    // itself, so they are left out of its light list.
    let mut scene = level.scene.clone();
    let own = scene.lights.len() as u32;
    let glow = scene.emissive_lights();
    let glow_ids = own..own + glow.len() as u32;
    scene.lights.extend(glow);
    let params = BakerParams { paths: budget.paths, seed, ..BakerParams::default() };
    eprintln!("editing: incremental bake ({} paths)...", budget.paths);
    let t = Instant::now();
    let mut baker = Baker::new(scene.clone(), texels.clone(), params.clone())
        .map_err(|e| anyhow!("bad baker parameter: {e}"))?;
    baker.converge();
    let bake_seconds = t.elapsed().as_secs_f64();
    // The same edits on a level of its own, to know each edited level before the baker meets it.
    let mut shadow = EditLevel::new(scene, texels.clone());

    let (entries, paths, clusters) = prm;
    let pp = PrecomputeParams {
        entries,
        paths,
        clusters,
        atlas: prm::density::Atlas::single(level.set.width),
        seed,
        ..PrecomputeParams::production()
    };
    eprintln!("editing: precompute with --cache...");
    let t = Instant::now();
    let first = run_precompute(&level.scene, &level.bvh, &pp, Reuse::Nothing, true)?;
    let precompute_seconds = t.elapsed().as_secs_f64();
    let (mut map, mut cache) = (first.prm, first.cache.context("the precompute kept no cache")?);

    let mut rows = Vec::new();
    for (k, (label, edit)) in script.iter().enumerate() {
        eprintln!("editing: edit {} ({label})...", k + 1);
        shadow.apply(edit).with_context(|| format!("edit {} ({label})", k + 1))?;
        let v = shadow.current().clone();
        let gt_lights: Vec<Light> =
            v.lights.iter().filter(|s| !glow_ids.contains(&s.id)).map(|s| s.light.clone()).collect();
        let mut edited_scene = v.scene.as_ref().clone();
        edited_scene.lights = gt_lights.clone();
        let set = carried(&level.set, &edited_scene);
        let edited = Level { bvh: Bvh::build(&edited_scene), scene: edited_scene, set };
        let (gt, gt_noise) = ground_truth(&edited, &gt_lights, budget.gt_spp, seed)?;
        let error = |b: &Baker| compare_texels(&b.lightmap().1, &gt).0;
        let error_before = error(&baker);

        // The fresh re-bake an editor would start instead (the same energy per path, octree
        // box and ray offsets as the baker: the state the incremental one converges to), and
        // one of the next seed: their distance over sqrt 2 is one bake's own noise.
        let mut fresh_scene = v.scene.as_ref().clone();
        fresh_scene.lights = v.lights.iter().map(|s| s.light.clone()).collect();
        let (fresh, rebake_seconds) = rebake(&fresh_scene, &baker, &texels, &params, seed)?;
        let rebake_error = error(&fresh);
        let fresh_map = summed(&fresh);
        drop(fresh);
        let mean = fresh_map.iter().map(|x| x.length() as f64).sum::<f64>() / fresh_map.len().max(1) as f64;
        let next = summed(&rebake(&fresh_scene, &baker, &texels, &params, seed.wrapping_add(1))?.0);
        let fresh_noise = relative_rms(&fresh_map, &next, mean) / std::f64::consts::SQRT_2;

        let t = Instant::now();
        let r = baker.apply(edit).with_context(|| format!("edit {} ({label})", k + 1))?;
        // Applying an edit plans its updates; the lightmap is the one before it until the first.
        let curve_start = t.elapsed().as_secs_f64();
        let mut curve = vec![(0.0, error_before), (curve_start, error_before)];
        let mut error_valid = f64::NAN;
        let mut seconds_within_noise = f64::NAN;
        let f = follow(&mut baker, t, r.invalid_flux, |at, b, first_valid| {
            let e = error(b);
            if first_valid {
                error_valid = e;
            }
            if seconds_within_noise.is_nan() && relative_rms(&summed(b), &fresh_map, mean) <= fresh_noise {
                seconds_within_noise = at;
            }
            curve.push((at, e));
        });
        let error_converged = error(&baker);
        curve.push((f.seconds_converged, error_converged));
        if seconds_within_noise.is_nan() && relative_rms(&summed(&baker), &fresh_map, mean) <= fresh_noise {
            seconds_within_noise = f.seconds_converged;
        }
        let error_worst = curve.iter().map(|p| p.1).fold(0.0, f64::max);

        let t = Instant::now();
        let cancel = AtomicBool::new(false);
        let reuse = Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&map) };
        let (updated, refused) =
            match precompute_with(&edited.scene, &edited.bvh, &pp, reuse, true, &|_, _, _| {}, &cancel) {
                Ok(b) => (b, None),
                // As `prm precompute --update` does: say why, and bake it whole.
                Err(PrecomputeError::Refused(r)) => (
                    run_precompute(&edited.scene, &edited.bvh, &pp, Reuse::Nothing, true)?,
                    Some(r.to_string()),
                ),
                Err(e) => return Err(anyhow!("precompute: {e}")),
            };
        let seconds_update = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let full = run_precompute(&edited.scene, &edited.bvh, &pp, Reuse::Nothing, false)?;
        let seconds_full = t.elapsed().as_secs_f64();
        let t = Instant::now();
        run_precompute(&edited.scene, &edited.bvh, &pp, Reuse::Nothing, true)?;
        let seconds_full_cached = t.elapsed().as_secs_f64();
        let map_error = |m: &Prm| {
            let img = CpuTwin::new(m, &edited.bvh, usize::MAX).frame(&gt_lights).to_vec();
            compare(&edited.set, &img, &gt).0
        };
        let ts = pp.tile_size.max(1);
        let update = UpdateRow {
            seconds_update,
            seconds_full,
            seconds_full_cached,
            refused,
            tiles_hit: updated.report.update_tiles_hit,
            tiles: (pp.atlas.width().div_ceil(ts) * pp.atlas.height().div_ceil(ts)) as usize,
            texels_walked: updated.report.update_texels_walked,
            error_update: map_error(&updated.prm),
            error_full: map_error(&full.prm),
        };
        cache = updated.cache.context("the update kept no cache")?;
        map = updated.prm;

        rows.push(EditRow {
            label: label.clone(),
            vpls_changed: r.vpls_changed,
            gt_noise,
            error_before,
            curve,
            seconds_90: f.seconds_90,
            seconds_valid: f.seconds_valid.unwrap_or(f.seconds_converged),
            error_valid: if error_valid.is_nan() { error_converged } else { error_valid },
            seconds_converged: f.seconds_converged,
            error_converged,
            error_worst,
            rebake_seconds,
            rebake_error,
            fresh_noise,
            seconds_within_noise,
            update,
        });
    }
    Ok(Editing {
        script: script_path.to_path_buf(),
        budget,
        bake_seconds,
        precompute_seconds,
        texels: level.set.len(),
        rows,
    })
}

fn run_precompute(
    scene: &Scene,
    bvh: &Bvh,
    params: &PrecomputeParams,
    reuse: Reuse,
    keep_cache: bool,
) -> Result<Baked> {
    let cancel = AtomicBool::new(false);
    precompute_with(scene, bvh, params, reuse, keep_cache, &|_, _, _| {}, &cancel)
        .map_err(|e| anyhow!("precompute: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec2, Vec3};

    /// Two quads, the second moved 5 cm along x: its texels move with it, the first's stay,
    /// each on its triangle at its barycentrics.
    #[test]
    fn an_edited_level_s_texels_move_with_their_triangles() {
        let quad = |x: f32| {
            [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x, 0.0, 1.0),
                Vec3::new(x + 1.0, 0.0, 1.0),
                Vec3::new(x + 1.0, 0.0, 0.0),
            ]
        };
        let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
        for (k, q) in [quad(0.0), quad(2.0)].iter().enumerate() {
            let base = pos.len() as u32;
            for (c, p) in q.iter().enumerate() {
                pos.push(*p);
                let corner =
                    [Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)][c];
                uv.push(Vec2::new((k as f32 + 0.1 + 0.8 * corner.x) / 2.0, 0.1 + 0.8 * corner.y));
            }
            idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        }
        let scene = Scene::from_mesh(pos, uv, &idx);
        let set = prm::TexelSet::build(&scene, 32, 32);
        let mut edited = scene.clone();
        for p in edited.positions.iter_mut().skip(4) {
            p.x += 0.05;
        }
        let moved = carried(&set, &edited);
        assert_eq!(moved.texels.len(), set.texels.len());
        let (mut on_moved, mut still) = (0, 0);
        for (a, b) in set.texels.iter().zip(&moved.texels) {
            let shift = if a.triangle >= 2 { 0.05 } else { 0.0 };
            assert!((b.position - a.position - Vec3::new(shift, 0.0, 0.0)).length() < 1e-5, "{a:?} -> {b:?}");
            assert!((b.normal - a.normal).length() < 1e-6);
            assert_eq!((a.i, a.j, a.triangle, a.bary), (b.i, b.j, b.triangle, b.bary));
            if shift > 0.0 {
                on_moved += 1
            } else {
                still += 1
            }
        }
        assert!(on_moved > 50 && still > 50, "{on_moved} texels moved, {still} stayed");
    }
}
