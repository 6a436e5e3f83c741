//! `prm bake`: the incremental many-light baker (paper 001). Bakes the level, then applies a
//! script of edits one by one, each followed by updates until the lightmap has converged again,
//! and reports per edit how fast the invalid light went: the time to resolve 90 % of the
//! invalid flux, the time to converge, against the time of the full bake.
//!
//! Edit script (JSON, a list, applied in order):
//! `{"move": {"node": "carpet" | 4, "by": [x, y, z]}}`,
//! `{"rotate": {"node": ..., "degrees": a, "axis": [x, y, z], "about": [x, y, z]}}`,
//! `{"albedo": {"material": "red" | 1, "rgb": [r, g, b]}}`,
//! `{"light": {"id": 0, "position": [x, y, z], "intensity": [r, g, b]}}` (either field),
//! `{"add_light": {"position": [x, y, z], "intensity": [r, g, b]}}` (a point light),
//! `{"remove_light": {"id": 0}}`.
//! An entry may also name itself for the printout: `{"label": "crate 1 m east", "move": ...}`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use glam::{Mat4, Vec3};
use prm::exr_io::Channels;
use prm::{Bvh, Light, Scene, TexelSet};
use prm_precompute::incremental::{Baker, BakerParams, Edit};
use serde_json::Value;

use crate::common::{AtlasArgs, SceneArgs};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// Output EXR of the last state: bare R G B = direct + indirect, layers direct.*,
    /// indirect.*, and mask.
    #[arg(short, long)]
    output: PathBuf,
    /// Edit script to apply after the first bake (see `prm bake --help`'s module doc).
    #[arg(long)]
    edits: Option<PathBuf>,
    /// Light paths over all lights.
    #[arg(long, default_value_t = 40_000)]
    paths: usize,
    /// Bounces a light path makes at most (Russian roulette ends most before).
    #[arg(long, default_value_t = BakerParams::default().max_bounces)]
    max_bounces: u32,
    /// VPLs a cell of the octree cut holds at most.
    #[arg(long, default_value_t = 256)]
    leaf_vpls: usize,
    /// Balance the octree cut by paper 001's metric B for this many cells (instead of
    /// --leaf-vpls): more cells where more light lands close by, fewer elsewhere; after an
    /// edit, balancing updates are interleaved with the others by eq. (2).
    #[arg(long)]
    cells: Option<usize>,
    /// Changed VPLs a correction holds at most (corrections are clustered coarser than cells).
    #[arg(long, default_value_t = 4096)]
    delta_leaf_vpls: usize,
    /// A region whose changed VPLs carry more than this share of its power is baked again
    /// whole; below it, the changes go in as corrections (consolidated last).
    #[arg(long, default_value_t = BakerParams::default().rebuild_share)]
    rebuild_share: f32,
    /// Leave out consolidation: after an edit, stop once no invalid light is left (the
    /// lightmap then holds corrections; a fresh bake's clusters differ, within noise).
    #[arg(long)]
    no_consolidate: bool,
    /// Shadow rays per texel and virtual light.
    #[arg(long, default_value_t = BakerParams::default().visibility_samples)]
    visibility_samples: u32,
    /// Shadow rays per texel and virtual light of a correction (an edit's small changes).
    #[arg(long, default_value_t = BakerParams::default().delta_visibility_samples)]
    delta_visibility_samples: u32,
    /// Virtual lights a correction makes of its added VPLs, and as many of its removed ones.
    #[arg(long, default_value_t = BakerParams::default().delta_lights_per_cell)]
    delta_lights: usize,
    #[command(flatten)]
    lightmap: AtlasArgs,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Relative RMS distance to the converged lightmap taken as converged (the bake's own
    /// noise: compare two seeds' bakes to choose it).
    #[arg(long, default_value_t = 0.01)]
    tolerance: f64,
    /// After each edit, also bake the edited level afresh twice (this seed and the next, with
    /// the same energy per path and octree box) and report when the updates came within one
    /// fresh bake's own noise of the first (the two bakes' distance over sqrt 2): converged
    /// as a re-bake is, rather than to --tolerance of the updates' own end.
    #[arg(long)]
    fresh: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
    /// After the bake (and the script), watch the level file: when an editor writes it again,
    /// load it, diff it node by node against the last load, apply the edits and update until
    /// converged, writing the output each time. Stops with Ctrl-C (or after --watch-limit).
    #[arg(long)]
    watch: bool,
    /// Stop watching after this many reloads (scripts and tests).
    #[arg(long, requires = "watch")]
    watch_limit: Option<usize>,
    /// Seconds between looks at the level file's modification time (0.01 to 60).
    #[arg(long, default_value_t = 0.25, requires = "watch")]
    watch_interval: f64,
}

