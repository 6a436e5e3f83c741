//! The incremental baker (paper 001 §4): a lightmap that is always a complete many-light
//! solution, and budgeted updates that bring it to the level as edited.
//!
//! The lightmap is a sum of baked cells: one per light (its direct light) and one per octree
//! cell of the cut (its virtual lights' indirect light). Each baked cell remembers the level
//! version it was evaluated with. An update takes a cell's light out with that version
//! (negative light, the same shadow rays as when it went in: visibility samples are keyed by
//! cell, light and texel) and puts the new one in with the current version, in one step, so
//! no state ever misses or doubles a cell.
//!
//! After an edit:
//! - every path is traced again and compared (validation); changed paths are replaced;
//! - the VPLs that differ between what is baked and the current paths are found exactly (by
//!   path vertex, position, normal and power). In a region (the smallest subtree holding the
//!   changed cells) where they carry more than `rebuild_share` of the power, the region is
//!   **rebuilt**: its cells taken out and baked again. Elsewhere they go in as **corrections**:
//!   the changed VPLs of all such regions cut into coarse cells of their own, each a set of
//!   virtual lights adding the new VPLs and taking the old ones away. A few VPLs changed in
//!   each of many cells (light that bounced off a moved object spreads everywhere) then cost a
//!   few corrections, not a rebuild of every cell;
//! - baked entries whose VPLs did not change but whose light may now be shadowed differently
//!   are **refreshed**, only at the texels whose shadow rays can meet what moved (texels on
//!   moved objects, and texels whose cone to the entry's bounding sphere passes a box where
//!   moved geometry was or is), and there only along the shadow rays that cross such a box
//!   and that the moved triangles block in one version and not the other. Elsewhere the old
//!   and new values are the same numbers, so leaving them is exact. Paper 001 finds such
//!   cells only through their scattered particles and misses the ones whose few particles did
//!   not touch the edit (its slow "footprint" cases); here every baked entry is checked;
//! - last, when no invalid light is left, regions holding corrections are **consolidated**:
//!   exchanged for the cells a fresh bake would have (the same light in other clusters, so
//!   it changes the lightmap by clustering noise only; `consolidate: false` leaves it out).
//!
//! With a balanced cut (`cells: Some(N)`, paper 001 §4.3 and §5) an edit may also change the
//! cut where no VPL changed (the budget N is shared: light that now lands closer or carries
//! more draws cells from elsewhere). Such a region is a **balancing** update (Refine / Merge:
//! its cells exchanged for the new cut's, the same light in other clusters), interleaved with
//! the validation updates at eq. (2)'s ratio for the next one's invalid share.
//!
//! Updates go in order of invalid flux per unit of expected work (texel x virtual-light
//! evaluations: a rebuild's old and new cells at every texel, a correction's lights, a
//! refresh's texels on what moved and a cheap ray test at the others), so that most of the
//! invalid light is gone soonest. The invalid flux: for a rebuild, the flux of the VPLs that differ
//! between the baked and the new cells (both counted, as paper 001's absolute term) plus the
//! flux of validated path segments that leave the region and now land elsewhere; for a
//! correction, the flux of its VPLs; for a refresh, those segments (paper 001's estimate) and
//! about one path's flux where none was seen.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::hash::{Hash, Hasher};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{DVec3, Vec3};
use prm::bvh::ShadowTarget;
use prm::{Bvh, Light, Scene, TexelSet};
use rayon::prelude::*;

use super::clusters::{
    balanced_cut, bound, cell_box, cell_lights, contains, cut, key, morton, Member, VirtualLight, MAX_DEPTH,
};
use super::level::{Aabb, Changes, Edit, EditError, Level, LightSlot, Version};
use super::paths::{light_flux, luminance, path_count, trace_all, validate, Change, LightPaths, PathParams};
use crate::params::{require, ParamError};
use crate::reference::bake::{soft_visibility, visibility_draws};
use prm::sampling::stream;

/// Incremental-baker parameters.
#[derive(Clone, Debug)]
pub struct BakerParams {
    /// Light paths over all of the level's lights when it is opened (each light gets its share
    /// of the flux, at equal energy per path).
    pub paths: usize,
    /// Bounces a path makes at most. Russian roulette by albedo ends paths without bias; the
    /// cap only bounds the worst case, and a low one is a bias: at 8 the chamber (albedo about
    /// 0.7) lost 4.7 % of its indirect light against the ground truth, at 64 it keeps it
    /// (-1.6 %, the clusters' own).
    pub max_bounces: u32,
    /// VPLs a cell of the cut holds at most (when `cells` is `None`).
    pub leaf_vpls: usize,
    /// `Some(N)`: the cut is balanced by paper 001's metric B for N cells
    /// ([`super::clusters::balanced_cut`]) instead of bounded by `leaf_vpls`.
    pub cells: Option<usize>,
    /// Paper 001's eq. (2) parameter t: the invalid share of the next validation update at
    /// which validation and balancing updates alternate 50:50 (above it, validation goes first
    /// more often; at a share of 1, only validation).
    pub interleave_t: f32,
    pub max_depth: u32,
    /// Virtual lights per cell (paper 001: K = 4).
    pub lights_per_cell: usize,
    /// Virtual lights per sign of a correction (its added and its removed VPLs each make at
    /// most this many). Corrections are exchanged for a fresh bake's cells once no invalid
    /// light is left, so they may be coarser than the cells. Measured (`prm bake --fresh`,
    /// the chamber's carpet moved 1 m, runs alternated; 90 % of the invalid flux after / within
    /// a fresh bake's noise after, in % of a bake): at 40,000 paths 4 gave 1.07-1.11 s / 15-18 %,
    /// 3 0.91-0.99 s / 16-17 %, 2 0.90-0.94 s / 18-21 %; at 20,000 paths 4 gave 0.66-0.82 s /
    /// 26-31 %, 3 0.66 s / 33 %, 2 0.53-0.59 s / 75-79 % (the coarser corrections then sit
    /// above the bake's noise until consolidation replaces them). The doorway's block at
    /// 40,000: 4 1.69-1.82 s / 27-35 %, 2 1.42-1.51 s / 25-26 %.
    pub delta_lights_per_cell: usize,
    /// Smallest plane cluster that becomes a polygon light (paper 001: p_min = 10).
    pub min_polygon: usize,
    /// Shadow rays per texel and virtual light.
    pub visibility_samples: u32,
    /// Shadow rays per texel and virtual light of a correction. Corrections carry little
    /// light (the changed VPLs of regions that kept most of theirs) and are exchanged for a
    /// fresh bake's cells once no invalid light is left, so they are worth fewer rays than
    /// the cells. Measured (`prm bake --fresh`, the chamber's carpet moved 1 m, 20,000 paths,
    /// alternated): 90 % of the invalid flux in 0.80 and 0.67 s at 1 against 1.05 and 0.90 s
    /// at 2 (the 8 corrections were 0.6 of the first 0.9 s); within a fresh bake's noise
    /// after 28 % of a bake at 1 and 26-33 % at 2 (the refreshes' tail decides that).
    pub delta_visibility_samples: u32,
    /// A region whose changed VPLs carry more than this share of its power is rebuilt whole;
    /// below it, the changes go in as corrections (deltas) and the region is consolidated last.
    /// Measured (`prm bake --fresh`, 20,000 paths, twice each): 0.25 -> 0.35 takes 90 % of
    /// the invalid flux from 0.98-0.99 to 0.87 s after the chamber's carpet moved, and
    /// 1.00-1.01 to 0.93-0.95 s after the doorway's block did; within a fresh bake's noise
    /// after 25-27 % and 21-22 % of a bake either way. At 1 even the first bake goes in as
    /// corrections (its changed VPLs carry all of the power, not more).
    pub rebuild_share: f32,
    /// Changed VPLs a correction holds at most: corrections carry little light, so they are
    /// clustered coarser than the cells (fewer virtual lights to evaluate).
    pub delta_leaf_vpls: usize,
    /// Once no invalid light waits, exchange corrections and old cells for the cells a fresh
    /// bake would have (same light, other clusters; as much work again as the corrections).
    pub consolidate: bool,
    pub seed: u64,
}

impl Default for BakerParams {
    fn default() -> Self {
        BakerParams {
            paths: 40_000,
            max_bounces: 64,
            leaf_vpls: 256,
            cells: None,
            interleave_t: 0.1,
            max_depth: 8,
            lights_per_cell: 4,
            delta_lights_per_cell: 3,
            min_polygon: 10,
            visibility_samples: 2,
            delta_visibility_samples: 1,
            rebuild_share: 0.35,
            delta_leaf_vpls: 4096,
            consolidate: true,
            seed: 0,
        }
    }
}

impl BakerParams {
    /// Shadow rays per texel and virtual light of baked entry `k`.
    fn samples(&self, k: CellKey) -> u32 {
        match k {
            CellKey::Delta(..) => self.delta_visibility_samples,
            _ => self.visibility_samples,
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        require((1..=100_000_000).contains(&self.paths), "paths", self.paths, "1 to 1e8")?;
        require((1..=64).contains(&self.max_bounces), "bounces", self.max_bounces, "1 to 64")?;
        require((1..=1_000_000).contains(&self.leaf_vpls), "leaf VPLs", self.leaf_vpls, "1 to 1e6")?;
        require((1..=MAX_DEPTH).contains(&self.max_depth), "octree depth", self.max_depth, "1 to 10")?;
        require(
            (1..=16).contains(&self.lights_per_cell),
            "lights per cell",
            self.lights_per_cell,
            "1 to 16",
        )?;
        require(
            (1..=16).contains(&self.delta_lights_per_cell),
            "correction lights per sign",
            self.delta_lights_per_cell,
            "1 to 16",
        )?;
        require((1..=100_000).contains(&self.min_polygon), "polygon support", self.min_polygon, "1 to 1e5")?;
        require(
            (1..=256).contains(&self.visibility_samples),
            "visibility samples",
            self.visibility_samples,
            "1 to 256",
        )?;
        require(
            (1..=256).contains(&self.delta_visibility_samples),
            "correction visibility samples",
            self.delta_visibility_samples,
            "1 to 256",
        )?;
        require(
            (1..=1_000_000).contains(&self.delta_leaf_vpls),
            "correction VPLs",
            self.delta_leaf_vpls,
            "1 to 1e6",
        )?;
        require((0.0..=1.0).contains(&self.rebuild_share), "rebuild share", self.rebuild_share, "0 to 1")?;
        if let Some(n) = self.cells {
            require((1..=10_000_000).contains(&n), "cells", n, "1 to 1e7")?;
        }
        require(
            self.interleave_t > 0.0 && self.interleave_t < 1.0,
            "interleaving t",
            self.interleave_t,
            "between 0 and 1",
        )?;
        Ok(())
    }
}

/// What fixes a bake's paths and cells besides the parameters: the energy per path and the
/// octree's root box. A level reached by edits and the same level opened afresh bake the same
/// lightmap when they share these (and the ray-offset extent, [`Level::with_extent`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub quantum: f32,
    pub root: Aabb,
}

