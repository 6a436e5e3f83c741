//! `prm precompute`: a level becomes a precomputed radiance map (DESIGN.md §4, paper 004).
//!
//! Phases: texel set -> entry points (those inside solids moved out, or left out) and their
//! cells -> clustering -> far field, near and echo links -> light transport (the panes'
//! contents, `transport`, leaving the links' first bounce to them) and pane atlases
//! (geometry-guided smoothing, the links' first bounce added back exactly, dilation, tiles,
//! `panes`), the two together a band of tile rows at a time so that only a band's walks are
//! ever held -> the drop rule and the file's parts. Every random stream is seeded from (seed,
//! purpose, index), so the result is the same bytes at any thread count and any band height.

use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use prm::density::Atlas;
use prm::prm_file::{Entry, Header, InvalidPrm, Prm, PrmParts};
use prm::{Bvh, Scene};
use serde::Serialize;

use crate::cluster::Clustering;
use crate::far::EnergySum;
use crate::panes::{assemble, Accumulated, Encoder, Tiled};
use crate::parallel::{stop_if, Cancelled, Control};
use crate::params::{require, require_atlas, ParamError};
use crate::transport::{Estimator, TexelPanes};
use crate::update::{
    edited_voxels, refusal, relabel, tile_digests, triangle_digests, CachedTile, Plan, Refused, TileRecord,
    UpdateCache, VoxelGrid,
};
use rayon::prelude::*;

mod preamble;

pub use preamble::Preamble;

/// Precompute parameters. Every field has a unit and a default; presets set them together.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PrecomputeParams {
    /// Entry points N (default 4096).
    pub entries: u32,
    /// Light paths: per texel for the gather estimator, per entry for scatter (default 128).
    pub paths: u32,
    /// Clusters C, one pane each (default 256; at most N).
    pub clusters: u32,
    /// The lightmap atlas: its page side and pages (default one 256^2 page). Several pages
    /// need a level whose UVs were generated in pages of that side.
    pub atlas: Atlas,
    /// Seed of every random stream.
    pub seed: u64,
    /// How panes are estimated (default gather; see `transport`).
    pub estimator: Estimator,
    /// Pane tile side in texels (default 16).
    pub tile_size: u32,
    /// Relative energy of a pane its dropped tiles may hold (default 1e-3).
    pub drop_threshold: f64,
    /// Hard cap on walk length (walks cut there are counted in the report; default 1000).
    pub max_bounces: u32,
    /// k-means iterations (default 30).
    pub kmeans_iterations: u32,
    /// Reach of the geometry-guided smoothing applied to every pane, in entry spacings
    /// (`prm::Smoothing`, per texel converted to texels; 0: none; default 1, measured best).
    pub smooth_radius: f32,
    /// Groups G of clusters (k-means on the clusters' centroids and normals), each storing the
    /// sum of its clusters' panes: what a runtime composing only the top K adds for the clusters
    /// it leaves out (`prm::prm_file` module doc). 0: none; default 16.
    pub groups: u32,
    /// Reach of the near-field links in entry spacings (`crate::near`; 0: none; default 2.5).
    pub near_radius: f32,
    /// Reach of the near field's echo in entry spacings (`crate::near::echo_links`; 0: none;
    /// default 1).
    pub echo_radius: f32,
    /// The far field of the deviations (`crate::far`; default on): the near links' first
    /// bounce carried on to every texel for the entries that hold a share of it.
    pub far_field: bool,
    /// Entries farther apart than this, in entry spacings, exchange no far-field light, so its
    /// visibility grows with the level, not with its square (default 48: 26 m at the production
    /// density, the bundled levels' rooms whole; 20 m from a deviation of 1 W its far field is
    /// under a thousandth of a W/m²).
    pub far_radius: f32,
    /// The walks read every bounce after the first from a table of the clusters' first bounce
    /// at the cell each vertex lies in (`crate::transport::NextBounce`; default on; needs the
    /// near links and the far field, which give that first bounce): 4-5x less walk noise, so
    /// the default takes 64 walks instead of 128.
    pub next_bounce: bool,
    /// The table's weak elements are kept by Russian roulette (`crate::transport::Cutoff`):
    /// those under the first bounce an albedo-1 cluster facing a cell head-on gives at this
    /// many entry spacings (default 32: rows 2.6x shorter, walks 17 % faster on the chamber;
    /// 0: every element kept).
    #[serde(default)]
    pub next_cutoff: f32,
    /// Each pane scaled so that its power is what its cells send to the level over every
    /// bounce by their bounce gains ([`match_power`]; default on).
    pub match_power: bool,
    /// Tile rows walked and encoded at a time (`crate::panes`; default 2): memory and time
    /// only, the result is the same bytes at any value.
    pub band_tile_rows: u32,
}

impl PrecomputeParams {
    /// Fast, noisier: for iterating on a level.
    pub fn preview() -> Self {
        PrecomputeParams { entries: 1024, paths: 32, clusters: 64, ..Self::production() }
    }
    /// The DESIGN.md §9 configuration.
    pub fn production() -> Self {
        PrecomputeParams {
            entries: 4096,
            paths: 64,
            clusters: 256,
            atlas: Atlas::single(256),
            seed: 0,
            estimator: Estimator::Gather,
            tile_size: 16,
            drop_threshold: 1e-3,
            max_bounces: 1000,
            kmeans_iterations: 30,
            smooth_radius: 1.0,
            groups: 16,
            near_radius: 2.5,
            echo_radius: 1.0,
            far_field: true,
            far_radius: 48.0,
            next_bounce: true,
            next_cutoff: 32.0,
            match_power: true,
            band_tile_rows: crate::panes::BAND_TILE_ROWS,
        }
    }

    /// The parameters that decide the result, as one line (everything but the band height):
    /// what an update cache records and compares (`crate::update`).
    pub fn canonical(&self) -> String {
        format!(
            "entries {} paths {} clusters {} atlas {} seed {} estimator {} tile {} drop {:e} bounces {} \
             kmeans {} smooth {} groups {} near {} echo {} far {} far-radius {} next {} \
             next-cutoff {} match-power {}",
            self.entries,
            self.paths,
            self.clusters,
            self.atlas,
            self.seed,
            self.estimator,
            self.tile_size,
            self.drop_threshold,
            self.max_bounces,
            self.kmeans_iterations,
            self.smooth_radius,
            self.groups,
            self.near_radius,
            self.echo_radius,
            self.far_field,
            self.far_radius,
            self.next_bounce,
            self.next_cutoff,
            self.match_power
        )
    }