pub fn run(a: Args) -> Result<()> {
    if !(a.tolerance.is_finite() && a.tolerance >= 0.0) {
        bail!("--tolerance {} must be a finite distance, at least 0", a.tolerance);
    }
    if !(0.01..=60.0).contains(&a.watch_interval) {
        bail!("--watch-interval {} must be 0.01 to 60 seconds", a.watch_interval);
    }
    crate::common::check_output_file(
        &a.output,
        &[&a.scene.scene, a.edits.as_deref().unwrap_or(&a.scene.scene)],
    )?;
    let (mut scene, atlas) = a.lightmap.load(&a.scene, a.json)?;
    if atlas.pages > 1 {
        bail!("prm bake takes a one-page atlas (give --atlas)");
    }
    let script = match &a.edits {
        Some(p) => parse_script(p, &scene)?,
        None => Vec::new(),
    };
    // Emissive surfaces light the bake as polygon lights (the ground truth meets them itself).
    let glow = scene.emissive_lights();
    scene.lights.extend(glow);
    let params = BakerParams {
        paths: a.paths,
        leaf_vpls: a.leaf_vpls,
        max_bounces: a.max_bounces,
        cells: a.cells,
        delta_leaf_vpls: a.delta_leaf_vpls,
        rebuild_share: a.rebuild_share,
        consolidate: !a.no_consolidate,
        visibility_samples: a.visibility_samples,
        delta_visibility_samples: a.delta_visibility_samples,
        delta_lights_per_cell: a.delta_lights,
        seed: a.seed,
        ..BakerParams::default()
    };
    params.validate().map_err(|e| anyhow!("bad parameter: {e}"))?;
    let bvh = Bvh::build(&scene);
    crate::common::warn_spheres_in_geometry(&scene, &bvh);
    let set = Arc::new(TexelSet::build_visible(&scene, &bvh, atlas.width(), atlas.height()));
    let start = Instant::now();
    let mut baker =
        Baker::new(scene, set.clone(), params.clone()).map_err(|e| anyhow!("bad parameter: {e}"))?;
    let updates = baker.converge();
    let full = start.elapsed().as_secs_f64();
    let (cells, lights) = baker.counts();
    if !a.json {
        println!(
            "full bake: {full:.2} s, {updates} updates, {cells} cells, {lights} lights, {} texels",
            set.len()
        );
    }
    let mut rows = Vec::new();
    for (k, (label, edit)) in script.iter().enumerate() {
        let t = Instant::now();
        let r = baker.apply(edit).with_context(|| format!("edit {} ({label})", k + 1))?;
        let validate_s = t.elapsed().as_secs_f64();
        let invalid = r.invalid_flux;
        // Snapshots of the lightmap as it goes, for its distance to the converged one.
        let mut shots = vec![(validate_s, summed(&baker))];
        let mut valid: Option<(f64, Vec<Vec3>)> = None;
        let f = follow(&mut baker, t, invalid, |at, b, first_valid| {
            let x = summed(b);
            if first_valid {
                valid = Some((at, x.clone()));
            }
            shots.push((at, x));
        });
        let (steps, converge_s) = (f.steps, f.seconds_converged);
        let (kinds, kind_texels) = (f.kinds, f.kind_texels);
        let last = summed(&baker);
        let mean = last.iter().map(|x| x.length() as f64).sum::<f64>() / last.len().max(1) as f64;
        let dist = |x: &[Vec3]| relative_rms(x, &last, mean);
        let before = dist(&shots[0].1);
        let within = shots.iter().find(|(_, x)| dist(x) <= a.tolerance).map_or(converge_s, |(t, _)| *t);
        let worst = shots.iter().map(|(_, x)| dist(x)).fold(0.0, f64::max);
        let (valid_s, valid_d) = valid.as_ref().map_or((0.0, 0.0), |(t, x)| (*t, dist(x)));
        shots.push((converge_s, last.clone()));
        let fresh = if a.fresh { Some(fresh_noise(&baker, &set, &params, &shots, mean)?) } else { None };
        let row = serde_json::json!({
            "edit": label,
            "paths_changed": r.paths_changed,
            "paths": r.paths_total,
            "invalid_flux": invalid,
            "updates": steps,
            "seconds_validation": validate_s,
            "seconds_to_90_percent": f.seconds_90,
            "seconds_to_converge": converge_s,
            "distance_before": before,
            "distance_worst": worst,
            "seconds_within_tolerance": within,
            "share_of_full_bake": converge_s / full.max(1e-9),
            "vpls_changed": r.vpls_changed,
            "seconds_valid": valid_s,
            "distance_when_valid": valid_d,
            "updates_by_kind": {"rebuild": kinds[0], "delta": kinds[1], "refresh": kinds[2], "consolidate": kinds[3], "balance": kinds[4]},
            "seconds_by_kind": {"rebuild": f.kind_seconds[0], "delta": f.kind_seconds[1], "refresh": f.kind_seconds[2], "consolidate": f.kind_seconds[3], "balance": f.kind_seconds[4]},
            "texels_by_kind": {"rebuild": kind_texels[0], "delta": kind_texels[1], "refresh": kind_texels[2], "consolidate": kind_texels[3], "balance": kind_texels[4]},
            "fresh_noise": fresh.map(|f| f.noise),
            "seconds_within_fresh_noise": fresh.map(|f| f.seconds),
            "seconds_fresh_bake": fresh.map(|f| f.bake_seconds),
        });
        if !a.json {
            println!(
                "edit {}: {label}: {} of {} paths changed ({validate_s:.3} s), {steps} updates; 90 % of the \
                 invalid flux in {:.3} s; within {:.1} % of the converged lightmap in {within:.2} s = {:.0} % of \
                 the full bake (it was {:.1} % off before; never further: {:.1} %); no invalid light left after \
                 {valid_s:.2} s ({:.1} % off; {} rebuilds, {} corrections, {} refreshes); all updates, \
                 {} consolidations included, {converge_s:.2} s",
                k + 1,
                r.paths_changed,
                r.paths_total,
                f.seconds_90,
                100.0 * a.tolerance,
                100.0 * within / full.max(1e-9),
                100.0 * before,
                100.0 * worst,
                100.0 * valid_d,
                kinds[0],
                kinds[1],
                kinds[2],
                kinds[3]
            );
        }
        if let (Some(f), false) = (fresh, a.json) {
            println!(
                "  against a fresh bake of the edited level ({:.2} s): within its own noise ({:.1} %) after \
                 {:.2} s = {:.0} % of that bake",
                f.bake_seconds,
                100.0 * f.noise,
                f.seconds,
                100.0 * f.seconds / f.bake_seconds.max(1e-9)
            );
        }
        rows.push(row);
    }
    write_lightmap(&baker, &set, &a.output)?;
    if a.watch {
        watch(&a, &mut baker, &set)?;
    }
    if a.json {
        let summary = serde_json::json!({
            "scene": a.scene.scene.display().to_string(),
            "output": a.output.display().to_string(),
            "seconds_full_bake": full,
            "cells": cells,
            "virtual_lights": lights,
            "texels": set.len(),
            "edits": rows,
        });
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(())
}

/// How the updates after one edit went (times in seconds since the edit, the observer's own
/// time left out).
pub struct Followed {
    pub steps: usize,
    /// Until 90 % of the invalid flux the edit left was resolved.
    pub seconds_90: f64,
    /// Until no invalid light was left (consolidations aside).
    pub seconds_valid: Option<f64>,
    /// Until no update was left.
    pub seconds_converged: f64,
    /// Updates, their time and the texels they evaluated, by [`prm_precompute::incremental::UpdateKind`] (as `usize`).
    pub kinds: [usize; 5],
    pub kind_seconds: [f64; 5],
    pub kind_texels: [usize; 5],
}

/// The ratio of one look's time to the last's in [`follow`].
const LOOK_SPACING: f64 = 1.04;

/// Run `baker`'s updates after an edit applied at `since` that left `invalid` flux, until none
/// is left. `look(seconds, baker, first_valid)` sees the lightmap at times spaced about 4 %
/// apart (and 20 ms at least; a time read off the looks is late by up to as much), and once
/// more, with `first_valid`, when no invalid light is left for the first time; the time it
/// takes is not counted.
pub fn follow(
    baker: &mut Baker,
    since: Instant,
    invalid: f32,
    mut look: impl FnMut(f64, &Baker, bool),
) -> Followed {
    let mut f = Followed {
        steps: 0,
        seconds_90: f64::NAN,
        seconds_valid: None,
        seconds_converged: 0.0,
        kinds: [0; 5],
        kind_seconds: [0.0; 5],
        kind_texels: [0; 5],
    };
    let (mut resolved, mut busy) = (0.0f32, 0.0f64);
    let now = |busy: f64| since.elapsed().as_secs_f64() - busy;
    let mut next_look = now(busy) * LOOK_SPACING + 0.02;
    let mut last = Instant::now();
    while let Some(s) = baker.step() {
        let k = s.kind as usize;
        resolved += s.resolved;
        f.steps += 1;
        f.kinds[k] += 1;
        f.kind_seconds[k] += last.elapsed().as_secs_f64();
        f.kind_texels[k] += s.texels;
        let at = now(busy);
        if f.seconds_90.is_nan() && resolved >= 0.9 * invalid {
            f.seconds_90 = at;
        }
        let first_valid = f.seconds_valid.is_none() && baker.valid();
        if first_valid || at >= next_look {
            let c = Instant::now();
            if first_valid {
                f.seconds_valid = Some(at);
            }
            look(at, baker, first_valid);
            busy += c.elapsed().as_secs_f64();
            next_look = at * LOOK_SPACING + 0.02;
        }
        last = Instant::now();
    }
    f.seconds_converged = now(busy);
    if f.seconds_90.is_nan() {
        f.seconds_90 = f.seconds_converged;
    }
    f
}

fn write_lightmap(baker: &Baker, set: &TexelSet, output: &Path) -> Result<()> {
    // Light taken out leaves round-off where it was added (-1e-14 W/m² on the Cornell box once
    // its lamp has left the level), and a correction's removed polygons are not exactly the
    // cell's they correct: a lightmap holds no negative light.
    let clamp = |v: Vec<Vec3>| -> Vec<Vec3> { v.into_iter().map(|x| x.max(Vec3::ZERO)).collect() };
    let (direct, indirect) = baker.lightmap();
    let (direct, indirect) = (clamp(direct), clamp(indirect));
    let total: Vec<Vec3> = direct.iter().zip(&indirect).map(|(d, i)| *d + *i).collect();
    let mut ch = Channels::new(set.width as usize, set.height as usize);
    ch.insert_rgb("", &set.to_image(&total, Vec3::ZERO));
    ch.insert_rgb("direct", &set.to_image(&direct, Vec3::ZERO));
    ch.insert_rgb("indirect", &set.to_image(&indirect, Vec3::ZERO));
    ch.insert("mask", set.mask().iter().map(|&m| m as u8 as f32).collect());
    ch.write(output).with_context(|| format!("writing {}", output.display()))
}

/// `--watch`: follow the level file as an editor writes it. Updates run in slices of the poll
/// interval, so a new save is taken up while the last one is still converging (its remaining
/// updates are planned again with the new edits); the output is written whenever the lightmap
/// has converged.
fn watch(a: &Args, baker: &mut Baker, set: &TexelSet) -> Result<()> {
    use prm_precompute::incremental::diff::{diff, match_lights};
    let path = &a.scene.scene;
    let stamp = || std::fs::metadata(path).and_then(|m| m.modified()).ok();
    let (mut last, mut seen) = (baker.level().current().scene.as_ref().clone(), stamp());
    // Baker light ids, one per light of `last`, in order.
    let mut ids: Vec<u32> = baker.level().current().lights.iter().map(|l| l.id).collect();
    let interval = std::time::Duration::from_secs_f64(a.watch_interval);
    let (mut reloads, mut since, mut written) = (0, Instant::now(), true);
    eprintln!("watching {} (Ctrl-C stops)", path.display());
    loop {
        if baker.converged() {
            if !written {
                write_lightmap(baker, set, &a.output)?;
                println!(
                    "reload {reloads}: converged {:.2} s after the save; wrote {}",
                    since.elapsed().as_secs_f64(),
                    a.output.display()
                );
                written = true;
            }
            if a.watch_limit.is_some_and(|n| reloads >= n) {
                return Ok(());
            }
            std::thread::sleep(interval);
        } else {
            baker.run_for(interval);
        }
        let now = stamp();
        if now == seen {
            continue;
        }
        // An editor may still be writing: take the file once its time stamp holds still.
        std::thread::sleep(interval);
        if stamp() != now {
            continue;
        }
        seen = now;
        reloads += 1;
        since = Instant::now();
        let fresh = match a.lightmap.load(&a.scene, true) {
            Ok((mut s, _)) => {
                let glow = s.emissive_lights();
                s.lights.extend(glow);
                s
            }
            Err(e) => {
                eprintln!("reload {reloads}: the level does not load; kept the last state: {e:#}");
                continue;
            }
        };
        let edits = match diff(&last, &fresh, &ids) {
            Ok(e) => e,
            Err(e) => {
                eprintln!("reload {reloads}: cannot follow this change; kept the last state: {e}");
                continue;
            }
        };
        let (matched, _) = match_lights(&last.lights, &fresh.lights);
        let mut new_ids: Vec<Option<u32>> = matched.iter().map(|m| m.map(|i| ids[i])).collect();
        let mut refused = None;
        for e in &edits {
            match baker.apply(e) {
                Ok(r) => {
                    if let Edit::AddLight(_) = e {
                        if let (Some(slot), Some(id)) =
                            (new_ids.iter_mut().find(|x| x.is_none()), r.changes.lights.first())
                        {
                            *slot = Some(*id);
                        }
                    }
                }
                Err(err) => {
                    refused = Some(err);
                    break;
                }
            }
        }
        written = false;
        if let Some(err) = refused {
            // The edits before it are in; compare the next save with what the level now is.
            eprintln!("reload {reloads}: an edit was refused ({err}); the level follows the ones before it");
            let v = baker.level().current().clone();
            last = v.scene.as_ref().clone();
            last.lights = v.lights.iter().map(|l| l.light.clone()).collect();
            ids = v.lights.iter().map(|l| l.id).collect();
            continue;
        }
        println!("reload {reloads}: {} edits ({})", edits.len(), summary(&edits));
        ids = new_ids.into_iter().map(|x| x.unwrap_or(u32::MAX)).collect();
        last = fresh;
    }
}

/// "2 moves, 1 albedo" for a list of edits.
fn summary(edits: &[Edit]) -> String {
    let mut n = [0usize; 5];
    for e in edits {
        n[match e {
            Edit::Transform { .. } => 0,
            Edit::Albedo { .. } => 1,
            Edit::AddLight(_) => 2,
            Edit::RemoveLight { .. } => 3,
            Edit::SetLight { .. } => 4,
        }] += 1;
    }
    let names = ["node transforms", "albedos", "lights added", "lights removed", "lights changed"];
    let parts: Vec<String> =
        n.iter().zip(names).filter(|(k, _)| **k > 0).map(|(k, s)| format!("{k} {s}")).collect();
    if parts.is_empty() {
        "nothing changed".into()
    } else {
        parts.join(", ")
    }
}

/// How an edit's updates compare with a fresh bake of the edited level.
#[derive(Clone, Copy)]
struct Fresh {
    /// One fresh bake's own noise: two seeds' distance over sqrt 2 (relative, as `dist`).
    noise: f64,
    /// When a snapshot first came within that of the fresh bake of this seed.
    seconds: f64,
    /// The fresh bake's time.
    bake_seconds: f64,
}

/// Bake the baker's current level afresh with its seed and the next one (its frame and
/// extent, so that its updates converge to the first), and find the first of `shots` within
/// one bake's noise of the first. Distances are RMS over texels relative to `mean`.
fn fresh_noise(
    baker: &Baker,
    set: &Arc<TexelSet>,
    params: &BakerParams,
    shots: &[(f64, Vec<Vec3>)],
    mean: f64,
) -> Result<Fresh> {
    let v = baker.level().current();
    let mut scene = v.scene.as_ref().clone();
    scene.lights = v.lights.iter().map(|s| s.light.clone()).collect();
    let (f0, bake_seconds) = rebake(&scene, baker, set, params, params.seed)?;
    let f1 = rebake(&scene, baker, set, params, params.seed.wrapping_add(1))?.0;
    let (f0, f1) = (summed(&f0), summed(&f1));
    let noise = relative_rms(&f0, &f1, mean) / std::f64::consts::SQRT_2;
    let seconds =
        shots.iter().find(|(_, x)| relative_rms(x, &f0, mean) <= noise).map_or(f64::NAN, |(t, _)| *t);
    Ok(Fresh { noise, seconds, bake_seconds })
}

/// `scene` baked afresh with `like`'s frame and ray-offset extent (so that `like`'s updates,
/// once at `scene`, converge to it with the same seed) and `params` but for the seed, and
/// the time it took: the re-bake an editor would start instead.
pub fn rebake(
    scene: &Scene,
    like: &Baker,
    set: &Arc<TexelSet>,
    params: &BakerParams,
    seed: u64,
) -> Result<(Baker, f64)> {
    let t = Instant::now();
    let p = BakerParams { seed, ..params.clone() };
    let mut b = Baker::with_frame(scene.clone(), set.clone(), p, like.frame(), like.level().extent())
        .map_err(|e| anyhow!("bad baker parameter: {e}"))?;
    b.converge();
    Ok((b, t.elapsed().as_secs_f64()))
}

/// RMS over texels of `x - y`, over `mean`.
pub fn relative_rms(x: &[Vec3], y: &[Vec3], mean: f64) -> f64 {
    let sum: f64 = x.iter().zip(y).map(|(a, b)| (*a - *b).length_squared() as f64).sum();
    (sum / x.len().max(1) as f64).sqrt() / mean.max(1e-30)
}

/// The baker's lightmap, direct + indirect.
pub fn summed(b: &Baker) -> Vec<Vec3> {
    let (d, i) = b.lightmap();
    d.iter().zip(&i).map(|(a, b)| *a + *b).collect()
}

/// A light as an edit script leaves it.
#[derive(Clone)]
enum Tracked {
    Light(Light),
    /// An emissive surface's polygon light: it follows its node and material.
    Glow,
    Gone,
}

/// Read an edit script; nodes and materials may be named (glTF names) or numbered.
pub fn parse_script(path: &Path, scene: &Scene) -> Result<Vec<(String, Edit)>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: Value = serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    let list =
        v.as_array().ok_or_else(|| anyhow!("{}: the script is a JSON list of edits", path.display()))?;
    let names = &scene.node_names;
    // A move needs a node that places triangles itself (a group, a camera or a light places
    // none, and the baker would refuse it only after the level's first bake).
    let placed: std::collections::BTreeSet<u32> = scene.triangles.iter().map(|t| t.node).collect();
    // An index is a whole number that fits (4294967296 is not node 0).
    let index = |x: &Value, what: &str| -> Result<u32> {
        x.as_u64().and_then(|n| u32::try_from(n).ok()).ok_or_else(|| anyhow!("{what} {x} is not an index"))
    };
    let node = |x: &Value| -> Result<u32> {
        match x {
            Value::Number(_) => match index(x, "node")? {
                n if placed.contains(&n) => Ok(n),
                n if (n as usize) < names.len() => bail!("node {n} places no triangles"),
                n => bail!("no node {n}: the level has {}", names.len()),
            },
            Value::String(s) => {
                let named: Vec<u32> = (0..names.len() as u32).filter(|&i| names[i as usize] == *s).collect();
                match named.iter().find(|i| placed.contains(i)) {
                    Some(&i) => Ok(i),
                    None if named.is_empty() => bail!("no node named {s:?}"),
                    None => bail!("node {s:?} places no triangles (a group, camera or light node)"),
                }
            }
            _ => bail!("a node is a name or an index"),
        }
    };
    let material = |x: &Value| -> Result<u32> {
        match x {
            Value::Number(_) => match index(x, "material")? {
                m if (m as usize) < scene.materials.len() => Ok(m),
                m => bail!("no material {m}: the level has {}", scene.materials.len()),
            },
            Value::String(s) => scene
                .materials
                .iter()
                .position(|m| m.name == *s)
                .map(|i| i as u32)
                .ok_or_else(|| anyhow!("no material named {s:?}")),
            _ => bail!("a material is a name or an index"),
        }
    };
    // Three numbers, each finite once stored as f32 (1e39 is not).
    let vec3 = |x: Option<&Value>, what: &str| -> Result<Vec3> {
        let a = x.and_then(Value::as_array).ok_or_else(|| anyhow!("{what}: expected [x, y, z]"))?;
        let f: Vec<Option<f32>> = a.iter().map(|v| v.as_f64().map(|f| f as f32)).collect();
        match f[..] {
            [Some(x), Some(y), Some(z)] if Vec3::new(x, y, z).is_finite() => Ok(Vec3::new(x, y, z)),
            [Some(_), Some(_), Some(_)] => {
                bail!("{what}: {} is not finite as a 32-bit float", Value::Array(a.clone()))
            }
            _ => bail!("{what}: expected three numbers, got {}", Value::Array(a.clone())),
        }
    };
    // The lights as the script leaves them, by baker id: the level's in order, its emissive
    // surfaces' polygons, then those the script adds (the baker numbers them so; an id is
    // never given again). A `light` edit changes the light as the edits before it left it.
    // An emissive surface's light follows its node and material, which the script does not
    // track here: it is edited through them.
    let glow = scene.emissive_lights().len();
    let mut lights: Vec<Tracked> = scene.lights.iter().cloned().map(Tracked::Light).collect();
    lights.extend((0..glow).map(|_| Tracked::Glow));
    let mut out = Vec::new();
    for (k, e) in list.iter().enumerate() {
        let mut one = || -> Result<(String, Edit)> {
            let obj = e.as_object().ok_or_else(|| anyhow!("an edit is a JSON object"))?;
            let named = obj.get("label").map(|l| l.as_str().ok_or_else(|| anyhow!("label is text")));
            let named = named.transpose()?;
            let mut kinds = obj.iter().filter(|(key, _)| *key != "label");
            let (kind, body) = match (kinds.next(), kinds.next()) {
                (Some(one), None) => one,
                _ => bail!("one edit per entry (and an optional label)"),
            };
            let at = |f: &str| body.get(f);
            let need = |f: &str| at(f).ok_or_else(|| anyhow!("{kind} needs {f}"));
            let label = named.map_or_else(|| format!("{kind} {body}"), str::to_string);
            let id_of = |lights: &[Tracked]| -> Result<u32> {
                let id = index(need("id")?, "light")?;
                match lights.get(id as usize) {
                    Some(Tracked::Gone) => bail!("light {id} was removed by an earlier edit"),
                    Some(_) => Ok(id),
                    None => bail!(
                        "no light {id} (the level has {} and {glow} emissive surfaces, the script adds {})",
                        scene.lights.len(),
                        lights.len() - scene.lights.len() - glow
                    ),
                }
            };
            let edit = match kind.as_str() {
                "move" => Edit::Transform {
                    node: node(need("node")?)?,
                    matrix: Mat4::from_translation(vec3(at("by"), "by")?),
                },
                "rotate" => {
                    let about = vec3(at("about"), "about")?;
                    let axis =
                        vec3(at("axis"), "axis")?.try_normalize().ok_or_else(|| anyhow!("axis is zero"))?;
                    let deg = need("degrees")?
                        .as_f64()
                        .filter(|d| (*d as f32).is_finite())
                        .ok_or_else(|| anyhow!("degrees must be a finite number"))?;
                    Edit::Transform {
                        node: node(need("node")?)?,
                        matrix: Mat4::from_translation(about)
                            * Mat4::from_axis_angle(axis, (deg as f32).to_radians())
                            * Mat4::from_translation(-about),
                    }
                }
                "albedo" => {
                    let albedo = vec3(at("rgb"), "rgb")?;
                    if !(albedo.min_element() >= 0.0 && albedo.max_element() <= 1.0) {
                        bail!("rgb {albedo} is outside [0, 1]");
                    }
                    Edit::Albedo { material: material(need("material")?)?, albedo }
                }
                "light" => {
                    let id = id_of(&lights)?;
                    let Tracked::Light(mut l) = lights[id as usize].clone() else {
                        bail!("light {id} is an emissive surface's: move its node or change its material")
                    };
                    if at("position").is_some() {
                        l.position = vec3(at("position"), "position")?;
                    }
                    if at("intensity").is_some() {
                        l.intensity = vec3(at("intensity"), "intensity")?;
                    }
                    l.check().map_err(|what| anyhow!("light {id}: {what}"))?;
                    lights[id as usize] = Tracked::Light(l.clone());
                    Edit::SetLight { id, light: l }
                }
                "add_light" => {
                    let l = Light::point(
                        "added",
                        vec3(at("position"), "position")?,
                        vec3(at("intensity"), "intensity")?,
                    );
                    l.check().map_err(|what| anyhow!("the added light: {what}"))?;
                    lights.push(Tracked::Light(l.clone()));
                    Edit::AddLight(l)
                }
                "remove_light" => {
                    let id = id_of(&lights)?;
                    lights[id as usize] = Tracked::Gone;
                    Edit::RemoveLight { id }
                }
                other => bail!("unknown edit {other:?}"),
            };
            Ok((label, edit))
        };
        out.push(one().map_err(|e| anyhow!("{}: edit {}: {e}", path.display(), k + 1))?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `script` parsed against the bundled Cornell box (one light, id 0).
    fn parsed(script: &str) -> Result<Vec<(String, Edit)>> {
        let level = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell.glb");
        let opts = prm::gltf_load::LoadOptions { unwrap_resolution: Some(32), ..Default::default() };
        let scene = prm::gltf_load::load_scene(&level, &opts)?;
        let dir = std::env::temp_dir().join(format!("prm-script-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        // One file per script: the tests run side by side.
        let mut h = std::collections::hash_map::DefaultHasher::new();
        std::hash::Hash::hash(script, &mut h);
        let path = dir.join(format!("{:016x}.json", std::hash::Hasher::finish(&h)));
        std::fs::write(&path, script)?;
        let r = parse_script(&path, &scene);
        std::fs::remove_file(&path)?;
        r
    }

    #[test]
    fn a_light_edit_changes_the_light_the_edits_before_it_left() {
        let edits = parsed(
            r#"[{"light": {"id": 0, "intensity": [0.5, 0.25, 0.125]}},
                {"light": {"id": 0, "position": [0.1, 0.2, 0.3]}},
                {"add_light": {"position": [0, 0.5, 0], "intensity": [1, 1, 1]}},
                {"light": {"id": 1, "position": [0, 0.4, 0]}}]"#,
        )
        .unwrap();
        let Edit::SetLight { id: 0, light } = &edits[1].1 else { panic!("{:?}", edits[1]) };
        // The second edit keeps the first's intensity (it used to start from the file's).
        assert_eq!(light.intensity, Vec3::new(0.5, 0.25, 0.125));
        assert_eq!(light.position, Vec3::new(0.1, 0.2, 0.3));
        // The added light is light 1, and can be edited.
        let Edit::SetLight { id: 1, light } = &edits[3].1 else { panic!("{:?}", edits[3]) };
        assert_eq!((light.position, light.intensity), (Vec3::new(0.0, 0.4, 0.0), Vec3::ONE));
    }

    #[test]
    fn a_bad_edit_is_refused_by_its_number_and_what_is_wrong() {
        for (script, says) in [
            // Numbers that are not numbers, or do not fit, are not dropped or wrapped.
            (r#"[{"move": {"node": "red", "by": [0.05, "x", 0]}}]"#, "edit 1: by: expected three numbers"),
            (r#"[{"move": {"node": 4294967296, "by": [1, 0, 0]}}]"#, "node 4294967296 is not an index"),
            (r#"[{"albedo": {"material": 4294967297, "rgb": [1, 0, 0]}}]"#, "is not an index"),
            (r#"[{"remove_light": {"id": 4294967296}}]"#, "light 4294967296 is not an index"),
            (r#"[{"light": {"id": 0, "position": [1e39, 0, 0]}}]"#, "not finite as a 32-bit float"),
            (
                r#"[{"rotate": {"node": "red", "about": [0,0,0], "axis": [0,1,0], "degrees": 1e39}}]"#,
                "finite",
            ),
            (
                r#"[{"remove_light": {"id": 0}}, {"light": {"id": 0, "position": [0, 0, 0]}}]"#,
                "edit 2: light 0 was removed",
            ),
            (r#"[{"light": {"id": 7, "position": [0, 0, 0]}}]"#, "no light 7"),
            // Found before the level's first bake, not after it.
            (r#"[{"move": {"node": 999, "by": [1, 0, 0]}}]"#, "no node 999"),
            (r#"[{"albedo": {"material": 99, "rgb": [1, 0, 0]}}]"#, "no material 99"),
            (r#"[{"albedo": {"material": 0, "rgb": [2, 0, 0]}}]"#, "outside [0, 1]"),
            (r#"[{"light": {"id": 0, "intensity": [2e9, 0, 0]}}]"#, "light 0: intensity"),
            (
                r#"[{"add_light": {"position": [0, 0, 0], "intensity": [-1, 0, 0]}}]"#,
                "the added light: intensity",
            ),
            (r#"[{"light": {"id": -1}}]"#, "light -1 is not an index"),
            (
                r#"[{"move": {"node": "red", "by": [1, 0]}}, {"teleport": {}}]"#,
                "edit 1: by: expected three numbers",
            ),
            (r#"[{"move": {"by": [1, 0, 0]}}]"#, "edit 1: move needs node"),
            (r#"[{"albedo": {"material": 0, "rgb": [1, 0, 0]}}, {"teleport": {}}]"#, "edit 2: unknown edit"),
        ] {
            let err = format!("{:#}", parsed(script).unwrap_err());
            assert!(err.contains(says), "{script}: {err}");
        }
    }
}