/// A baked cell's identity.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CellKey {
    /// Direct light of the light with this id.
    Direct(u32),
    /// Indirect light of an octree cell of the cut.
    Cell(u64),
    /// A correction inside an octree cell (its code, and a serial number).
    Delta(u64, u32),
}

#[derive(Clone, Debug)]
enum Source {
    Direct(Light),
    Lights(Arc<Vec<VirtualLight>>),
    /// A correction: light added by `plus`, taken away by `minus`.
    Delta {
        plus: Arc<Vec<VirtualLight>>,
        minus: Arc<Vec<VirtualLight>>,
    },
}

/// What a cell should hold now.
#[derive(Clone, Debug)]
struct Content {
    members: Vec<Member>,
    light: Option<Light>,
    hash: u64,
    flux: Vec3,
}

struct Baked {
    version: Arc<Version>,
    source: Source,
    hash: u64,
    /// Net power (W per channel): a delta's added less its removed power.
    flux: Vec3,
    /// Luminance of the power it moves, both signs counted (refresh priority).
    weight: f32,
    /// The VPLs it holds (a delta: those it adds) and, for a delta, those it takes away.
    plus: Arc<Vec<Member>>,
    minus: Arc<Vec<Member>>,
    bound: (Vec3, f32),
}

#[derive(Clone, Debug)]
enum Work {
    /// Take out every baked entry under the unit's root and bake the wanted cells there.
    Rebuild { add: Vec<(CellKey, Content)> },
    /// Bake a correction for the VPLs of one octree cell that changed.
    Delta { code: u64, plus: Vec<Member>, minus: Vec<Member> },
    /// Evaluate a baked entry again with the current version where visibility may differ.
    Refresh(CellKey),
}

/// A refresh's cost, in full evaluations of one light at one texel (110-120 ns on 2 cores, as
/// rebuilds and corrections take): [`REFRESH_PICK`] a texel of the level, to pick those whose
/// rays may cross what moved, and [`REFRESH_TRACE`] a light and texel on what moved or in the
/// share of the level the moved boxes take of the entry's view. Fitted to 2,119 refreshes'
/// times on the chamber's carpet and the doorway's block (30 and 31 ns): the model before
/// (every texel's test 0.05 of an evaluation, per light) put the doorway's at a third of their
/// time and the chamber's at twice.
const REFRESH_PICK: f32 = 0.26;
/// See [`REFRESH_PICK`].
const REFRESH_TRACE: f32 = 0.27;
/// A correction's virtual light over a cell's, per texel: its polygons span a coarser cell and
/// light more texels, and it takes `delta_visibility_samples` rays (1 by default) against a
/// cell's 2. Fitted on the chamber's carpet (2 cores, quiet): corrections took 85-93 ns a
/// unit of the model at 1.9 against rebuilds' 110-124 ns; 1.9 was measured when corrections
/// took 2 rays. At 1.45, 90 % of the invalid flux in 0.73, 0.65 s (20,000 paths) and 1.01,
/// 1.00 s (40,000) against 0.67, 0.70 and 1.08, 1.04 s at 1.9, alternated: within noise.
const DELTA_LIGHT: f32 = 1.45;

/// The glTF nodes that the edits logged after version `was`, up to `now`, moved.
fn moved_nodes(log: &[(u64, Changes)], was: u64, now: u64) -> BTreeSet<u32> {
    log.iter()
        .filter(|(id, _)| *id > was && *id <= now)
        .flat_map(|(_, c)| c.moved_nodes.iter().copied())
        .collect()
}

/// Virtual lights a baked entry evaluates at each texel (a direct light counts one).
fn lights_of(b: &Baked) -> f32 {
    match &b.source {
        Source::Direct(_) => 1.0,
        Source::Lights(ls) => ls.len() as f32,
        Source::Delta { plus, minus } => (plus.len() + minus.len()) as f32,
    }
}

/// Update tiers: invalid light first, interleaved with balancing by eq. (2) (a region whose VPLs
/// are all valid but whose balanced cut changed: its cells exchanged for the new cut's), then
/// consolidation (which only exchanges a region's corrections and old cells for the cells a
/// fresh bake would have: same light, other clusters).
const TIER_INVALID: u8 = 2;
const TIER_BALANCE: u8 = 1;
const TIER_CONSOLIDATE: u8 = 0;

/// Paper 001's eq. (2): the share of validation updates when the next one's invalid flux is
/// `share` of its cell's flux. The paper calls it quadratic; it is the power
/// log(0.5)/log(t) (0.301 for t = 0.1), which gives 0.5 at `share` = t and 1 at 1.
pub fn validation_ratio(share: f32, t: f32) -> f32 {
    let e = 0.5f32.ln() / t.ln();
    share.clamp(0.0, 1.0).powf(e).max(0.5)
}

#[derive(Clone, Debug)]
struct Unit {
    tier: u8,
    priority: f32,
    /// What it costs, in texel x virtual-light evaluations ([`Baker::plan`]'s model).
    cost: f32,
    /// Invalid flux over the flux of the cells it updates (at most 1), for eq. (2).
    share: f32,
    root: CellKey,
    work: Work,
}

/// A VPL's identity: its path vertex and exact geometry and power.
type VplKey = (u32, u32, u32, [u32; 9]);

fn vpl_key(m: &Member) -> VplKey {
    let b = |v: Vec3| v.to_array().map(f32::to_bits);
    let (p, n, w) = (b(m.position), b(m.normal), b(m.power));
    (m.light, m.path, m.vertex, [p[0], p[1], p[2], n[0], n[1], n[2], w[0], w[1], w[2]])
}

fn region(k: CellKey) -> Option<u64> {
    match k {
        CellKey::Cell(c) | CellKey::Delta(c, _) => Some(c),
        CellKey::Direct(_) => None,
    }
}

/// What [`Baker::step`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    pub cell: CellKey,
    pub kind: UpdateKind,
    /// Invalid flux it resolved (the unit's priority; 0 for a consolidation), W (luminance).
    pub resolved: f32,
    /// What the scheduler expected it to cost, in texel x virtual-light evaluations: invalid
    /// light goes in order of `resolved / cost`.
    pub cost: f32,
    /// Texels it evaluated.
    pub texels: usize,
}

/// What an update did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateKind {
    /// A region whose VPLs changed much: its cells taken out and baked again.
    Rebuild,
    /// A correction: the changed VPLs of a cell added and taken away as virtual lights.
    Delta,
    /// A baked entry evaluated again where moved geometry may shadow it differently.
    Refresh,
    /// A region's corrections and old cells exchanged for a fresh bake's cells (no invalid
    /// light left; the clusters become those of a fresh bake).
    Consolidate,
    /// Refine / Merge: a region whose VPLs did not change but whose balanced cut did, its
    /// cells exchanged for the new cut's (same light, other clusters).
    Balance,
}

/// What [`Baker::apply`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EditReport {
    pub changes: Changes,
    /// Paths replaced (traced again from where they changed, or all of a changed light's).
    pub paths_changed: usize,
    pub paths_total: usize,
    /// VPLs that differ between what is baked and the current paths (both sides counted).
    pub vpls_changed: usize,
    /// Updates now waiting, and their invalid flux (luminance, W).
    pub pending: usize,
    pub invalid_flux: f32,
    pub seconds: f64,
}

/// Power held by the baked cells against the power the current paths carry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Energy {
    /// Indirect power of the baked cells (W per channel), each as it was baked.
    pub baked: Vec3,
    /// What the waiting rebuilds will add less what they will take out.
    pub pending: Vec3,
    /// Power of the current VPLs.
    pub vpls: Vec3,
}

/// The incremental baker.
pub struct Baker {
    params: BakerParams,
    level: Level,
    frame: Frame,
    lights: BTreeMap<u32, LightPaths>,
    baked: BTreeMap<CellKey, Baked>,
    /// Waiting updates, the next one last.
    work: Vec<Unit>,
    /// Edits that moved geometry, by the version they made.
    log: Vec<(u64, Changes)>,
    /// Absolute invalid flux per cell from validated segments, until the cell is updated.
    segments: BTreeMap<CellKey, f32>,
    direct: Vec<DVec3>,
    indirect: Vec<DVec3>,
    /// Next delta serial number.
    serial: u32,
    /// VPLs that differed at the last plan.
    vpls_changed: usize,
    /// Moved triangles between two versions (by version ids), for refreshes.
    movers: HashMap<(u64, u64), Arc<Movers>>,
    /// Eq. (2)'s interleaving: validation updates owed (each adds its ratio, one is spent).
    credit: f32,
}