    /// Reject absurd values with an error naming the parameter.
    pub fn validate(&self) -> Result<(), ParamError> {
        require((1..=1 << 20).contains(&self.entries), "entries", self.entries, "1 to 1048576")?;
        require((1..=1 << 16).contains(&self.paths), "paths", self.paths, "1 to 65536")?;
        require((1..=65536).contains(&self.clusters), "clusters", self.clusters, "1 to 65536")?;
        require(self.groups <= 4096, "groups", self.groups, "0 to 4096")?;
        require_atlas(self.atlas)?;
        require((1..=1024).contains(&self.tile_size), "tile size", self.tile_size, "1 to 1024")?;
        require(
            (0.0..0.5).contains(&self.drop_threshold),
            "drop threshold",
            self.drop_threshold,
            "in [0, 0.5)",
        )?;
        require(self.max_bounces >= 1, "max bounces", self.max_bounces, "at least 1")?;
        require((0.0..=4.0).contains(&self.smooth_radius), "smooth radius", self.smooth_radius, "0 to 4")?;
        require((0.0..=8.0).contains(&self.near_radius), "near radius", self.near_radius, "0 to 8")?;
        require((0.0..=4.0).contains(&self.echo_radius), "echo radius", self.echo_radius, "0 to 4")?;
        require(
            self.far_radius > 0.0 && self.far_radius <= 1e6,
            "far radius",
            self.far_radius,
            "above 0, at most 1e6 entry spacings",
        )?;
        require(
            self.next_cutoff == 0.0 || (1.0..=1e6).contains(&self.next_cutoff),
            "next cutoff",
            self.next_cutoff,
            "0 (none), or 1 to 1e6 entry spacings",
        )?;
        require(
            (1..=8192).contains(&self.band_tile_rows),
            "band tile rows",
            self.band_tile_rows,
            "1 to 8192",
        )?;
        if let Estimator::Scatter { clamp } = self.estimator {
            require(clamp.is_finite() && clamp >= 0.0, "clamp", clamp, "finite and >= 0")?;
        }
        Ok(())
    }
}

/// What a preset means per square metre of level (issue 13), so a level of one room and one
/// of a hundred get the same quality per room. The preset's own counts are the floor: a level
/// smaller than the bundled chamber keeps them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Density {
    /// Entry points per square metre of surface.
    pub entries_per_m2: f64,
    /// Entries per cluster (pane).
    pub entries_per_cluster: u32,
    /// Clusters per group (a group's summed pane stands in for the clusters a top-K runtime
    /// leaves out).
    pub clusters_per_group: u32,
}

impl Density {
    /// The production preset's: the bundled chamber's 4096 entries over its 1208 m^2, 16
    /// entries a cluster and 16 clusters a group. (The texel density is the atlas's:
    /// `prm::density`.)
    pub const PRODUCTION: Density =
        Density { entries_per_m2: 3.39, entries_per_cluster: 16, clusters_per_group: 16 };
    /// The preview preset's: a quarter of production's entries.
    pub const PREVIEW: Density = Density { entries_per_m2: 3.39 / 4.0, ..Density::PRODUCTION };

    /// Entries for `area` square metres, at least `floor` and at most the parameter's limit.
    pub fn entries(&self, area: f64, floor: u32) -> u32 {
        let n = (self.entries_per_m2 * area.max(0.0)).floor().min((1 << 20) as f64) as u32;
        n.max(floor)
    }

    /// Clusters for `entries` entries, at least `floor` (and at most the entries).
    pub fn clusters(&self, entries: u32, floor: u32) -> u32 {
        (entries / self.entries_per_cluster.max(1)).max(floor).min(entries.max(1)).min(65536)
    }

    /// Groups for `clusters` clusters, at least `floor`.
    pub fn groups(&self, clusters: u32, floor: u32) -> u32 {
        (clusters / self.clusters_per_group.max(1)).max(floor).min(4096)
    }
}

impl PrecomputeParams {
    /// Entries, clusters and groups for a level of `area` square metres at `density`: each
    /// given count is kept, the others follow the density with these params' counts as the
    /// floor (clusters from the entries, groups from the clusters).
    pub fn fit_to_area(&mut self, density: &Density, area: f64, given: [Option<u32>; 3]) {
        let [entries, clusters, groups] = given;
        self.entries = entries.unwrap_or_else(|| density.entries(area, self.entries));
        self.clusters = clusters.unwrap_or_else(|| density.clusters(self.entries, self.clusters));
        self.groups = groups.unwrap_or_else(|| density.groups(self.clusters, self.groups));
    }
}

impl Default for PrecomputeParams {
    fn default() -> Self {
        Self::production()
    }
}

/// The phases, for progress reporting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    Texels,
    Entries,
    Clustering,
    Transport,
    Panes,
}

/// What a precompute did and what it cost.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    pub estimator: String,
    pub entries: u32,
    pub clusters: u32,
    pub paths: u32,
    pub atlas: u32,
    pub pages: u32,
    pub seed: u64,
    pub texels: usize,
    /// Entries dropped because they lie inside a solid and no point of their triangle tried
    /// outside it was free (the others are moved there).
    pub entries_enclosed: usize,
    /// Rooms (connected free space, `prm::rooms`) the entries lie in: k-means keeps within
    /// each. 0 when the clusters came from an update's cache.
    pub rooms: usize,
    /// The side of the voxels the rooms were found in (scene units): openings narrower than
    /// about two of them may part rooms, and the far field does not trace between rooms.
    pub room_voxel: f32,
    /// Near-field links (`crate::near`) and the seconds they took.
    pub near_links: usize,
    /// Near-field links whose texel does not see some of their cell's triangles
    /// (`prm::prm_file::NearLink::hidden`).
    pub near_links_hiding: usize,
    /// Links of the near field's echo.
    pub echo_links: usize,
    /// The echo's crease points and their near links (`crate::near::crease_points`).
    pub crease_points: usize,
    pub crease_links: usize,
    pub seconds_near: f64,
    /// Covered texels the far field lights, and pairs of entries that see each other.
    pub far_texels: usize,
    pub far_pairs: usize,
    pub seconds_far: f64,
    /// Triangles of the entries' cells (`prm::prm_file::Cells`).
    pub cell_triangles: usize,
    /// Surface area no entry's cell covers (triangles too small for an entry, with none near
    /// enough facing the same way), as a fraction of the level's area.
    pub area_without_entry: f64,
    /// Phase times. The rooms' flood fill, counted in `seconds_clustering`, runs beside the
    /// texels, so the phases can sum to a little more than `seconds_total`.
    pub seconds_texels: f64,
    pub seconds_entries: f64,
    pub seconds_clustering: f64,
    pub seconds_transport: f64,
    pub seconds_panes: f64,
    pub seconds_total: f64,
    pub rays: usize,
    pub rays_per_second: f64,
    pub walks_truncated: usize,
    pub unowned_vertices: usize,
    pub virtual_lights: usize,
    pub tiles_kept: u32,
    pub tiles_dropped: u32,
    pub dropped_energy: f64,
    /// The least and most a pane was scaled to match its power ([`match_power`]; 1 and 1
    /// without).
    pub power_scale: [f32; 2],
    pub pane_bytes: usize,
    pub threads: usize,
    /// An update's atlas tiles the edit reached (their walks or other inputs changed), the
    /// tiles encoded again (those within reach of one), the texels walked again, and the rooms
    /// of the level as baked whose walks could meet the edit (`crate::update::Edit::rooms`).
    pub update_tiles_hit: usize,
    pub update_tiles_encoded: usize,
    pub update_texels_walked: usize,
    pub update_rooms_touched: usize,
    /// An update's entries settled (each as it was, in a room the edit did not touch), whose
    /// far-field pairs and texels' near links come from the old bake
    /// (`crate::update::Untouched`).
    pub update_entries_settled: usize,
    /// An update's pairs of entry blocks in touched rooms whose far-field bits came from the
    /// old bake by geometry (`crate::far::FarReuse`), not traced again.
    pub update_far_pairs_kept: usize,
    /// An update's texels not settled whose near links came from the old bake by geometry
    /// (`crate::near::NearReuse`).
    pub update_near_texels_kept: usize,
    /// An update's rows of the walks' next-bounce table made again: those whose inputs
    /// changed and those of the rooms its walks can reach (of `entries`).
    pub update_rows_made: usize,
}