impl Baker {
    /// Open `scene` (receivers `texels`) and plan its first bake: the lightmap starts dark and
    /// every cell is a waiting update.
    pub fn new(scene: Scene, texels: Arc<TexelSet>, params: BakerParams) -> Result<Baker, ParamError> {
        let (lo, hi) = scene.bounds();
        let pad = 0.01 * (hi - lo).max_element().max(1e-6);
        let root = Aabb { lo: lo - Vec3::splat(pad), hi: hi + Vec3::splat(pad) };
        let bounds = (root.lo, root.hi);
        let total: f32 = scene
            .lights
            .iter()
            .enumerate()
            .map(|(i, l)| luminance(light_flux(&LightSlot { id: i as u32, light: l.clone() }, bounds)))
            .sum();
        let quantum = if total > 0.0 { total / params.paths.max(1) as f32 } else { 1.0 };
        let extent = scene.diagonal();
        Baker::with_frame(scene, texels, params, Frame { quantum, root }, extent)
    }

    /// As [`Baker::new`] with a given [`Frame`] and ray-offset extent.
    pub fn with_frame(
        scene: Scene,
        texels: Arc<TexelSet>,
        params: BakerParams,
        frame: Frame,
        extent: f32,
    ) -> Result<Baker, ParamError> {
        params.validate()?;
        require(frame.quantum > 0.0 && frame.quantum.is_finite(), "path quantum", frame.quantum, "> 0")?;
        let level = Level::with_extent(scene, texels, extent);
        let n = level.texels().texels.len();
        let mut b = Baker {
            params,
            level,
            frame,
            lights: BTreeMap::new(),
            baked: BTreeMap::new(),
            work: Vec::new(),
            log: Vec::new(),
            segments: BTreeMap::new(),
            direct: vec![DVec3::ZERO; n],
            indirect: vec![DVec3::ZERO; n],
            serial: 0,
            vpls_changed: 0,
            movers: HashMap::new(),
            credit: 0.0,
        };
        let v = b.level.current().clone();
        for slot in v.lights.iter() {
            let count = path_count(slot, b.bounds(), frame.quantum, b.params.paths);
            b.lights.insert(slot.id, trace_all(&v, slot, count, b.bounds(), b.path_params()));
        }
        b.plan();
        Ok(b)
    }

    pub fn frame(&self) -> Frame {
        self.frame
    }

    pub fn level(&self) -> &Level {
        &self.level
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        (self.frame.root.lo, self.frame.root.hi)
    }

    fn path_params(&self) -> PathParams {
        PathParams { max_bounces: self.params.max_bounces, seed: self.params.seed }
    }

    /// Apply an edit: validate the paths, and plan the updates it needs. The lightmap is not
    /// touched (it still shows the level before the edit, whole) until [`Baker::step`].
    pub fn apply(&mut self, edit: &Edit) -> Result<EditReport, EditError> {
        let start = Instant::now();
        let old_lights = self.level.current().lights.clone();
        let changes = self.level.apply(edit)?;
        let v = self.level.current().clone();
        let (bounds, pp) = (self.bounds(), self.path_params());
        let mut events = Vec::new();
        let mut changed = 0;
        let mut retraced = BTreeSet::new();
        for &id in &changes.lights {
            let old = self.lights.remove(&id);
            if let Some(old) = &old {
                for path in &old.paths {
                    for x in &path.vertices {
                        events.push(Change::Vpl { position: x.position, power: x.power, added: false });
                    }
                }
                changed += old.paths.len();
            }
            let Some(slot) = v.lights.iter().find(|l| l.id == id) else { continue };
            let before = old_lights.iter().find(|l| l.id == id);
            let lp = match (old, before) {
                // Only the intensity changed: the same paths, their flux scaled (exact and
                // cheap; a fresh bake would give the light a path count for its new flux).
                (Some(mut lp), Some(b))
                    if same_geometry(&b.light, &slot.light) && b.light.intensity.min_element() > 0.0 =>
                {
                    let s = slot.light.intensity / b.light.intensity;
                    for path in &mut lp.paths {
                        for x in &mut path.vertices {
                            x.incident *= s;
                            x.power *= s;
                        }
                    }
                    lp.light = slot.clone();
                    lp
                }
                _ => {
                    let count = path_count(slot, bounds, self.frame.quantum, self.params.paths);
                    trace_all(&v, slot, count, bounds, pp)
                }
            };
            for path in &lp.paths {
                for x in &path.vertices {
                    events.push(Change::Vpl { position: x.position, power: x.power, added: true });
                }
            }
            self.lights.insert(id, lp);
            retraced.insert(id);
        }
        if !changes.moved_nodes.is_empty() || !changes.materials.is_empty() {
            for (id, lp) in self.lights.iter_mut() {
                if !retraced.contains(id) {
                    changed += validate(&v, lp, bounds, pp, &mut events);
                }
            }
        }
        if !changes.moved_nodes.is_empty() {
            self.log.push((v.id, changes.clone()));
        }
        self.note_segments(&events);
        self.plan();
        Ok(EditReport {
            changes,
            paths_changed: changed,
            paths_total: self.lights.values().map(|l| l.paths.len()).sum(),
            vpls_changed: self.vpls_changed,
            pending: self.work.len(),
            invalid_flux: self.invalid_flux(),
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// Attribute validated segments to the cells they leave (after the edit's cut).
    fn note_segments(&mut self, events: &[Change]) {
        let root = self.frame.root;
        for e in events {
            let Change::Segment { from: Some(p), flux } = e else { continue };
            let code = morton(&root, *p, MAX_DEPTH);
            // The baked cell containing it, if any (cells are disjoint).
            let hit = self.baked.keys().find(|k| match k {
                CellKey::Cell(c) => contains(*c, key(MAX_DEPTH, code)),
                _ => false,
            });
            if let Some(k) = hit {
                *self.segments.entry(*k).or_default() += luminance(*flux);
            }
        }
    }

    /// All current VPLs, sorted by cell code and path vertex.
    fn members(&self) -> Vec<Member> {
        let root = self.frame.root;
        let mut m: Vec<Member> = self
            .lights
            .values()
            .flat_map(|lp| {
                let light = lp.light.id;
                lp.paths.iter().enumerate().flat_map(move |(pi, p)| {
                    p.vertices.iter().enumerate().map(move |(vi, x)| {
                        let next = p.vertices.get(vi + 1);
                        Member {
                            code: morton(&root, x.position, MAX_DEPTH),
                            light,
                            path: pi as u32,
                            vertex: vi as u32,
                            position: x.position,
                            normal: x.normal,
                            power: x.power,
                            onward: next.map_or(0.0, |y| luminance(y.power)),
                            reach: next.map_or(0.0, |y| (y.position - x.position).length()),
                        }
                    })
                })
            })
            .collect();
        m.par_sort_unstable_by_key(|x| (x.code, x.light, x.path, x.vertex));
        m
    }

    /// Compare what is baked with what the current paths and lights call for; queue updates.
    fn plan(&mut self) {
        self.movers.clear();
        let v = self.level.current().clone();
        let members = self.members();
        let cells = match self.params.cells {
            Some(n) => balanced_cut(&members, n, self.params.max_depth),
            None => cut(&members, self.params.leaf_vpls, self.params.max_depth),
        };
        // Each cell's members and their digest, cells in parallel (each on its own).
        let mut want: BTreeMap<CellKey, Content> = cells
            .into_par_iter()
            .map(|(k, r)| {
                let ms = members[r].to_vec();
                let mut h = std::collections::hash_map::DefaultHasher::new();
                let mut flux = Vec3::ZERO;
                for m in &ms {
                    vpl_key(m).hash(&mut h);
                    flux += m.power;
                }
                (CellKey::Cell(k), Content { members: ms, light: None, hash: h.finish(), flux })
            })
            .collect();
        for slot in v.lights.iter() {
            let mut h = std::collections::hash_map::DefaultHasher::new();
            format!("{:?}", slot.light).hash(&mut h);
            want.insert(
                CellKey::Direct(slot.id),
                Content {
                    members: Vec::new(),
                    light: Some(slot.light.clone()),
                    hash: h.finish(),
                    flux: Vec3::ZERO,
                },
            );
        }
        // The VPLs that differ: what the baked cells and corrections hold against the paths.
        // A count > 0 is baked but gone (to take away); < 0 is new (to add). Each VPL is
        // represented by its first listing (baked cells in key order, then the paths): its
        // onward flux and reach may differ between listings. Counted in one sort: a hash map
        // over every VPL took 0.18 s of an edit's plan (0.29-0.36 s, the chamber at 40,000
        // paths), the sort 0.05-0.08 s.
        let count: usize = self.baked.values().map(|b| b.plus.len() + b.minus.len()).sum();
        let mut listed: Vec<(u32, u32, u32, u32, i32, &Member)> = Vec::with_capacity(count + members.len());
        let baked = self.baked.values().flat_map(|b| [(1, &b.plus[..]), (-1, &b.minus[..])]);
        for (c, ms) in baked.chain([(-1, &members[..])]) {
            for m in ms.iter() {
                listed.push((m.light, m.path, m.vertex, listed.len() as u32, c, m));
            }
        }
        // Keys are unique (the listing order is one): the parallel sort gives the same order.
        listed.par_sort_unstable_by_key(|x| (x.0, x.1, x.2, x.3));
        // A path vertex is listed a few times (baked, corrected, traced again): its VPLs are
        // told apart by their whole keys, each counted at its first listing.
        let mut diffs: Vec<(i32, Member)> = Vec::new();
        for run in listed.chunk_by(|a, b| (a.0, a.1, a.2) == (b.0, b.1, b.2)) {
            if let [x] = run {
                diffs.push((x.4, *x.5));
                continue;
            }
            // Most vertices: baked once and traced again the same (no allocation for them).
            if let [x, y] = run {
                if x.4 + y.4 == 0 && vpl_key(x.5) == vpl_key(y.5) {
                    continue;
                }
            }
            let keys: Vec<VplKey> = run.iter().map(|x| vpl_key(x.5)).collect();
            for (i, x) in run.iter().enumerate() {
                if keys[..i].contains(&keys[i]) {
                    continue;
                }
                let c: i32 =
                    run.iter().zip(&keys).skip(i).filter(|(_, k)| **k == keys[i]).map(|(y, _)| y.4).sum();
                if c != 0 {
                    diffs.push((c, *x.5));
                }
            }
        }
        diffs.sort_unstable_by_key(|(c, m)| (m.code, vpl_key(m), *c));
        self.vpls_changed = diffs.iter().map(|(c, _)| c.unsigned_abs() as usize).sum();

        // Changed keys, grouped under the shallowest baked or wanted region containing them.
        let changed: Vec<CellKey> = want
            .iter()
            .filter(|(k, c)| self.baked.get(k).map(|b| b.hash) != Some(c.hash))
            .map(|(k, _)| *k)
            .chain(self.baked.keys().filter(|k| !want.contains_key(k)).copied())
            .collect();
        let codes: Vec<u64> = self.baked.keys().chain(want.keys()).filter_map(|k| region(*k)).collect();
        let root_of = |k: CellKey| -> CellKey {
            match region(k) {
                None => k,
                Some(c) => codes
                    .iter()
                    .filter(|x| contains(**x, c))
                    .min_by_key(|x| **x >> 32)
                    .map_or(k, |x| CellKey::Cell(*x)),
            }
        };
        let roots: BTreeSet<CellKey> = changed.iter().map(|&k| root_of(k)).collect();
        // Each differing VPL goes to the root holding it (roots are disjoint).
        let depths: BTreeSet<u32> =
            roots.iter().filter_map(|r| region(*r)).map(|c| (c >> 32) as u32).collect();
        let mut by_root: HashMap<u64, Vec<(i32, Member)>> = HashMap::new();
        for (c, m) in diffs {
            let hit = depths
                .iter()
                .map(|&d| key(d, m.code >> (3 * (MAX_DEPTH - d))))
                .find(|r| roots.contains(&CellKey::Cell(*r)));
            debug_assert!(hit.is_some(), "a changed VPL outside every changed region");
            if let Some(r) = hit {
                by_root.entry(r).or_default().push((c, m));
            }
        }
        let texel_count = self.level.texels().texels.len() as f32;
        let per_cell = self.params.lights_per_cell as f32;
        // What a rebuild costs: its old entries taken out and its cells baked, at every texel.
        let rebuild_cost = |baked_here: &[CellKey], add: &[(CellKey, Content)]| -> f32 {
            let out: f32 = baked_here.iter().map(|k| lights_of(&self.baked[k])).sum();
            let put: f32 = add
                .iter()
                .map(|(_, c)| match c.light {
                    Some(_) => 1.0,
                    None => (c.members.len() as f32).min(per_cell),
                })
                .sum();
            texel_count * (out + put).max(1.0)
        };
        let mut units = Vec::new();
        let mut in_units: BTreeSet<CellKey> = BTreeSet::new();
        // Differing VPLs of the regions that take corrections, and those regions.
        let mut pool: Vec<(i32, Member)> = Vec::new();
        let mut corrected: Vec<CellKey> = Vec::new();
        for r in roots {
            let baked_here: Vec<CellKey> = self.baked.keys().filter(|k| under(r, **k)).copied().collect();
            let seg: f32 = baked_here.iter().filter_map(|k| self.segments.get(k)).sum();
            let CellKey::Cell(code) = r else {
                // A light's direct light: all of its flux is invalid, old and new.
                let add: Vec<(CellKey, Content)> = want.get(&r).map(|c| (r, c.clone())).into_iter().collect();
                let mut differing: f32 =
                    add.iter().filter_map(|(_, c)| c.light.as_ref()).map(|l| self.flux_of(l)).sum();
                for k in &baked_here {
                    if let Source::Direct(l) = &self.baked[k].source {
                        differing += self.flux_of(l);
                    }
                }
                in_units.extend(baked_here.iter().copied());
                units.push(Unit {
                    tier: TIER_INVALID,
                    priority: differing + seg,
                    cost: rebuild_cost(&baked_here, &add),
                    share: 1.0,
                    root: r,
                    work: Work::Rebuild { add },
                });
                continue;
            };
            let diffs = by_root.remove(&code).unwrap_or_default();
            let differing: f32 =
                diffs.iter().map(|(c, m)| c.unsigned_abs() as f32 * luminance(m.power)).sum();
            let held: f32 = baked_here
                .iter()
                .filter(|k| matches!(k, CellKey::Cell(_)))
                .map(|k| luminance(self.baked[k].flux))
                .sum::<f32>()
                + want.iter().filter(|(k, _)| under(r, **k)).map(|(_, c)| luminance(c.flux)).sum::<f32>();
            // Only the balanced cut changed here: no VPL differs and no correction is baked. If
            // geometry moved since the cells were baked, the exchange also brings their
            // shadows up to date, which is invalid light: it then goes as a validation update.
            let balance_only =
                diffs.is_empty() && seg == 0.0 && baked_here.iter().all(|k| matches!(k, CellKey::Cell(_)));
            if balance_only {
                let add = wanted_under(&want, r);
                in_units.extend(baked_here.iter().copied());
                let stale: f32 =
                    baked_here.iter().filter_map(|k| self.refresh_priority(*k, &self.baked[k], v.id)).sum();
                let (tier, priority, share) = match stale > 0.0 {
                    true => (TIER_INVALID, stale, (stale / held.max(f32::MIN_POSITIVE)).min(1.0)),
                    false => (TIER_BALANCE, held, 0.0),
                };
                let cost = rebuild_cost(&baked_here, &add);
                units.push(Unit { tier, priority, cost, share, root: r, work: Work::Rebuild { add } });
            } else if differing > self.params.rebuild_share * held {
                let add = wanted_under(&want, r);
                in_units.extend(baked_here.iter().copied());
                units.push(Unit {
                    tier: TIER_INVALID,
                    priority: differing + seg,
                    cost: rebuild_cost(&baked_here, &add),
                    share: ((differing + seg) / held.max(f32::MIN_POSITIVE)).min(1.0),
                    root: r,
                    work: Work::Rebuild { add },
                });
            } else {
                pool.extend(diffs);
                corrected.push(r);
            }
        }
        // Corrections: the changed VPLs of all those regions, cut into cells of their own (a
        // few VPLs changed in many cells make a few corrections, not one per cell).
        pool.sort_unstable_by_key(|(c, m)| (m.code, vpl_key(m), *c));
        let mut dm = Vec::with_capacity(pool.len());
        let mut sign = Vec::with_capacity(pool.len());
        for (c, m) in &pool {
            for _ in 0..c.unsigned_abs() {
                dm.push(*m);
                sign.push(*c < 0);
            }
        }
        let mut delta_codes = Vec::new();
        for (cell, range) in cut(&dm, self.params.delta_leaf_vpls, self.params.max_depth) {
            let (mut plus, mut minus) = (Vec::new(), Vec::new());
            for i in range {
                if sign[i] {
                    plus.push(dm[i])
                } else {
                    minus.push(dm[i])
                }
            }
            let priority = plus.iter().chain(&minus).map(|m| luminance(m.power)).sum();
            delta_codes.push(cell);
            let per_sign = self.params.delta_lights_per_cell as f32;
            let lights = (plus.len() as f32).min(per_sign) + (minus.len() as f32).min(per_sign);
            let cost = DELTA_LIGHT * texel_count * lights;
            units.push(Unit {
                tier: TIER_INVALID,
                priority,
                cost: cost.max(1.0),
                share: 1.0,
                root: CellKey::Cell(cell),
                work: Work::Delta { code: cell, plus, minus },
            });
        }
        // Consolidation, last: regions holding corrections (made now or earlier) or whose cut
        // changed, grouped so that each holds its corrections whole.
        if self.params.consolidate {
            // The shallowest of these holding a region is its group: groups are disjoint, and
            // a correction and the regions whose VPLs it holds (nested cells) share one. A group
            // may hold a region rebuilt above: it is consolidated again (after it).
            let all: Vec<u64> = codes.iter().copied().chain(delta_codes.iter().copied()).collect();
            let group_of = |c: u64| -> u64 {
                all.iter().copied().filter(|x| contains(*x, c)).min_by_key(|x| *x >> 32).unwrap_or(c)
            };
            let groups: BTreeSet<u64> = corrected
                .iter()
                .filter_map(|r| region(*r))
                .chain(delta_codes.iter().copied())
                .map(group_of)
                .collect();
            for g in groups {
                let r = CellKey::Cell(g);
                let add = wanted_under(&want, r);
                units.push(Unit {
                    tier: TIER_CONSOLIDATE,
                    priority: 0.0,
                    cost: 1.0,
                    share: 0.0,
                    root: r,
                    work: Work::Rebuild { add },
                });
            }
        }
        // Refreshes: baked entries outside the rebuilds that an edit since their bake may shadow.
        let mut on_moved: HashMap<u64, f32> = HashMap::new();
        for (k, b) in &self.baked {
            if in_units.contains(k) {
                continue;
            }
            if let Some((priority, view)) = self.refresh_estimate(*k, b, v.id) {
                // A refresh tests every texel's cone against the moved boxes, evaluates the
                // texels on what moved twice, and traces the rays of the others that cross
                // the boxes.
                let moved =
                    *on_moved.entry(b.version.id).or_insert_with(|| self.texels_moved_since(b.version.id));
                let cost =
                    REFRESH_PICK * texel_count + REFRESH_TRACE * lights_of(b) * (moved + texel_count * view);
                // A direct light's entry holds its flux; a cell's, its VPLs'.
                let whole = match &b.source {
                    Source::Direct(l) => self.flux_of(l),
                    _ => b.weight,
                };
                let share = (priority / whole.max(f32::MIN_POSITIVE)).min(1.0);
                units.push(Unit {
                    tier: TIER_INVALID,
                    priority,
                    cost: cost.max(1.0),
                    share,
                    root: *k,
                    work: Work::Refresh(*k),
                });
            }
        }
        let rank = |w: &Work| match w {
            Work::Rebuild { .. } => 0,
            Work::Delta { .. } => 1,
            Work::Refresh(_) => 2,
        };
        // Invalid light goes in order of flux resolved per unit of cost, so that most of it is
        // gone soonest; balancing by the flux it moves.
        let urgency = |u: &Unit| match u.tier {
            TIER_INVALID => u.priority / u.cost,
            _ => u.priority,
        };
        units.sort_by(|a, b| {
            (a.tier, urgency(a))
                .partial_cmp(&(b.tier, urgency(b)))
                .unwrap_or(std::cmp::Ordering::Equal)
                .then(b.root.cmp(&a.root))
                .then(rank(&b.work).cmp(&rank(&a.work)))
        });
        self.work = units;
        // Eq. (2)'s interleaving starts half way, so that the first update after an edit is
        // the most urgent validation one (the ratio is at least 0.5).
        self.credit = 0.5;
        // Entries no edit can have changed may forget their old version.
        let moved_since = |id: u64| self.log.iter().any(|(e, _)| *e > id);
        let cur = v.clone();
        let keys: Vec<CellKey> = self
            .baked
            .iter()
            .filter(|(k, b)| !in_units.contains(k) && b.version.id != cur.id && !moved_since(b.version.id))
            .map(|(k, _)| *k)
            .collect();
        for k in keys {
            if let Some(b) = self.baked.get_mut(&k) {
                b.version = cur.clone();
            }
        }
        let oldest = self.baked.values().map(|b| b.version.id).min().unwrap_or(v.id);
        self.log.retain(|(id, _)| *id > oldest);
    }

    /// A light's emitted flux (luminance, W) in this bake's bounds.
    fn flux_of(&self, l: &Light) -> f32 {
        luminance(light_flux(&LightSlot { id: 0, light: l.clone() }, self.bounds()))
    }

    /// The invalid flux a baked entry may carry because geometry moved since it was baked
    /// (with the current version `now`); `None` when nothing moved since.
    fn refresh_priority(&self, k: CellKey, b: &Baked, now: u64) -> Option<f32> {
        self.refresh_estimate(k, b, now).map(|(flux, _)| flux)
    }

    /// [`Self::refresh_priority`] and the largest share of the entry's view that a box where
    /// geometry moved since takes (about the solid angle over 2 pi).
    fn refresh_estimate(&self, k: CellKey, b: &Baked, now: u64) -> Option<(f32, f32)> {
        if b.version.id == now {
            return None;
        }
        let since: Vec<&Changes> =
            self.log.iter().filter(|(id, _)| *id > b.version.id).map(|(_, c)| c).collect();
        if since.is_empty() {
            return None;
        }
        let (c, r) = b.bound;
        let view = since
            .iter()
            .flat_map(|ch| ch.regions.iter())
            .map(|bx| {
                let half = 0.5 * (bx.hi - bx.lo).length() + r;
                let d = (c - c.clamp(bx.lo, bx.hi)).length();
                half * half / (half * half + d * d)
            })
            .fold(0.0f32, f32::max);
        // A direct light's shadow moved: its flux, as much as the moved boxes take of its
        // view. Virtual lights: the flux of their paths' next segments that now land
        // elsewhere (paper 001's estimate, unbiased), and where none did, at most about one
        // path's worth (the edit's shadow may still fall between the paths).
        let flux = match &b.source {
            Source::Direct(l) => self.flux_of(l) * view,
            _ => self.segments.get(&k).copied().unwrap_or(0.0) + self.frame.quantum * view,
        };
        Some((flux, view))
    }

    /// Texels on the nodes that edits since version `id` moved.
    fn texels_moved_since(&self, id: u64) -> f32 {
        let nodes = moved_nodes(&self.log, id, u64::MAX);
        if nodes.is_empty() {
            return 0.0;
        }
        let v = self.level.current();
        let texels = self.level.texels();
        texels.texels.iter().filter(|t| nodes.contains(&v.scene.triangles[t.triangle as usize].node)).count()
            as f32
    }

    /// Updates waiting.
    pub fn pending(&self) -> usize {
        self.work.len()
    }

    /// Invalid flux still waiting (luminance, W); consolidations carry none.
    pub fn invalid_flux(&self) -> f32 {
        self.work.iter().filter(|u| u.tier == TIER_INVALID).map(|u| u.priority).sum()
    }

    pub fn converged(&self) -> bool {
        self.work.is_empty()
    }

    /// Whether invalid light waits (consolidations aside): when false, the lightmap is a
    /// complete many-light solution of the current level, its clusters perhaps not yet those
    /// of a fresh bake.
    pub fn valid(&self) -> bool {
        self.work.iter().all(|u| u.tier != TIER_INVALID)
    }

    /// The next update: the most urgent validation update, or, by eq. (2)'s ratio for its
    /// invalid share, the largest balancing update; consolidation last.
    fn next_unit(&mut self) -> Option<Unit> {
        let top = self.work.last()?;
        if top.tier == TIER_INVALID {
            // Units are sorted by tier: the balancing ones end where the validation ones start.
            let at = self.work.partition_point(|u| u.tier < TIER_INVALID);
            if at > 0 && self.work[at - 1].tier == TIER_BALANCE {
                self.credit += validation_ratio(top.share, self.params.interleave_t);
                if self.credit >= 1.0 {
                    self.credit -= 1.0;
                } else {
                    return Some(self.work.remove(at - 1));
                }
            }
        }
        self.work.pop()
    }

    /// Run the most urgent update; `None` when there is none.
    pub fn step(&mut self) -> Option<StepReport> {
        let unit = self.next_unit()?;
        let v = self.level.current().clone();
        let texels = self.level.texels().clone();
        let seed = self.params.seed;
        let root = self.frame.root;
        let (k_lights, p_min) = (self.params.lights_per_cell, self.params.min_polygon);
        let resolved = if unit.tier == TIER_INVALID { unit.priority } else { 0.0 };
        let cost = unit.cost;
        match unit.work {
            Work::Rebuild { add } => {
                let remove: Vec<CellKey> =
                    self.baked.keys().filter(|k| under(unit.root, **k)).copied().collect();
                let old: Vec<(CellKey, Baked)> =
                    remove.iter().filter_map(|k| self.baked.remove(k).map(|b| (*k, b))).collect();
                let new: Vec<(CellKey, Baked)> = add
                    .into_par_iter()
                    .map(|(k, c)| {
                        let (source, bnd) = match (&k, c.light) {
                            (CellKey::Direct(_), Some(l)) => {
                                // An area light casts shadows from all of its aperture.
                                let b = (l.position, l.aperture_radius());
                                (Source::Direct(l), b)
                            }
                            (CellKey::Cell(code), _) => {
                                let ls = cell_lights(&c.members, &cell_box(&root, *code), k_lights, p_min);
                                let b = bound(&ls);
                                (Source::Lights(Arc::new(ls)), b)
                            }
                            _ => unreachable!("wanted cells are direct lights or octree cells"),
                        };
                        let weight = luminance(c.flux);
                        let baked = Baked {
                            version: v.clone(),
                            source,
                            hash: c.hash,
                            flux: c.flux,
                            weight,
                            plus: Arc::new(c.members),
                            minus: Arc::new(Vec::new()),
                            bound: bnd,
                        };
                        (k, baked)
                    })
                    .collect();
                self.accumulate(&old, &new);
                for k in &remove {
                    self.segments.remove(k);
                }
                self.baked.extend(new);
                let kind = match unit.tier {
                    TIER_INVALID => UpdateKind::Rebuild,
                    TIER_BALANCE => UpdateKind::Balance,
                    _ => UpdateKind::Consolidate,
                };
                Some(StepReport { cell: unit.root, kind, resolved, cost, texels: texels.texels.len() })
            }
            Work::Delta { code, plus, minus } => {
                let bx = cell_box(&root, code);
                let k_delta = self.params.delta_lights_per_cell;
                let (pl, ml) = rayon::join(
                    || cell_lights(&plus, &bx, k_delta, p_min),
                    || cell_lights(&minus, &bx, k_delta, p_min),
                );
                let both: Vec<VirtualLight> = pl.iter().chain(&ml).cloned().collect();
                let sum = |ms: &[Member]| ms.iter().fold(Vec3::ZERO, |a, m| a + m.power);
                let (fp, fm) = (sum(&plus), sum(&minus));
                let k = CellKey::Delta(code, self.serial);
                self.serial += 1;
                let baked = Baked {
                    version: v.clone(),
                    source: Source::Delta { plus: Arc::new(pl), minus: Arc::new(ml) },
                    hash: 0,
                    flux: fp - fm,
                    weight: luminance(fp) + luminance(fm),
                    plus: Arc::new(plus),
                    minus: Arc::new(minus),
                    bound: bound(&both),
                };
                let new = [(k, baked)];
                self.accumulate(&[], &new);
                let [(k, baked)] = new;
                self.baked.insert(k, baked);
                Some(StepReport {
                    cell: k,
                    kind: UpdateKind::Delta,
                    resolved,
                    cost,
                    texels: texels.texels.len(),
                })
            }
            Work::Refresh(k) => {
                let old = self.baked.get(&k)?.version.clone();
                let movers = self.movers(&old, &v);
                let b = self.baked.get_mut(&k)?;
                let (c, r) = b.bound;
                let directional = match &b.source {
                    Source::Direct(l) if !l.is_positional() => Some(-l.direction),
                    _ => None,
                };
                let crosses = |bx: &Aabb, p: Vec3, grow: f32| -> bool {
                    match directional {
                        Some(d) => bx.grown(grow).meets_segment(p, d, f32::INFINITY),
                        None => bx.meets_cone(p, c, r, grow),
                    }
                };
                // A segment from within `grow` of p to the ball is within `grow` of one from
                // p at every point (the same argument as a refresh's per-light test): a part
                // no segment from a group's ball crosses is crossed by none of its texels'.
                let picked = movers.groups.pick(
                    |g, grow| movers.parts_meeting(|bx| crosses(bx, g, grow)),
                    &movers.on_moved,
                    |i, parts| {
                        // The whole boxes first, as in `Movers::meets`: most texels fail there.
                        let p = v.frames[i].0;
                        movers.boxes.iter().any(|bx| crosses(bx, p, 0.0))
                            && parts.iter().any(|bx| crosses(bx, p, 0.0))
                    },
                );
                let was = Baked {
                    version: old,
                    source: b.source.clone(),
                    hash: b.hash,
                    flux: b.flux,
                    weight: b.weight,
                    plus: b.plus.clone(),
                    minus: b.minus.clone(),
                    bound: b.bound,
                };
                b.version = v.clone();
                let b = &*b;
                let balls = Balls::of(&b.source);
                let s = self.params.samples(k);
                let deltas: Vec<(DVec3, DVec3)> = picked
                    .par_iter()
                    .map(|&i| {
                        if !movers.on_moved[i] {
                            // The texel stayed: only the shadow rays that cross what moved differ.
                            return shadow_change(&was, b, k, i, s, seed, &movers, &balls);
                        }
                        let (od, oi) = evaluate(&was, k, i, s, seed);
                        let (nd, ni) = evaluate(b, k, i, s, seed);
                        (nd - od, ni - oi)
                    })
                    .collect();
                for (&i, (dd, di)) in picked.iter().zip(deltas) {
                    self.direct[i] += dd;
                    self.indirect[i] += di;
                }
                self.segments.remove(&k);
                Some(StepReport { cell: k, kind: UpdateKind::Refresh, resolved, cost, texels: picked.len() })
            }
        }
    }

    /// What moved between versions `was` and `now`, worked out once for all the refreshes
    /// between them (kept until the next plan).
    fn movers(&mut self, was: &Arc<Version>, now: &Arc<Version>) -> Arc<Movers> {
        let log = &self.log;
        let extent = self.level.extent();
        let texels = self.level.texels();
        // Shadow rays leave a texel a little off its surface: a margin covers it.
        let margin = 1e-3 * (self.frame.root.hi - self.frame.root.lo).length();
        let root = self.frame.root;
        self.movers
            .entry((was.id, now.id))
            .or_insert_with(|| {
                let nodes = moved_nodes(log, was.id, now.id);
                let since = log.iter().filter(|(id, _)| *id > was.id && *id <= now.id).map(|(_, c)| c);
                let boxes = since.flat_map(|c| c.regions.iter().map(|x| x.grown(margin))).collect();
                let on_node = |t: u32| nodes.contains(&now.scene.triangles[t as usize].node);
                let tris: Vec<u32> = (0..now.scene.triangles.len() as u32).filter(|&t| on_node(t)).collect();
                let on_moved = texels.texels.par_iter().map(|t| on_node(t.triangle)).collect();
                let (w, n) = rayon::join(
                    || Bvh::build_subset(&was.scene, &tris, extent),
                    || Bvh::build_subset(&now.scene, &tris, extent),
                );
                let groups = TexelGroups::new(&now.frames, &root);
                let mut parts = parts_of(&was.scene, &tris);
                parts.extend(parts_of(&now.scene, &tris));
                let parts = parts.into_iter().map(|x| x.grown(margin)).collect();
                Arc::new(Movers { was: w, now: n, boxes, parts, on_moved, groups })
            })
            .clone()
    }

    /// Take `old` entries' light out (each with its own version) and put `new` in, at every
    /// texel, in one pass.
    fn accumulate(&mut self, old: &[(CellKey, Baked)], new: &[(CellKey, Baked)]) {
        let params = &self.params;
        let seed = params.seed;
        self.direct.par_iter_mut().zip(self.indirect.par_iter_mut()).enumerate().for_each(|(i, (d, ind))| {
            for (k, b) in old {
                let (ed, ei) = evaluate(b, *k, i, params.samples(*k), seed);
                *d -= ed;
                *ind -= ei;
            }
            for (k, b) in new {
                let (ed, ei) = evaluate(b, *k, i, params.samples(*k), seed);
                *d += ed;
                *ind += ei;
            }
        });
    }

    /// Run updates for about `budget` of wall time (at least one, if any waits).
    pub fn run_for(&mut self, budget: Duration) -> usize {
        let start = Instant::now();
        let mut n = 0;
        while self.step().is_some() {
            n += 1;
            if start.elapsed() >= budget {
                break;
            }
        }
        n
    }

    /// Run updates until none waits.
    pub fn converge(&mut self) -> usize {
        let mut n = 0;
        while self.step().is_some() {
            n += 1;
        }
        n
    }

    /// (direct, indirect) irradiance per receiver texel (W/m²).
    pub fn lightmap(&self) -> (Vec<Vec3>, Vec<Vec3>) {
        (
            self.direct.iter().map(|d| d.as_vec3()).collect(),
            self.indirect.iter().map(|d| d.as_vec3()).collect(),
        )
    }

    /// The energy ledger (see [`Energy`]).
    pub fn energy(&self) -> Energy {
        let baked = self
            .baked
            .values()
            .filter(|b| !matches!(b.source, Source::Direct(_)))
            .fold(Vec3::ZERO, |a, b| a + b.flux);
        let mut pending = Vec3::ZERO;
        for u in self.work.iter().filter(|u| u.tier == TIER_INVALID) {
            match &u.work {
                Work::Rebuild { add } => {
                    pending += add.iter().fold(Vec3::ZERO, |a, (_, c)| a + c.flux);
                    pending -= self
                        .baked
                        .iter()
                        .filter(|(k, b)| under(u.root, **k) && !matches!(b.source, Source::Direct(_)))
                        .fold(Vec3::ZERO, |a, (_, b)| a + b.flux);
                }
                Work::Delta { plus, minus, .. } => {
                    pending += plus.iter().fold(Vec3::ZERO, |a, m| a + m.power);
                    pending -= minus.iter().fold(Vec3::ZERO, |a, m| a + m.power);
                }
                Work::Refresh(_) => {}
            }
        }
        let vpls = self
            .lights
            .values()
            .flat_map(|lp| lp.paths.iter().flat_map(|p| p.vertices.iter()))
            .fold(Vec3::ZERO, |a, x| a + x.power);
        Energy { baked, pending, vpls }
    }

    /// The lightmap as the sum of the baked entries, each evaluated afresh with its own
    /// version (a check: equals [`Baker::lightmap`] up to rounding, whatever the updates did).
    pub fn recomputed(&self) -> (Vec<Vec3>, Vec<Vec3>) {
        let (params, seed) = (&self.params, self.params.seed);
        (0..self.direct.len())
            .into_par_iter()
            .map(|i| {
                let (mut d, mut ind) = (DVec3::ZERO, DVec3::ZERO);
                for (k, b) in &self.baked {
                    let (ed, ei) = evaluate(b, *k, i, params.samples(*k), seed);
                    d += ed;
                    ind += ei;
                }
                (d.as_vec3(), ind.as_vec3())
            })
            .unzip()
    }

    /// Whether the baked cells are disjoint (no cell inside another): no VPL counted twice.
    pub fn cells_disjoint(&self) -> bool {
        let cells: Vec<u64> = self
            .baked
            .keys()
            .filter_map(|k| match k {
                CellKey::Cell(c) => Some(*c),
                _ => None,
            })
            .collect();
        cells.iter().all(|a| cells.iter().all(|b| a == b || !contains(*a, *b)))
    }

    /// Baked cells and their virtual lights.
    pub fn counts(&self) -> (usize, usize) {
        let lights = self
            .baked
            .values()
            .map(|b| match &b.source {
                Source::Lights(l) => l.len(),
                Source::Delta { plus, minus } => plus.len() + minus.len(),
                Source::Direct(_) => 1,
            })
            .sum();
        (self.baked.len(), lights)
    }
}

fn same_geometry(a: &Light, b: &Light) -> bool {
    a.kind == b.kind
        && a.position == b.position
        && a.direction == b.direction
        && a.range == b.range
        && a.aperture == b.aperture
        && a.profile == b.profile
}

/// The wanted cells under region root `r`.
fn wanted_under(want: &BTreeMap<CellKey, Content>, r: CellKey) -> Vec<(CellKey, Content)> {
    want.iter().filter(|(k, _)| under(r, **k)).map(|(k, c)| (*k, c.clone())).collect()
}

/// Whether region root `r` holds baked or wanted entry `k`.
fn under(r: CellKey, k: CellKey) -> bool {
    match (r, region(k)) {
        (CellKey::Cell(a), Some(b)) => contains(a, b),
        _ => r == k,
    }
}

/// Seed of an entry's visibility streams at texel `i`: taking an entry out draws the same
/// shadow rays as putting it in.
fn salt(k: CellKey, i: usize) -> u64 {
    match k {
        CellKey::Cell(c) => c,
        CellKey::Delta(c, serial) => c ^ (serial as u64 + 1) << 40,
        CellKey::Direct(id) => id as u64,
    }
    .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ i as u64
}

/// What moved between two versions: the moved triangles in each (ray tests over them alone),
/// the boxes where they were or are (grown by a ray-offset margin), and which texels lie on them.
struct Movers {
    was: Bvh,
    now: Bvh,
    boxes: Vec<Aabb>,
    /// The moved triangles' boxes in both versions, a few triangles each (grown like `boxes`):
    /// the carpet of the chamber is a runner along the floor and a dais at its end, whose
    /// one box is a slab of the floor that most shadow rays near the floor cross.
    parts: Vec<Aabb>,
    on_moved: Vec<bool>,
    groups: TexelGroups,
}

impl Movers {
    /// Whether `test` holds for a box where moved geometry was or is: tried on the whole
    /// boxes first (most tests fail there), then on the parts, which hold the moved
    /// triangles tighter. A test that holds for a box holds for any box holding it.
    fn meets(&self, test: impl Fn(&Aabb) -> bool) -> bool {
        self.boxes.iter().any(&test) && self.parts.iter().any(&test)
    }

    /// The parts `test` holds for (none when it holds for no whole box).
    fn parts_meeting(&self, test: impl Fn(&Aabb) -> bool) -> Vec<&Aabb> {
        if !self.boxes.iter().any(&test) {
            return Vec::new();
        }
        self.parts.iter().filter(|bx| test(bx)).collect()
    }
}

/// Splits of a moved object's box a refresh tests against: at most 2^this parts a version.
const PART_DEPTH: u32 = 4;

/// The boxes of `tris` in `scene`, split while splitting tightens them: a box is cut in two
/// (its triangles in centroid order along an axis) where the halves' surfaces (what a random
/// ray meets in proportion to) sum least, when that is under 4/5 of the whole's. A block stays one
/// box (its halves are about as large as it); the chamber's carpet, a runner along the floor
/// and a dais at its end, whose one box is a slab of the floor, splits into its pieces.
fn parts_of(scene: &Scene, tris: &[u32]) -> Vec<Aabb> {
    let mut items: Vec<(Vec3, Aabb)> = tris
        .iter()
        .map(|&t| {
            let c = scene.corners(t as usize);
            ((c[0] + c[1] + c[2]) / 3.0, Aabb::of(c))
        })
        .collect();
    let mut out = Vec::new();
    split_parts(&mut items, PART_DEPTH, &mut out);
    out
}

fn split_parts(items: &mut [(Vec3, Aabb)], depth: u32, out: &mut Vec<Aabb>) {
    let whole = |xs: &[(Vec3, Aabb)]| Aabb::of(xs.iter().flat_map(|(_, b)| [b.lo, b.hi]));
    let area = |b: &Aabb| {
        let e = (b.hi - b.lo).max(Vec3::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    };
    if items.is_empty() {
        return;
    }
    let all = whole(items);
    if depth > 0 && items.len() > 1 {
        // The split (along an axis, in centroid order) whose halves' surfaces sum least.
        let mut best: Option<(f32, usize, usize)> = None;
        for axis in 0..3 {
            items.sort_by(|a, b| a.0[axis].total_cmp(&b.0[axis]));
            let mut before = vec![0.0f32; items.len()];
            let mut b = Aabb::of(std::iter::empty());
            for (k, (_, x)) in items.iter().enumerate() {
                b = Aabb { lo: b.lo.min(x.lo), hi: b.hi.max(x.hi) };
                before[k] = area(&b);
            }
            let mut b = Aabb::of(std::iter::empty());
            for k in (1..items.len()).rev() {
                b = Aabb { lo: b.lo.min(items[k].1.lo), hi: b.hi.max(items[k].1.hi) };
                let sum = before[k - 1] + area(&b);
                if best.is_none_or(|(s, _, _)| sum < s) {
                    best = Some((sum, axis, k));
                }
            }
        }
        if let Some((_, axis, k)) = best.filter(|(sum, _, _)| *sum < 0.8 * area(&all)) {
            items.sort_by(|a, b| a.0[axis].total_cmp(&b.0[axis]));
            let (l, r) = items.split_at_mut(k);
            split_parts(l, depth - 1, out);
            split_parts(r, depth - 1, out);
            return;
        }
    }
    out.push(all);
}

/// Texels gathered in small groups of neighbours (in the Morton order of their positions in
/// the newer version), each with a ball holding its texels' positions: a refresh tests a
/// group's ball against the moved boxes before its texels (most groups lie nowhere near what
/// an entry's light crosses to reach them).
struct TexelGroups {
    order: Vec<u32>,
    /// Centre, radius and the group's range of `order`.
    groups: Vec<(Vec3, f32, std::ops::Range<usize>)>,
}

/// Texels a group holds at most.
const GROUP_TEXELS: usize = 64;

impl TexelGroups {
    fn new(frames: &[(Vec3, Vec3, f32)], root: &Aabb) -> TexelGroups {
        let mut order: Vec<u32> = (0..frames.len() as u32).collect();
        order.sort_by_key(|&i| (morton(root, frames[i as usize].0, MAX_DEPTH), i));
        let groups = (0..order.len())
            .step_by(GROUP_TEXELS)
            .map(|start| {
                let range = start..(start + GROUP_TEXELS).min(order.len());
                let pts = || order[range.clone()].iter().map(|&i| frames[i as usize].0);
                let (lo, hi) =
                    pts().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| (lo.min(p), hi.max(p)));
                let c = 0.5 * (lo + hi);
                (c, pts().map(|p| (p - c).length()).fold(0.0, f32::max), range)
            })
            .collect();
        TexelGroups { order, groups }
    }

    /// The texels in `always` or for which `pick` holds, ascending. `near` gives, for a
    /// group's ball (centre, radius), the boxes its texels may meet, and `pick` tests a
    /// texel against those: `near` must list every box for which `pick` can hold at a point
    /// of the ball. A group with none is passed over whole.
    fn pick<'a>(
        &self,
        near: impl Fn(Vec3, f32) -> Vec<&'a Aabb> + Sync,
        always: &[bool],
        pick: impl Fn(usize, &[&'a Aabb]) -> bool + Sync,
    ) -> Vec<usize> {
        let (near, pick) = (&near, &pick);
        let mut picked: Vec<usize> = self
            .groups
            .par_iter()
            .flat_map_iter(|(c, r, range)| {
                let parts = near(*c, *r);
                self.order[range.clone()]
                    .iter()
                    .map(|&i| i as usize)
                    .filter(|&i| always[i] || (!parts.is_empty() && pick(i, &parts)))
                    .collect::<Vec<_>>()
            })
            .collect();
        picked.sort_unstable();
        picked
    }
}

/// Stream bases of a cell's virtual lights and of a correction's subtracted ones.
const STREAM_PLUS: u64 = 50;
const STREAM_MINUS: u64 = 66;

/// How a baked entry's (direct, indirect) light at a texel that did not move changes from its
/// version in `was` to the one in `now`: the same shadow rays are drawn (same streams; a
/// direct light's from the texel's position), and only those that cross a box where geometry
/// moved are traced, in both versions. A ray that crosses none meets the same triangles in
/// both, so this equals the difference of two full evaluations (exactly for virtual lights;
/// to round-off for an area light some of whose rays changed and some not, whose evaluation
/// may sum its parts' light another way, `prm::bvh::shadowed_irradiance`), for the cost of
/// the rays the edit can have changed.
#[allow(clippy::too_many_arguments)]
fn shadow_change(
    was: &Baked,
    now: &Baked,
    k: CellKey,
    i: usize,
    s: u32,
    seed: u64,
    movers: &Movers,
    balls: &Balls,
) -> (DVec3, DVec3) {
    let (p, n, eps) = now.version.frames[i];
    let salt = salt(k, i);
    let change = |ls: &[VirtualLight], balls: &[(Vec3, f32)], base: u64| -> DVec3 {
        let mut sum = DVec3::ZERO;
        for ((li, l), &(c, r)) in ls.iter().enumerate().zip(balls) {
            // A shadow ray ends at one of the light's samples, inside its ball: at any point
            // along it, it is within r of the same point of the segment to the ball's centre.
            // So when that segment misses every box grown by r, no draw can cross one, and
            // the light's draws (its own stream, nothing shared) need not be made at all.
            let (d, len) = ((c - p).normalize_or_zero(), (c - p).length());
            if !movers.meets(|bx| bx.grown(r).meets_segment(p, d, len)) {
                continue;
            }
            // The draws do not depend on the irradiance (each light has its own stream), so
            // the costly form factor waits until a ray is known to differ.
            let mut rng = stream(seed, base + li as u64, salt);
            let r2_min = l.polygon.area() / l.samples.len().max(1) as f32;
            let mut seen = 0i32;
            visibility_draws(p, n, &l.samples, r2_min, s, &mut rng, |j| {
                let (q, nq) = l.samples[j];
                let (d, len) = ((q - p).normalize_or_zero(), (q - p).length());
                if !movers.meets(|bx| bx.meets_segment(p, d, len)) {
                    return;
                }
                // Visibility is the product of the moved triangles' and the rest's (same
                // offsets): only a ray the moved triangles block in one version and not in
                // the other can differ, and then by the rest's visibility.
                let (blocked_was, blocked_now) =
                    (!movers.was.visible(p, n, q, nq), !movers.now.visible(p, n, q, nq));
                if blocked_was && !blocked_now {
                    seen += now.version.bvh.visible(p, n, q, nq) as i32;
                } else if blocked_now && !blocked_was {
                    seen -= was.version.bvh.visible(p, n, q, nq) as i32;
                }
            });
            if seen != 0 {
                let e = l.polygon.irradiance(p, n, eps);
                sum += (e * (seen as f32 / s as f32)).as_dvec3();
            }
        }
        sum
    };
    match &now.source {
        Source::Direct(l) => {
            let ray_change = |t: ShadowTarget| -> f32 {
                let (d, len) = t.segment(p);
                if !movers.meets(|bx| bx.meets_segment(p, d, len)) {
                    return 0.0;
                }
                let (blocked_was, blocked_now) =
                    (!movers.was.visible_to(p, n, t), !movers.now.visible_to(p, n, t));
                if blocked_was && !blocked_now {
                    now.version.bvh.visible_to(p, n, t) as u8 as f32
                } else if blocked_now && !blocked_was {
                    -(was.version.bvh.visible_to(p, n, t) as u8 as f32)
                } else {
                    0.0
                }
            };
            (prm::bvh::shadowed_irradiance(l, p, n, ray_change).as_dvec3(), DVec3::ZERO)
        }
        Source::Lights(ls) => (DVec3::ZERO, change(ls, &balls.plus, STREAM_PLUS)),
        Source::Delta { plus, minus } => {
            (DVec3::ZERO, change(plus, &balls.plus, STREAM_PLUS) - change(minus, &balls.minus, STREAM_MINUS))
        }
    }
}

/// Each virtual light's ball (centre, radius) holding its samples, for a refresh's tests; the
/// lights added by a source and those it takes away.
struct Balls {
    plus: Vec<(Vec3, f32)>,
    minus: Vec<(Vec3, f32)>,
}

impl Balls {
    fn of(source: &Source) -> Balls {
        let each = |ls: &[VirtualLight]| ls.iter().map(|l| bound(std::slice::from_ref(l))).collect();
        match source {
            Source::Direct(_) => Balls { plus: Vec::new(), minus: Vec::new() },
            Source::Lights(ls) => Balls { plus: each(ls), minus: Vec::new() },
            Source::Delta { plus, minus } => Balls { plus: each(plus), minus: each(minus) },
        }
    }
}

/// A baked entry's (direct, indirect) irradiance at texel `i`, with its own version.
fn evaluate(b: &Baked, k: CellKey, i: usize, s: u32, seed: u64) -> (DVec3, DVec3) {
    let (p, n, eps) = b.version.frames[i];
    let salt = salt(k, i);
    let sum = |ls: &[VirtualLight], base: u64| -> DVec3 {
        let mut sum = DVec3::ZERO;
        for (li, l) in ls.iter().enumerate() {
            let e = l.polygon.irradiance(p, n, eps);
            if e == Vec3::ZERO {
                continue;
            }
            let mut rng = stream(seed, base + li as u64, salt);
            let r2_min = l.polygon.area() / l.samples.len().max(1) as f32;
            sum += (e * soft_visibility(&b.version.bvh, p, n, &l.samples, r2_min, s, &mut rng)).as_dvec3();
        }
        sum
    };
    match &b.source {
        Source::Direct(l) => (
            prm::bvh::direct_irradiance(&b.version.bvh, std::slice::from_ref(l), p, n).as_dvec3(),
            DVec3::ZERO,
        ),
        Source::Lights(ls) => (DVec3::ZERO, sum(ls, STREAM_PLUS)),
        Source::Delta { plus, minus } => (DVec3::ZERO, sum(plus, STREAM_PLUS) - sum(minus, STREAM_MINUS)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn random_box(rng: &mut impl Rng) -> Aabb {
        let lo = Vec3::new(rng.random(), rng.random(), rng.random());
        let size = Vec3::new(rng.random(), rng.random(), rng.random()) * 0.3;
        Aabb { lo, hi: lo + size }
    }

    /// The pieces of `Aabb::meets_cone` without its one-test shortcut: the twin it must agree
    /// with.
    fn meets_cone_in_pieces(bx: &Aabb, apex: Vec3, centre: Vec3, radius: f32) -> bool {
        let axis = centre - apex;
        let len = axis.length();
        if !(len > radius) {
            return bx.meets_cone(apex, centre, radius, 0.0);
        }
        let d = axis / len;
        let slope = radius / (len * len - radius * radius).sqrt();
        let mut t0 = 0.0f32;
        for t1 in [len / 16.0, len / 8.0, len / 4.0, len / 2.0, len] {
            if bx.grown(t1 * slope).meets_segment(apex + d * t0, d, t1 - t0) {
                return true;
            }
            t0 = t1;
        }
        bx.grown(radius).meets_segment(centre, d, radius)
    }

    #[test]
    fn corrections_take_their_own_shadow_rays_and_none_is_refused() {
        let p = BakerParams { visibility_samples: 3, delta_visibility_samples: 1, ..Default::default() };
        assert_eq!(p.samples(CellKey::Delta(9, 2)), 1);
        assert_eq!(p.samples(CellKey::Cell(9)), 3);
        assert_eq!(p.samples(CellKey::Direct(0)), 3);
        let e = BakerParams { delta_visibility_samples: 0, ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("correction visibility samples"), "{e}");
    }

    #[test]
    fn a_cone_test_agrees_with_its_pieces_and_misses_no_segment() {
        let mut rng = stream(7, 0, 0);
        let mut hits = 0;
        for _ in 0..4000 {
            let bx = random_box(&mut rng);
            let apex = Vec3::new(rng.random(), rng.random(), rng.random()) * 1.6 - Vec3::splat(0.3);
            let centre = Vec3::new(rng.random(), rng.random(), rng.random()) * 1.6 - Vec3::splat(0.3);
            let radius = 0.2 * rng.random::<f32>();
            let fast = bx.meets_cone(apex, centre, radius, 0.0);
            assert_eq!(
                fast,
                meets_cone_in_pieces(&bx, apex, centre, radius),
                "{bx:?} {apex} {centre} {radius}"
            );
            hits += fast as u32;
            // Segments to points of the ball: none may meet the box when the cone misses it.
            for _ in 0..32 {
                let q =
                    centre + radius * (Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0) / 1.8;
                let (d, l) = ((q - apex).normalize_or_zero(), (q - apex).length());
                assert!(fast || !bx.meets_segment(apex, d, l), "{bx:?} {apex} {q}");
            }
        }
        assert!((200..3800).contains(&hits), "both outcomes are tried: {hits} hits");
    }

    /// A group's test and its texels' are both conservative, not nested: a texel the plain
    /// test takes only because it is conservative may be passed over. So the groups must pick
    /// within what the plain test picks, and every texel a segment to the ball really leaves
    /// for a box from (sampled).
    #[test]
    fn texel_groups_pick_every_texel_whose_segments_meet_a_box() {
        let mut rng = stream(11, 0, 0);
        let frames: Vec<(Vec3, Vec3, f32)> =
            (0..3000).map(|_| (Vec3::new(rng.random(), rng.random(), rng.random()), Vec3::Y, 0.01)).collect();
        let always: Vec<bool> = (0..frames.len()).map(|_| rng.random::<f32>() < 0.01).collect();
        let root = Aabb { lo: Vec3::ZERO, hi: Vec3::ONE };
        let groups = TexelGroups::new(&frames, &root);
        assert!(groups.groups.len() >= frames.len() / GROUP_TEXELS);
        let (mut sizes, mut kept) = (Vec::new(), 0usize);
        for _ in 0..40 {
            let boxes: Vec<Aabb> = (0..3).map(|_| random_box(&mut rng)).collect();
            let centre = Vec3::new(rng.random(), rng.random(), rng.random());
            let radius = 0.1 * rng.random::<f32>();
            let plain: Vec<usize> = (0..frames.len())
                .filter(|&i| {
                    always[i] || boxes.iter().any(|b| b.meets_cone(frames[i].0, centre, radius, 0.0))
                })
                .collect();
            let picked = groups.pick(
                |g, grow| boxes.iter().filter(|b| b.meets_cone(g, centre, radius, grow)).collect(),
                &always,
                |i, parts| parts.iter().any(|b| b.meets_cone(frames[i].0, centre, radius, 0.0)),
            );
            assert!(picked.windows(2).all(|w| w[0] < w[1]), "ascending, once each");
            assert!(picked.iter().all(|i| plain.binary_search(i).is_ok()), "within the plain test's");
            for (i, (p, _, _)) in frames.iter().enumerate() {
                let q =
                    centre + radius * (Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0) / 1.8;
                let (d, l) = ((q - *p).normalize_or_zero(), (q - *p).length());
                if always[i] || boxes.iter().any(|b| b.meets_segment(*p, d, l)) {
                    assert!(picked.binary_search(&i).is_ok(), "texel {i} at {p} meets a box towards {q}");
                }
            }
            sizes.push(plain.len());
            kept += picked.len();
        }
        let all: usize = sizes.iter().sum();
        assert!(sizes.iter().any(|&n| n > 300) && sizes.iter().any(|&n| n < 100), "{sizes:?}");
        assert!(kept as f64 >= 0.95 * all as f64, "the groups lose few of the plain picks: {kept} of {all}");
    }

    fn scene_of(tris: &[[Vec3; 3]]) -> Scene {
        let positions: Vec<Vec3> = tris.iter().flatten().copied().collect();
        let idx: Vec<u32> = (0..positions.len() as u32).collect();
        let uv = vec![glam::Vec2::ZERO; positions.len()];
        Scene::from_mesh(positions, uv, &idx)
    }

    fn quad(a: Vec3, b: Vec3, c: Vec3, d: Vec3) -> [[Vec3; 3]; 2] {
        [[a, b, c], [a, c, d]]
    }

    #[test]
    fn a_moved_object_splits_into_boxes_only_where_its_pieces_lie_apart() {
        let v = Vec3::new;
        // A cube's faces: every split leaves halves about as large as the cube.
        let (lo, hi) = (v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0));
        let cube: Vec<[Vec3; 3]> = [
            quad(v(lo.x, lo.y, lo.z), v(hi.x, lo.y, lo.z), v(hi.x, lo.y, hi.z), v(lo.x, lo.y, hi.z)),
            quad(v(lo.x, hi.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z)),
            quad(v(lo.x, lo.y, lo.z), v(lo.x, hi.y, lo.z), v(lo.x, hi.y, hi.z), v(lo.x, lo.y, hi.z)),
            quad(v(hi.x, lo.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(hi.x, lo.y, hi.z)),
            quad(v(lo.x, lo.y, lo.z), v(hi.x, lo.y, lo.z), v(hi.x, hi.y, lo.z), v(lo.x, hi.y, lo.z)),
            quad(v(lo.x, lo.y, hi.z), v(hi.x, lo.y, hi.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z)),
        ]
        .into_iter()
        .flatten()
        .collect();
        let s = scene_of(&cube);
        let all: Vec<u32> = (0..s.triangles.len() as u32).collect();
        assert_eq!(parts_of(&s, &all).len(), 1);
        // The carpet: a runner 15 m along the floor and the cube, as a dais, at its end.
        let mut carpet = cube.clone();
        carpet.extend(quad(v(0.3, 0.0, -15.0), v(0.7, 0.0, -15.0), v(0.7, 0.0, -0.1), v(0.3, 0.0, -0.1)));
        let s = scene_of(&carpet);
        let all: Vec<u32> = (0..s.triangles.len() as u32).collect();
        let parts = parts_of(&s, &all);
        assert!(parts.len() >= 2, "{parts:?}");
        let whole = Aabb::of(carpet.iter().flatten().copied());
        let area = |b: &Aabb| {
            let e = b.hi - b.lo;
            e.x * e.y + e.y * e.z + e.z * e.x
        };
        assert!(parts.iter().map(area).sum::<f32>() < 0.5 * area(&whole), "{parts:?}");
        // Every triangle lies in a part.
        for t in &carpet {
            assert!(
                parts.iter().any(|p| t.iter().all(|c| c.cmpge(p.lo).all() && c.cmple(p.hi).all())),
                "{t:?} outside {parts:?}"
            );
        }
    }
}