/// Why a precompute gave no map.
#[derive(Debug, thiserror::Error)]
pub enum PrecomputeError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
    /// The scratch file the encoded panes wait in could not be made, written or read.
    #[error("the precompute's scratch file (in the system's temporary folder) failed: {0}")]
    Scratch(#[from] std::io::Error),
    /// The bake assembled a map the format refuses: a bug, reported rather than written.
    #[error("the precompute produced an inconsistent map (a bug): {0}")]
    Invalid(#[from] InvalidPrm),
    /// An update (or a bake that keeps an update cache) cannot be done this way: run a full
    /// precompute (`crate::update` module doc).
    #[error("cannot update: {0}")]
    Refused(#[from] Refused),
}

/// What a precompute takes from an earlier bake's update cache (`crate::update`).
pub enum Reuse<'a> {
    /// Nothing: a fresh bake.
    Nothing,
    /// The cache's clusters and groups, every texel walked: the full precompute an update
    /// writes the same bytes as.
    Clusters(&'a UpdateCache),
    /// An update of `old` (the `.prm` the cache belongs to): the cache's clusters, and its
    /// tiles wherever the edit cannot have changed them. Given rather than lent, the update
    /// lets each go as soon as it is done with it (the old map after its plan, the cache after
    /// the walks): 0.7 GB less at the 16 chambers' peak.
    Update { cache: Held<'a, UpdateCache>, old: Held<'a, Prm> },
}

/// What an update is lent (the caller keeps it) or given (the update lets it go once it is
/// done with it).
pub enum Held<'a, T> {
    Lent(&'a T),
    Given(Box<T>),
}

impl<T> Held<'_, T> {
    fn get(&self) -> &T {
        match self {
            Held::Lent(t) => t,
            Held::Given(t) => t,
        }
    }
}

impl<T: Clone> Held<'_, T> {
    /// The thing itself: moved out if given, a copy if lent.
    fn into_owned(self) -> T {
        match self {
            Held::Lent(t) => t.clone(),
            Held::Given(t) => *t,
        }
    }
}

impl<'a, T> From<&'a T> for Held<'a, T> {
    fn from(t: &'a T) -> Self {
        Held::Lent(t)
    }
}

impl<T> From<T> for Held<'_, T> {
    fn from(t: T) -> Self {
        Held::Given(Box::new(t))
    }
}

/// A precompute's map, its report and, when asked for, its update cache.
pub struct Baked {
    pub prm: Prm,
    pub report: Report,
    pub cache: Option<UpdateCache>,
}

/// The checksum a `.prm` file of `prm` ends with (what an update cache is tied to).
pub fn prm_checksum(prm: &Prm) -> u64 {
    prm.checksum()
}

/// Run the precompute. `progress(phase, done, total)` is called as work completes; `cancel`
/// stops it (no result). Parameters are validated first.
pub fn precompute(
    scene: &Scene,
    bvh: &Bvh,
    params: &PrecomputeParams,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<(Prm, Report), PrecomputeError> {
    let baked = precompute_with(scene, bvh, params, Reuse::Nothing, false, progress, cancel)?;
    Ok((baked.prm, baked.report))
}

/// [`precompute`] taking what `reuse` gives from an earlier bake, and with `keep_cache` also
/// returning the update cache a later `--update` needs (`crate::update`). An update that
/// cannot reuse the earlier bake is refused ([`PrecomputeError::Refused`]) before any walk.
pub fn precompute_with(
    scene: &Scene,
    bvh: &Bvh,
    params: &PrecomputeParams,
    reuse: Reuse,
    keep_cache: bool,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<Baked, PrecomputeError> {
    check_params(scene, params)?;
    let all = Instant::now();
    let mut report = Report::new(params);
    // What an update compares and a cache keeps (`crate::update`).
    let tiles = (params.atlas.width().div_ceil(params.tile_size)
        * params.atlas.height().div_ceil(params.tile_size)) as usize;
    // The cache and the old map, each held until the update is done with it.
    let (mut cache_held, mut old_held): (Option<Held<UpdateCache>>, Option<Held<Prm>>) = match reuse {
        Reuse::Nothing => (None, None),
        Reuse::Clusters(c) => (Some(Held::Lent(c)), None),
        Reuse::Update { cache, old } => (Some(cache), Some(old)),
    };
    let tracing = keep_cache || old_held.is_some();
    let triangles = (tracing || cache_held.is_some()).then(|| triangle_digests(scene));
    if let (Some(cache), Some(triangles)) = (cache_held.as_ref().map(Held::get), &triangles) {
        if let Some(r) = refusal(cache, params, triangles, tiles) {
            return Err(r.into());
        }
    }
    if tracing && params.estimator != Estimator::Gather {
        return Err(Refused(format!(
            "an update cache is kept for the gather estimator only (not {})",
            params.estimator
        ))
        .into());
    }
    let unchanged = match (cache_held.as_ref().map(Held::get), old_held.as_ref().map(Held::get)) {
        (Some(cache), Some(old)) => {
            // An older build's file reads in this version's form, whose checksum is not its
            // cache's: say so rather than that the cache is another map's.
            if old.read_version() != prm::prm_file::VERSION {
                return Err(Refused(format!(
                    "the old .prm is format version {}, written by an older build; an update needs \
                     version {} and its cache: bake the level in full once",
                    old.read_version(),
                    prm::prm_file::VERSION
                ))
                .into());
            }
            if prm_checksum(old) != cache.prm_checksum {
                return Err(Refused("the cache belongs to another .prm (checksums differ)".into()).into());
            }
            if let Some(r) = crate::update::moved_bounds(cache, scene.bounds()) {
                return Err(r.into());
            }
            triangles.as_ref() == Some(&cache.triangles)
        }
        _ => false,
    };
    // Every triangle reads as it did (a light moved or recoloured, a camera, a node that holds
    // no geometry): the map is made of nothing else, so the update is OLD, to the byte, and its
    // cache; the preamble a plan would need costs what it saves (the chamber's lamp moved 7 m:
    // 1.7 s, 42 % of a full precompute, for no walk).
    if unchanged {
        if let (Some(old), Some(cache)) = (old_held.take(), cache_held.take()) {
            let mut report = Report::of_map(params, old.get());
            report.seconds_total = all.elapsed().as_secs_f64();
            return Ok(Baked { prm: old.into_owned(), report, cache: Some(cache.into_owned()) });
        }
    }
    let same_entries = |entries: &[Entry]| match cache_held.as_ref().map(Held::get) {
        Some(cache) if entries.len() != cache.assignment.len() => Err(Refused(format!(
            "{} entries now, {} then (the edit changed the surface's area or what lies inside solids)",
            entries.len(),
            cache.assignment.len()
        ))
        .into()),
        _ => Ok(()),
    };
    let (cache, old) = (cache_held.as_ref().map(Held::get), old_held.as_ref().map(Held::get));
    let update = match (old, &triangles) {
        (Some(old), Some(t)) => Some((old, &t[..])),
        _ => None,
    };
    let mut pre = Preamble::build(
        scene,
        bvh,
        params,
        cache,
        update,
        tracing,
        update.is_some(),
        same_entries,
        &mut report,
        progress,
        cancel,
    )?;
    // What each texel's exact first bounce, and so each next-bounce row, is made of: the
    // tiles' and the rows' digests (an update compares them with the old bake's).
    let t = Instant::now();
    let exact = tracing.then(|| pre.exact_digests(pre.first_bounce().as_ref()));
    let row_inputs = exact.as_ref().map_or(Vec::new(), |e| pre.row_inputs(e));
    report.seconds_panes += t.elapsed().as_secs_f64();
    // The rows' values' digests (the plan marks a cell whose row's value changed). An update
    // makes only the rows whose inputs changed (most of them in the edited room), and keeps
    // the others' digests; it makes the rows its walks need after its plan.
    let t = Instant::now();
    let (rows, changed) = match (&pre.next, cache) {
        (Some(next), _) => (next.row_digests(), None),
        (None, Some(cache)) if pre.next_on => {
            let same = cache.row_inputs.len() == row_inputs.len() && cache.rows.len() == row_inputs.len();
            let changed: Vec<bool> =
                (0..row_inputs.len()).map(|e| !same || cache.row_inputs[e] != row_inputs[e]).collect();
            pre.make_next(Some(&changed));
            let rows = (0..row_inputs.len())
                .map(|e| match (&pre.next, changed[e]) {
                    (Some(n), true) => n.row_digest(e),
                    _ => cache.rows[e],
                })
                .collect();
            (rows, Some(changed))
        }
        _ => (Vec::new(), None),
    };
    report.seconds_far += t.elapsed().as_secs_f64();
    // The update's plan: what the edit changed and the rooms whose walks could meet it (in
    // the rooms of the level as baked, which the cache's tiles name, rebuilt from its
    // triangles), then which tiles it reaches and which texels to walk again.
    let t = Instant::now();
    let edit = match (cache, old, &triangles) {
        (Some(cache), Some(old), Some(triangles)) => {
            let edit = edited_voxels(
                cache,
                triangles,
                scene,
                (old.entries(), old.cells()),
                (&pre.entries, &pre.cells),
                &rows,
            );
            // The rooms of the level as baked, as the settled entries found them (the
            // preamble makes them for every update).
            let Some(u) = &pre.untouched else {
                return Err(Refused("the update found no rooms of the old level".into()).into());
            };
            Some((edit.rooms(&u.baked), u.map.clone(), edit))
        }
        _ => None,
    };
    report.seconds_clustering += t.elapsed().as_secs_f64();
    let t = Instant::now();
    let digests = exact.map(|exact| {
        // Every tile's digest is made again, what its exact first bounce is made of included.
        // Made only for tiles whose walks lay in a touched room, one tile of an untouched
        // chamber of the 16 kept a stale digest: its far-field first bounce carried 1e-11 of
        // the edited chamber's clusters' light, which changed.
        tile_digests(&pre.set, params.tile_size, pre.smoothing.as_ref(), pre.linked().as_ref(), &exact)
    });
    report.seconds_panes += t.elapsed().as_secs_f64();
    let plan = match (cache, &triangles, &digests, edit) {
        (Some(cache), Some(_), Some(digests), Some((touched, now, edit))) => {
            let set = &pre.set;
            let plan = Plan::new(
                cache,
                set,
                params.tile_size,
                pre.smoothing.as_ref(),
                digests,
                &edit.voxels,
                &touched,
            );
            let layout = Encoder::new(set, None, params.tile_size, 1).tile_codes();
            // Tiles taken from the cache must hold as many codes as this atlas stores there
            // (a tile whose stored texels changed has another digest, so it is not taken).
            let fits = cache.panes.iter().flatten().all(|t| {
                let k = t.index as usize;
                plan.dirty.get(k) != Some(&false) || layout.get(k) == Some(&t.codes.len())
            });
            let panes = pre.clustering.members.len() + pre.grouping.as_ref().map_or(0, |g| g.members.len());
            if !fits || cache.panes.len() != panes {
                return Err(Refused("the cache's pane tiles do not fit this atlas".into()).into());
            }
            report.update_tiles_hit = plan.hit.iter().filter(|&&h| h).count();
            report.update_tiles_encoded = plan.dirty.iter().filter(|&&d| d).count();
            report.update_texels_walked = plan.walk.iter().filter(|&&w| w).count();
            report.update_rooms_touched = touched.len();
            Some((plan, cache, now, touched))
        }
        _ => None,
    };
    // An update's next-bounce table holds the rows of the rooms its walks can reach: those
    // the walked tiles' walks lay in when baked, and those the edit touched. A walk that meets
    // a row left out (through a gap narrower than the rooms' voxels) refuses the update below.
    if pre.next_on && pre.next.as_ref().is_none_or(|n| n.left_out_any()) {
        let t = Instant::now();
        let only = plan.as_ref().map(|(plan, cache, now, touched)| {
            let tx = params.atlas.width().div_ceil(params.tile_size) as usize;
            let mut rooms = touched.clone();
            let mut seen = vec![false; cache.tiles.len()];
            for (t, _) in pre.set.texels.iter().zip(&plan.walk).filter(|(_, &w)| w) {
                let k = crate::update::tile_of(t.i, t.j, params.tile_size, tx);
                if !std::mem::replace(&mut seen[k], true) {
                    rooms.extend_from_slice(&cache.tiles[k].rooms);
                }
            }
            rooms.sort_unstable();
            rooms.dedup();
            // In this level's rooms; a baked room whose space is gone (a moved block's inside)
            // adds none, a tile with a walk placed in no room (`ANY_ROOM`) every one.
            let (mut reach, mut any) = (Vec::new(), false);
            for &r in &rooms {
                match now.get(r as usize) {
                    Some(in_now) => reach.extend_from_slice(in_now),
                    None => any = true,
                }
            }
            reach.sort_unstable();
            (0..pre.entry_room.len())
                .map(|e| {
                    let r = &pre.entry_room[e];
                    any || reach.binary_search(r).is_ok() || changed.as_ref().is_some_and(|c| c[e])
                })
                .collect::<Vec<bool>>()
        });
        pre.make_next(only.as_deref());
        report.seconds_far += t.elapsed().as_secs_f64();
    }
    if let (Some(next), Some(_)) = (&pre.next, &changed) {
        report.update_rows_made = (0..pre.entries.len() as u32).filter(|&e| !next.left_out(e)).count();
    }
    let linked = pre.linked();
    let set = &pre.set;
    // The old map is done with (its entries and cells made the plan).
    drop(old_held.take());
    let grid = match cache {
        Some(c) => c.grid.clone(),
        None => {
            let (lo, hi) = scene.bounds();
            VoxelGrid::around(lo, hi)
        }
    };
    let transport = pre.transport(scene, bvh, linked.as_ref(), params);
    let prepared = transport.prepare(params.estimator);
    let (tx, ty) = (
        params.atlas.width().div_ceil(params.tile_size) as usize,
        params.atlas.height().div_ceil(params.tile_size) as usize,
    );
    let mut records =
        tracing.then(|| vec![TileRecord { footprint: vec![0; grid.words()], ..Default::default() }; tx * ty]);
    let rooms = pre.rooms.as_ref();
    // With a voxel grid each walked texel is recorded in its tile; with a plan only its
    // texels are walked (the others give nothing and are taken from the cache).
    let mut walk = |range: Range<usize>, control: Control| -> Result<Walked, PrecomputeError> {
        let (Some(records), Some(rooms)) = (records.as_mut(), rooms) else {
            return Ok(transport.run_texels(&prepared, &set.texels[range], set.width, control)?);
        };
        let todo: Vec<usize> =
            range.clone().filter(|&k| plan.as_ref().is_none_or(|(p, _, _, _)| p.walk[k])).collect();
        let texels: Vec<prm::Texel> = todo.iter().map(|&k| set.texels[k]).collect();
        let walked = transport.run_traced(&texels, set.width, &grid, rooms, control)?;
        let mut out: Walked = vec![Vec::new(); range.len()];
        for (&k, (p, trace)) in todo.iter().zip(walked) {
            let t = &set.texels[k];
            let r = &mut records[crate::update::tile_of(t.i, t.j, params.tile_size, tx)];
            for v in trace.voxels {
                r.footprint[v as usize / 64] |= 1 << (v % 64);
            }
            r.truncated += trace.truncated;
            r.unowned += trace.unowned;
            if !trace.rooms.iter().all(|x| r.rooms.binary_search(x).is_ok()) {
                r.rooms.extend(trace.rooms);
                r.rooms.sort_unstable();
                r.rooms.dedup();
            }
            out[k - range.start] = p;
        }
        Ok(out)
    };
    let cached = plan.as_ref().map(|(plan, cache, _, _)| CachedPanes {
        dirty: &plan.dirty,
        panes: &cache.panes,
        walk: &plan.walk,
    });
    crate::memory::release_freed();
    let mut acc = walk_and_encode(&pre, params, &mut walk, cached, progress, cancel, &mut report)?;
    // The estimator's tables (virtual lights, MIS) are the walks' only (`walk`, which borrows
    // them, is not used again).
    drop(prepared);
    let left_out = transport.stats.rows_left_out.load(Ordering::Relaxed);
    if left_out > 0 {
        return Err(Refused(format!(
            "{left_out} walk vertices met next-bounce rows the update did not make (a walk left the rooms \
             it lay in when baked)"
        ))
        .into());
    }
    report.rays = transport.stats.rays.load(Ordering::Relaxed);
    report.walks_truncated = transport.stats.truncated.load(Ordering::Relaxed);
    report.unowned_vertices = transport.stats.unowned.load(Ordering::Relaxed);
    report.virtual_lights = transport.stats.vpls.load(Ordering::Relaxed);
    // An update walked some texels only: the counters are the tiles' (the same totals a full
    // bake's walks give, tile by tile).
    if let (Some((plan, cache, now, _)), Some(records)) = (&plan, records.as_mut()) {
        for (k, r) in records.iter_mut().enumerate() {
            if !plan.dirty[k] {
                *r = cache.tiles[k].clone();
                r.rooms = relabel(&r.rooms, now);
            }
        }
        report.walks_truncated = records.iter().map(|r| r.truncated as usize).sum();
        report.unowned_vertices = records.iter().map(|r| r.unowned as usize).sum();
    }
    // So is the cache (its tiles are in the walks' encoding now).
    drop(plan);
    drop(cache_held.take());
    crate::memory::release_freed();
    let pane_cache = if tracing {
        let mut panes = acc.fine.export()?;
        panes.extend(acc.groups.export()?);
        Some(panes)
    } else {
        None
    };
    let kept = tracing.then(|| (pre.clustering.assignment.clone(), pre.grouping.clone()));
    let prm = finish(pre, acc, params, &mut report, all)?;
    progress(Phase::Panes, 1, 1);
    let cache = match (pane_cache, records, triangles, digests, kept) {
        (Some(panes), Some(mut records), Some(triangles), Some(digests), Some((assignment, grouping))) => {
            for (r, d) in records.iter_mut().zip(digests) {
                r.inputs = d;
            }
            let (group_of, groups) = match &grouping {
                Some(g) => (g.assignment.clone(), g.members.len() as u32),
                None => (Vec::new(), 0),
            };
            Some(UpdateCache {
                prm_checksum: prm_checksum(&prm),
                params: params.canonical(),
                grid,
                bounds: scene.bounds(),
                triangles,
                assignment,
                clusters: report.clusters,
                group_of,
                groups,
                rows,
                row_inputs,
                tiles: records,
                panes,
            })
        }
        _ => None,
    };
    Ok(Baked { prm, report, cache })
}

/// Parameters valid, and several atlas pages only for a level generated in them.
pub(crate) fn check_params(scene: &Scene, params: &PrecomputeParams) -> Result<(), PrecomputeError> {
    params.validate()?;
    if params.atlas.pages > 1 && scene.report.generated_atlas != Some(params.atlas) {
        return Err(PrecomputeError::Params(ParamError {
            name: "atlas pages",
            value: params.atlas.to_string(),
            allowed: "several pages only for a level whose UVs were generated in those pages",
        }));
    }
    Ok(())
}

impl Report {
    /// A report with the parameters filled in and nothing measured yet.
    /// What a bake that made `map` reported of it, from its header (an update that hands back
    /// the old map: nothing was walked or timed). A map from before its header recorded the
    /// texels reads the far field's (every covered texel when it has one).
    fn of_map(params: &PrecomputeParams, map: &Prm) -> Report {
        let h = map.header();
        let p = &h.provenance;
        let count = |k: &str| p[k].as_u64().unwrap_or(0) as usize;
        Report {
            entries: h.entries,
            clusters: h.clusters,
            texels: p.get("texels").map_or(count("far_texels"), |t| t.as_u64().unwrap_or(0) as usize),
            entries_enclosed: count("entries_enclosed"),
            near_links: count("near_links"),
            near_links_hiding: map.near().iter().filter(|l| l.hidden != 0).count(),
            echo_links: count("echo_links"),
            crease_points: map.echo().creases.len(),
            crease_links: map.near().iter().filter(|l| l.texel as usize >= map.texel_count()).count(),
            far_texels: count("far_texels"),
            far_pairs: count("far_pairs"),
            cell_triangles: count("cell_triangles"),
            area_without_entry: p["area_without_entry"].as_f64().unwrap_or(0.0),
            walks_truncated: count("walks_truncated"),
            unowned_vertices: count("unowned_vertices"),
            tiles_kept: h.tiles,
            tiles_dropped: h.tiles_dropped,
            dropped_energy: h.dropped_energy,
            pane_bytes: map.data().len(),
            power_scale: match p["power_scale"]
                .as_array()
                .map(|r| r.iter().filter_map(|x| x.as_f64()).collect::<Vec<_>>())
            {
                Some(r) if r.len() == 2 => [r[0] as f32, r[1] as f32],
                _ => [1.0, 1.0],
            },
            ..Report::new(params)
        }
    }

    pub(crate) fn new(params: &PrecomputeParams) -> Report {
        Report {
            estimator: params.estimator.to_string(),
            entries: params.entries,
            paths: params.paths,
            atlas: params.atlas.side,
            pages: params.atlas.pages,
            seed: params.seed,
            threads: rayon::current_num_threads(),
            power_scale: [1.0, 1.0],
            ..Default::default()
        }
    }
}

/// The walks' results for a run of texels, one per texel in order (empty for a texel not
/// walked).
pub(crate) type Walked = Vec<TexelPanes>;

/// Where the walks come from: `walk(texels, control)` gives those of a run of covered texels
/// (the transport's, or a sharded precompute's parts).
pub(crate) type WalkSource<'a> = dyn FnMut(Range<usize>, Control) -> Result<Walked, PrecomputeError> + 'a;

/// The file from the preamble and the encoded panes: the drop rule, the header and the
/// sections (the last step of a precompute and of a sharded one's merge). `all` is when the
/// precompute started.
pub(crate) fn finish(
    mut pre: Preamble,
    acc: Encoded,
    params: &PrecomputeParams,
    report: &mut Report,
    all: Instant,
) -> Result<Prm, PrecomputeError> {
    // The links' shares and exact first bounce, the cell owners and the smoothing are the
    // walks' and the encoding's only: out of memory before the tiles are assembled (what the
    // peak is made of).
    (pre.keep, pre.smoothing) = (None, None);
    pre.owners = crate::cells::CellOwners::default();
    crate::memory::release_freed();
    // The far field's energies, where the preamble left them: added up beside the first
    // bounce, or (without it) summed now.
    if !pre.far.texels.is_empty() && pre.far.energy.is_empty() {
        pre.far.energy = match acc.far_energy {
            Some(e) => e,
            None => {
                let t = Instant::now();
                let energies = crate::far::energies(&pre.far, &pre.entries, &pre.cell());
                report.seconds_far += t.elapsed().as_secs_f64();
                energies
            }
        };
    }
    let t = Instant::now();
    let encoder = Encoder::new(&pre.set, pre.smoothing.as_ref(), params.tile_size, params.band_tile_rows);
    let (members, threshold) = (&pre.clustering.members, params.drop_threshold);
    let tiled = assemble(&encoder, acc.fine, acc.groups, members, &pre.centroids, threshold)?;
    drop(encoder);
    report.seconds_panes += t.elapsed().as_secs_f64();
    report.tiles_kept = tiled.tiles.len() as u32;
    report.tiles_dropped = tiled.tiles_dropped;
    report.dropped_energy = tiled.dropped_energy;
    report.pane_bytes = tiled.data.len();
    report.rays_per_second = report.rays as f64 / report.seconds_transport.max(1e-9);
    report.seconds_total = all.elapsed().as_secs_f64();
    let header = header(&pre, params, report, &tiled);
    let Preamble {
        entries,
        stays,
        gains,
        cells,
        mut near,
        mut near_points,
        echo,
        crease_links,
        crease_points,
        mut far,
        grouping,
        set: pre_set,
        texel_areas,
        ..
    } = pre;
    // Each far texel's area, for the runtime's sum of the near field's power (none where the
    // areas were not made: without `match_power`).
    far.areas = if texel_areas.is_empty() {
        Vec::new()
    } else {
        far.texels
            .iter()
            .map(|t| match pre_set.index.get(t.texel as usize) {
                Some(&k) if k != prm::TexelSet::EMPTY => texel_areas.get(k as usize).copied().unwrap_or(0.0),
                _ => 0.0,
            })
            .collect()
    };
    // The crease points come after the texels' (their texels past the atlas's).
    near.extend(crease_links);
    near_points.extend(crease_points);
    let group_of = grouping.map_or_else(Vec::new, |g| g.assignment);
    let Tiled { clusters, groups, mask, tiles, data, .. } = tiled;
    let prm = Prm::new(PrmParts {
        header,
        entries,
        stays,
        gains,
        cells,
        near,
        near_points,
        echo,
        clusters,
        groups,
        group_of,
        tiles,
        mask,
        data,
        far,
    })?;
    if !params.match_power {
        return Ok(prm);
    }
    let t = Instant::now();
    let (prm, matched) = match_power(prm, &pre_set, &texel_areas)?;
    report.seconds_panes += t.elapsed().as_secs_f64();
    report.seconds_total = all.elapsed().as_secs_f64();
    report.power_scale = matched;
    Ok(prm)
}

/// The most and least a pane is scaled by [`match_power`] (a pane further off keeps this
/// bound: something other than walk noise is wrong with it).
pub const POWER_SCALE_LIMITS: [f32; 2] = [0.5, 2.0];

/// Each pane scaled so that the power it delivers (its texels' luminance times the area of
/// surface each stands for, `TexelSet::visible_areas`) is the power its cells send to the level
/// over every bounce under unit irradiance: `sum over its entries of A_j luminance(rho_j g_j)`,
/// by the cells' areas and their bounce gains (`crate::cells::reflections`). A pane answers
/// unit irradiance on its cluster; under it each cell reflects `rho_j A_j` and of that `g_j`
/// lands over every bounce, so the two are the same power (a group's pane: its clusters' sum).
/// The walks left the chamber's panes 0.94-1.07 of it (seed 1, 7.8 % standard deviation over
/// its 256 panes, the same at 512 walks a texel: the cells' geometry, chiefly floor cells
/// reaching under plinths, which no walk hits while the weight divides by their whole area,
/// not noise), and a light whose beam lands in one cluster takes that pane's error whole: the
/// flashlight on the floor by a pillar read -6.3 % and -4.4 % bias at seeds 1 and 2, where
/// their panes held 0.94 and 0.96 of their power, +0.1 % at seed 0 (1.01). The scale is
/// bounded by [`POWER_SCALE_LIMITS`]; a pane with no power or nothing to deliver keeps its
/// values. Returns the map and the least and most scale used; a texel set or areas not of
/// the map's atlas are refused.
pub fn match_power(prm: Prm, set: &prm::TexelSet, areas: &[f32]) -> Result<(Prm, [f32; 2]), InvalidPrm> {
    if areas.len() != set.texels.len() || set.index.len() != prm.texel_count() {
        return Err(InvalidPrm(format!(
            "pane power: {} texel areas for {} texels, a texel set of {} atlas texels for a map of {}",
            areas.len(),
            set.texels.len(),
            set.index.len(),
            prm.texel_count()
        )));
    }
    let layout = prm.layout();
    let c = prm.clusters().len();
    // What each cluster's cells send to the level per unit irradiance, then each group's.
    let mut want: Vec<f64> = prm
        .clusters()
        .iter()
        .map(|cl| {
            cl.members
                .iter()
                .map(|&m| {
                    let m = m as usize;
                    prm.cells().area(m) as f64 * prm::luminance(prm.gain(m) * prm.entries()[m].albedo) as f64
                })
                .sum()
        })
        .collect();
    let mut groups = vec![0.0f64; prm.groups().len()];
    for (cl, &g) in prm.group_of().iter().enumerate() {
        groups[g as usize] += want[cl];
    }
    want.extend(groups);
    let scales: Vec<f32> = (0..want.len())
        .into_par_iter()
        .map(|pane| {
            let mut power = 0.0f64;
            for t in prm.pane_tiles(pane, &layout) {
                for (&texel, &v) in t.texels.iter().zip(t.data) {
                    let k = set.index[texel as usize];
                    if k != prm::TexelSet::EMPTY {
                        let e = prm::luminance(t.tile.scale * prm::prm_file::intensity(v));
                        power += e as f64 * areas[k as usize] as f64;
                    }
                }
            }
            if power > 0.0 && want[pane] > 0.0 {
                ((want[pane] / power) as f32).clamp(POWER_SCALE_LIMITS[0], POWER_SCALE_LIMITS[1])
            } else {
                1.0
            }
        })
        .collect();
    let ranges: Vec<Range<usize>> = (0..scales.len()).map(|pane| prm.tile_range(pane)).collect();
    let mut parts = prm.into_parts();
    for (pane, range) in ranges.into_iter().enumerate() {
        for tile in &mut parts.tiles[range] {
            tile.scale *= scales[pane];
        }
    }
    for (cl, s) in parts.clusters.iter_mut().zip(&scales) {
        cl.energy *= s;
    }
    for (g, s) in parts.groups.iter_mut().zip(&scales[c..]) {
        g.energy *= s;
    }
    let range = scales.iter().fold([f32::INFINITY, 0.0f32], |[lo, hi], &s| [lo.min(s), hi.max(s)]);
    let range = if scales.is_empty() { [1.0, 1.0] } else { range };
    parts.header.provenance["power_scale"] = serde_json::json!(range);
    Ok((Prm::new(parts)?, range))
}

/// The panes being encoded: the clusters' and the groups'.
pub(crate) struct Encoded {
    /// The far field's energies where they were added up beside the first bounce.
    pub(crate) far_energy: Option<Vec<f32>>,
    pub(crate) fine: Accumulated,
    pub(crate) groups: Accumulated,
}

/// What an update takes from its cache (`crate::update::Plan`): per atlas tile whether it is
/// encoded again, the cached pane tiles, and per texel whether it is walked again (only those
/// need their exact first bounce).
#[derive(Clone, Copy)]
pub(crate) struct CachedPanes<'a> {
    pub dirty: &'a [bool],
    pub panes: &'a [Vec<CachedTile>],
    pub walk: &'a [bool],
}

/// Walk the texels a band of tile rows at a time (`walk(texels, control)`: the walks of a run
/// of covered texels, the transport's or a sharded precompute's parts') and encode every
/// pane's tiles in each band as it is done (`crate::panes`), holding only the walks the next
/// bands still need. With `cached` (an update's dirty tiles and the cache's pane tiles), only
/// the dirty tiles are encoded, the rest taken from the cache.
pub(crate) fn walk_and_encode(
    pre: &Preamble,
    params: &PrecomputeParams,
    walk: &mut WalkSource,
    cached: Option<CachedPanes>,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    cancel: &AtomicBool,
    report: &mut Report,
) -> Result<Encoded, PrecomputeError> {
    let need = cached.map(|c| c.walk);
    let (set, grouping) = (&pre.set, pre.grouping.as_ref());
    let encoder = Encoder::new(set, pre.smoothing.as_ref(), params.tile_size, params.band_tile_rows);
    let clusters = pre.clustering.members.len();
    let mut out = Encoded {
        far_energy: None,
        fine: Accumulated::new(clusters)?,
        groups: Accumulated::new(grouping.map_or(0, |g| g.members.len()))?,
    };
    let reuse = cached.map(|CachedPanes { dirty, panes, .. }| {
        let split = clusters.min(panes.len());
        (dirty, &panes[..split], &panes[split..])
    });
    // The walks of texels first..first + panes.len().
    let (mut first, mut panes): (usize, Vec<TexelPanes>) = (0, Vec::new());
    let n = set.len();
    let first_bounce = pre.first_bounce();
    // The far field's energies, added up beside the first bounce where the preamble left them
    // (a full precompute: `crate::far::EnergySum`).
    let mut energy = (need.is_none() && first_bounce.is_some() && pre.far.energy.is_empty())
        .then(|| EnergySum::new(pre.entries.len()));
    // The last band's exact first bounce and its texels.
    let (mut last, mut last_at): (Vec<TexelPanes>, std::ops::Range<usize>) = (Vec::new(), 0..0);
    let bands = encoder.bands();
    for (b, band) in bands.iter().enumerate() {
        let range = encoder.texel_range(band.window.clone());
        let gone = (range.start - first).min(panes.len());
        panes.drain(..gone);
        // The walks the last band no longer needs, and its encoding's scratch.
        crate::memory::release_freed();
        first = range.start;
        let have = first + panes.len();
        if range.end > have {
            let t = Instant::now();
            let on_texels = |done| progress(Phase::Transport, have + done, n);
            let control = Control { progress: &on_texels, cancel };
            panes.extend(walk(have..range.end, control)?);
            report.seconds_transport += t.elapsed().as_secs_f64();
        }
        stop_if(cancel)?;
        let t = Instant::now();
        // The exact first bounce of the band's texels; the part the last band made is kept.
        let kept = range.start.clamp(last_at.start, last_at.end)..range.end.clamp(last_at.start, last_at.end);
        let mut exact: Vec<TexelPanes> = if last.len() == last_at.len() {
            last.drain(kept.start - last_at.start..kept.end - last_at.start).collect()
        } else {
            Vec::new()
        };
        if kept.start == range.start && !exact.is_empty() {
            exact.extend(pre.band_exact(kept.end..range.end, first_bounce.as_ref(), need, energy.as_mut()));
        } else {
            exact = pre.band_exact(range.clone(), first_bounce.as_ref(), need, energy.as_mut());
        }
        let fine_reuse = reuse.map(|(dirty, fine, _)| (dirty, fine));
        encoder.encode_band(band, first, &panes, &exact, &mut out.fine, fine_reuse)?;
        if let Some(g) = grouping {
            let (group_panes, group_exact) = (by_group(&panes, g), by_group(&exact, g));
            let group_reuse = reuse.map(|(dirty, _, groups)| (dirty, groups));
            encoder.encode_band(band, first, &group_panes, &group_exact, &mut out.groups, group_reuse)?;
        }
        // Only what the next band's window holds is kept.
        let next = bands
            .get(b + 1)
            .map_or(range.end, |next| encoder.texel_range(next.window.clone()).start)
            .clamp(range.start, range.end);
        if exact.len() == range.len() {
            exact.drain(..next - range.start);
            (last, last_at) = (exact, next..range.end);
        } else {
            (last, last_at) = (exact, range);
        }
        report.seconds_panes += t.elapsed().as_secs_f64();
    }
    out.far_energy = energy.and_then(|e| e.finish(&pre.far, &pre.entries));
    Ok(out)
}
/// Each texel's contributions summed by group, its list ascending by group as every pane list
/// is: the encoder transposes a band a run of panes at a time and finds a run's part of each
/// list by bisection (`panes::span`). The groups were listed in the order first met, so a
/// level with enough groups for the band to be split into runs (the chamber with a cluster per
/// entry: 256 groups) took the wrong part of a list, and the precompute stopped on an index out
/// of bounds (or, had the indices fallen in range, left a group's light out).
fn by_group(panes: &[TexelPanes], grouping: &Clustering) -> Vec<TexelPanes> {
    panes
        .par_iter()
        .map(|tp| {
            let mut out: TexelPanes = Vec::new();
            for &(cl, v) in tp {
                let g = grouping.assignment[cl as usize];
                match out.iter_mut().find(|(x, _)| *x == g) {
                    Some(slot) => slot.1 += v,
                    None => out.push((g, v)),
                }
            }
            out.sort_unstable_by_key(|&(g, _)| g);
            out
        })
        .collect()
}

/// The file header: what the map was baked for, its counts, and the parameters and counters
/// the inputs fix (timings would break byte-for-byte determinism, so none go in).
fn header(pre: &Preamble, params: &PrecomputeParams, report: &Report, tiled: &Tiled) -> Header {
    Header {
        fingerprint: pre.fingerprint.clone(),
        atlas_width: params.atlas.width(),
        atlas_height: params.atlas.height(),
        pages: params.atlas.pages,
        page_texel_size: pre.page_texel_size,
        tile_size: params.tile_size,
        entries: pre.entries.len() as u32,
        clusters: tiled.clusters.len() as u32,
        groups: tiled.groups.len() as u32,
        tiles: tiled.tiles.len() as u32,
        tiles_dropped: tiled.tiles_dropped,
        dropped_energy: tiled.dropped_energy,
        drop_threshold: params.drop_threshold,
        provenance: serde_json::json!({
            "estimator": report.estimator, "entries": params.entries, "paths": params.paths,
            "clusters": params.clusters, "atlas": params.atlas.side, "pages": params.atlas.pages,
            "seed": params.seed,
            "max_bounces": params.max_bounces, "kmeans_iterations": params.kmeans_iterations,
            "smooth_radius": params.smooth_radius, "near_radius": params.near_radius,
            "near_links": report.near_links, "echo_radius": params.echo_radius,
            "echo_links": report.echo_links,
            "far_field": params.far_field, "next_bounce": params.next_bounce, "next_cutoff": params.next_cutoff,
            "match_power": params.match_power,
            "far_texels": report.far_texels, "far_pairs": report.far_pairs,
            "groups": params.groups,
            "walks_truncated": report.walks_truncated, "unowned_vertices": report.unowned_vertices,
            "texels": report.texels,
            "entries_enclosed": report.entries_enclosed,
            "cell_triangles": report.cell_triangles, "area_without_entry": report.area_without_entry,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Groups met in descending order (cluster c in group 9 - c % 10) come out ascending, each
    /// the sum of its clusters' contributions.
    #[test]
    fn a_texel_s_group_list_ascends() {
        let grouping = Clustering {
            assignment: (0..40u32).map(|c| 9 - c % 10).collect(),
            members: (0..10u32).map(|g| (0..40).filter(|c| 9 - c % 10 == g).collect()).collect(),
        };
        let panes: Vec<TexelPanes> = (0..5u32)
            .map(|t| {
                (0..40u32)
                    .filter(|c| (c + t) % 3 != 0)
                    .map(|c| (c, Vec3::splat((c * 7 + t) as f32)))
                    .collect()
            })
            .collect();
        for (tp, grouped) in panes.iter().zip(by_group(&panes, &grouping)) {
            assert!(
                grouped.windows(2).all(|w| w[0].0 < w[1].0),
                "{:?}",
                grouped.iter().map(|g| g.0).collect::<Vec<_>>()
            );
            for &(g, v) in &grouped {
                let sum = tp.iter().filter(|(c, _)| 9 - c % 10 == g).fold(Vec3::ZERO, |a, (_, x)| a + *x);
                assert_eq!(v, sum, "group {g}");
            }
            let named = tp.iter().map(|(c, _)| 9 - c % 10).collect::<std::collections::BTreeSet<_>>();
            assert_eq!(grouped.len(), named.len());
        }
    }
}
