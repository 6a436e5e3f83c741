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
//! - cells whose VPLs changed are **rebuilt**: the smallest subtree holding every old and new
//!   cell of a change, so a split or merge of the cut is one update;
//! - cells whose VPLs did not change but whose light may now be shadowed differently are
//!   **refreshed**, only at the texels whose shadow rays can meet what moved: texels on moved
//!   objects, and texels whose segment to the cell's bounding sphere passes a box where moved
//!   geometry was or is. Elsewhere the old and new values are the same numbers, so leaving them
//!   is exact. Paper 001 finds such cells only through their scattered particles and misses
//!   the ones whose few particles did not touch the edit (its slow "footprint" cases); here
//!   every baked cell is checked.
//!
//! Updates go in order of invalid flux: for a rebuild, the flux of the VPLs that differ
//! between the baked and the new cell (both counted, as paper 001's absolute term) plus the
//! flux of validated path segments that leave the cell and now land elsewhere; for a refresh,
//! those segments plus the cell's flux times how much of its view the moved boxes take.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::hash::{Hash, Hasher};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{DVec3, Vec3};
use prm::{Light, Scene, TexelSet};
use rayon::prelude::*;

use super::clusters::{
    bound, cell_box, cell_lights, contains, cut, key, morton, Member, VirtualLight, MAX_DEPTH,
};
use super::level::{Aabb, Changes, Edit, EditError, Level, LightSlot, Version};
use super::paths::{light_flux, luminance, path_count, trace_all, validate, Change, LightPaths, PathParams};
use crate::params::{require, ParamError};
use crate::reference::bake::soft_visibility;
use prm::sampling::stream;

/// Incremental-baker parameters.
#[derive(Clone, Debug)]
pub struct BakerParams {
    /// Light paths over all of the level's lights when it is opened (each light gets its share
    /// of the flux, at equal energy per path).
    pub paths: usize,
    pub max_bounces: u32,
    /// VPLs a cell of the cut holds at most.
    pub leaf_vpls: usize,
    pub max_depth: u32,
    /// Virtual lights per cell (paper 001: K = 4).
    pub lights_per_cell: usize,
    /// Smallest plane cluster that becomes a polygon light (paper 001: p_min = 10).
    pub min_polygon: usize,
    /// Shadow rays per texel and virtual light.
    pub visibility_samples: u32,
    pub seed: u64,
}

impl Default for BakerParams {
    fn default() -> Self {
        BakerParams {
            paths: 40_000,
            max_bounces: 8,
            leaf_vpls: 256,
            max_depth: 8,
            lights_per_cell: 4,
            min_polygon: 10,
            visibility_samples: 2,
            seed: 0,
        }
    }
}

impl BakerParams {
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
        require((1..=100_000).contains(&self.min_polygon), "polygon support", self.min_polygon, "1 to 1e5")?;
        require(
            (1..=256).contains(&self.visibility_samples),
            "visibility samples",
            self.visibility_samples,
            "1 to 256",
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
}

#[derive(Clone, Debug)]
enum Source {
    Direct(Light),
    Lights(Arc<Vec<VirtualLight>>),
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
    flux: Vec3,
    /// Members' (id, power) for the differing-flux priority.
    ids: Arc<HashMap<(u32, u32, u32), Vec3>>,
    bound: (Vec3, f32),
}

#[derive(Clone, Debug)]
enum Work {
    Rebuild { remove: Vec<CellKey>, add: Vec<(CellKey, Content)> },
    Refresh(CellKey),
}

#[derive(Clone, Debug)]
struct Unit {
    priority: f32,
    root: CellKey,
    work: Work,
}

/// What [`Baker::step`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    pub cell: CellKey,
    pub rebuilt: bool,
    /// Invalid flux it resolved (the unit's priority), W (luminance).
    pub resolved: f32,
    /// Texels it evaluated.
    pub texels: usize,
}

/// What [`Baker::apply`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EditReport {
    pub changes: Changes,
    /// Paths replaced (traced again from where they changed, or all of a changed light's).
    pub paths_changed: usize,
    pub paths_total: usize,
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
    /// Waiting updates, lowest priority first.
    work: Vec<Unit>,
    /// Edits that moved geometry, by the version they made.
    log: Vec<(u64, Changes)>,
    /// Absolute invalid flux per cell from validated segments, until the cell is updated.
    segments: BTreeMap<CellKey, f32>,
    direct: Vec<DVec3>,
    indirect: Vec<DVec3>,
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
        };
        let v = b.level.current().clone();
        for slot in v.lights.iter() {
            let count = path_count(slot, b.bounds(), frame.quantum);
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
                _ => trace_all(&v, slot, path_count(slot, bounds, self.frame.quantum), bounds, pp),
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
            pending: self.work.len(),
            invalid_flux: self.work.iter().map(|u| u.priority).sum(),
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
                CellKey::Direct(_) => false,
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
                    p.vertices.iter().enumerate().map(move |(vi, x)| Member {
                        code: morton(&root, x.position, MAX_DEPTH),
                        light,
                        path: pi as u32,
                        vertex: vi as u32,
                        position: x.position,
                        normal: x.normal,
                        power: x.power,
                    })
                })
            })
            .collect();
        m.par_sort_unstable_by_key(|x| (x.code, x.light, x.path, x.vertex));
        m
    }

    /// Compare what is baked with what the current paths and lights call for; queue updates.
    fn plan(&mut self) {
        let v = self.level.current().clone();
        let members = self.members();
        let mut want: BTreeMap<CellKey, Content> = BTreeMap::new();
        for (k, r) in cut(&members, self.params.leaf_vpls, self.params.max_depth) {
            let ms = members[r].to_vec();
            let mut h = std::collections::hash_map::DefaultHasher::new();
            let mut flux = Vec3::ZERO;
            for m in &ms {
                (m.light, m.path, m.vertex).hash(&mut h);
                for x in [m.position, m.normal, m.power] {
                    x.to_array().map(f32::to_bits).hash(&mut h);
                }
                flux += m.power;
            }
            want.insert(CellKey::Cell(k), Content { members: ms, light: None, hash: h.finish(), flux });
        }
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
        // Changed keys, grouped under the shallowest baked or wanted cell containing them.
        let changed: Vec<CellKey> = want
            .iter()
            .filter(|(k, c)| self.baked.get(k).map(|b| b.hash) != Some(c.hash))
            .map(|(k, _)| *k)
            .chain(self.baked.keys().filter(|k| !want.contains_key(k)).copied())
            .collect();
        let all: Vec<CellKey> = self.baked.keys().chain(want.keys()).copied().collect();
        let root_of = |k: CellKey| -> CellKey {
            match k {
                CellKey::Direct(_) => k,
                CellKey::Cell(c) => all
                    .iter()
                    .filter_map(|a| match a {
                        CellKey::Cell(x) if contains(*x, c) => Some(*x),
                        _ => None,
                    })
                    .min_by_key(|x| x >> 32)
                    .map_or(k, CellKey::Cell),
            }
        };
        let under = |r: CellKey, k: CellKey| match (r, k) {
            (CellKey::Cell(a), CellKey::Cell(b)) => contains(a, b),
            _ => r == k,
        };
        let roots: BTreeSet<CellKey> = changed.iter().map(|&k| root_of(k)).collect();
        let mut units = Vec::new();
        let mut in_units: BTreeSet<CellKey> = BTreeSet::new();
        for r in roots {
            let remove: Vec<CellKey> = self.baked.keys().filter(|k| under(r, **k)).copied().collect();
            // Units are disjoint, so each wanted cell moves into at most one (no copy).
            let keys: Vec<CellKey> = want.keys().filter(|k| under(r, **k)).copied().collect();
            let add: Vec<(CellKey, Content)> =
                keys.into_iter().filter_map(|k| want.remove(&k).map(|c| (k, c))).collect();
            in_units.extend(remove.iter().copied());
            // Invalid flux: the power of the VPLs on one side only, plus segments.
            let mut old_ids: HashMap<(u32, u32, u32), Vec3> = HashMap::new();
            for k in &remove {
                for (id, p) in self.baked[k].ids.iter() {
                    old_ids.insert(*id, *p);
                }
            }
            let mut differing = 0.0f32;
            for (_, c) in &add {
                for m in &c.members {
                    match old_ids.remove(&(m.light, m.path, m.vertex)) {
                        Some(p) if p == m.power => {}
                        Some(p) => differing += luminance(p) + luminance(m.power),
                        None => differing += luminance(m.power),
                    }
                }
            }
            differing += old_ids.values().map(|p| luminance(*p)).sum::<f32>();
            let direct = |k: &CellKey, light: Option<&Light>| match (k, light) {
                (CellKey::Direct(id), Some(l)) => {
                    luminance(light_flux(&LightSlot { id: *id, light: l.clone() }, self.bounds()))
                }
                _ => 0.0,
            };
            differing += add.iter().map(|(k, c)| direct(k, c.light.as_ref())).sum::<f32>();
            differing += remove
                .iter()
                .map(|k| match &self.baked[k].source {
                    Source::Direct(l) => direct(k, Some(l)),
                    Source::Lights(_) => 0.0,
                })
                .sum::<f32>();
            let seg: f32 = remove.iter().filter_map(|k| self.segments.get(k)).sum();
            units.push(Unit { priority: differing + seg, root: r, work: Work::Rebuild { remove, add } });
        }
        // Refreshes: baked cells outside the rebuilds that an edit since their bake may shadow.
        for (k, b) in &self.baked {
            if in_units.contains(k) || b.version.id == v.id {
                continue;
            }
            let since: Vec<&Changes> =
                self.log.iter().filter(|(id, _)| *id > b.version.id).map(|(_, c)| c).collect();
            if since.is_empty() {
                continue;
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
            let flux = match &b.source {
                Source::Direct(l) => {
                    luminance(light_flux(&LightSlot { id: 0, light: l.clone() }, self.bounds()))
                }
                Source::Lights(_) => luminance(b.flux),
            };
            let seg = self.segments.get(k).copied().unwrap_or(0.0);
            units.push(Unit { priority: flux * view + seg, root: *k, work: Work::Refresh(*k) });
        }
        units.sort_by(|a, b| a.priority.total_cmp(&b.priority).then(b.root.cmp(&a.root)));
        self.work = units;
        // Cells no edit can have changed may forget their old version.
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

    /// Updates waiting.
    pub fn pending(&self) -> usize {
        self.work.len()
    }

    /// Invalid flux still waiting (luminance, W).
    pub fn invalid_flux(&self) -> f32 {
        self.work.iter().map(|u| u.priority).sum()
    }

    pub fn converged(&self) -> bool {
        self.work.is_empty()
    }

    /// Run the most urgent update; `None` when there is none.
    pub fn step(&mut self) -> Option<StepReport> {
        let unit = self.work.pop()?;
        let v = self.level.current().clone();
        let texels = self.level.texels().clone();
        let (s, seed) = (self.params.visibility_samples, self.params.seed);
        match unit.work {
            Work::Rebuild { remove, add } => {
                let old: Vec<(CellKey, Baked)> =
                    remove.iter().filter_map(|k| self.baked.remove(k).map(|b| (*k, b))).collect();
                let root = self.frame.root;
                let (k_lights, p_min) = (self.params.lights_per_cell, self.params.min_polygon);
                let new: Vec<(CellKey, Baked)> = add
                    .into_par_iter()
                    .map(|(k, c)| {
                        let (source, bnd) = match (&k, c.light) {
                            (CellKey::Direct(_), Some(l)) => {
                                let b = (l.position, 0.0);
                                (Source::Direct(l), b)
                            }
                            (CellKey::Cell(code), _) => {
                                let ls = cell_lights(&c.members, &cell_box(&root, *code), k_lights, p_min);
                                let b = bound(&ls);
                                (Source::Lights(Arc::new(ls)), b)
                            }
                            (CellKey::Direct(_), None) => {
                                unreachable!("a direct cell is made with its light")
                            }
                        };
                        let ids = c.members.iter().map(|m| ((m.light, m.path, m.vertex), m.power)).collect();
                        (
                            k,
                            Baked {
                                version: v.clone(),
                                source,
                                hash: c.hash,
                                flux: c.flux,
                                ids: Arc::new(ids),
                                bound: bnd,
                            },
                        )
                    })
                    .collect();
                let frames_old: Vec<&Baked> = old.iter().map(|(_, b)| b).collect();
                let frames_new: Vec<&Baked> = new.iter().map(|(_, b)| b).collect();
                let keys_old: Vec<CellKey> = old.iter().map(|(k, _)| *k).collect();
                let keys_new: Vec<CellKey> = new.iter().map(|(k, _)| *k).collect();
                self.direct.par_iter_mut().zip(self.indirect.par_iter_mut()).enumerate().for_each(
                    |(i, (d, ind))| {
                        for (k, b) in keys_old.iter().zip(&frames_old) {
                            let (ed, ei) = evaluate(b, *k, i, s, seed);
                            *d -= ed;
                            *ind -= ei;
                        }
                        for (k, b) in keys_new.iter().zip(&frames_new) {
                            let (ed, ei) = evaluate(b, *k, i, s, seed);
                            *d += ed;
                            *ind += ei;
                        }
                    },
                );
                for k in &keys_old {
                    self.segments.remove(k);
                }
                self.baked.extend(new);
                Some(StepReport {
                    cell: unit.root,
                    rebuilt: true,
                    resolved: unit.priority,
                    texels: texels.texels.len(),
                })
            }
            Work::Refresh(k) => {
                let b = self.baked.get_mut(&k)?;
                let old = b.version.clone();
                let since: Vec<&Changes> =
                    self.log.iter().filter(|(id, _)| *id > old.id).map(|(_, c)| c).collect();
                let moved: BTreeSet<u32> = since.iter().flat_map(|c| c.moved_nodes.iter().copied()).collect();
                let (c, r) = b.bound;
                let regions: Vec<Aabb> =
                    since.iter().flat_map(|ch| ch.regions.iter().map(|x| x.grown(r))).collect();
                let directional = match &b.source {
                    Source::Direct(l) if !l.is_positional() => Some(-l.direction),
                    _ => None,
                };
                let shadowed = |p: Vec3| -> bool {
                    let (dir, len) = match directional {
                        Some(d) => (d, f32::INFINITY),
                        None => ((c - p).normalize_or_zero(), (c - p).length()),
                    };
                    regions.iter().any(|bx| bx.meets_segment(p, dir, len))
                };
                let picked: Vec<usize> = (0..texels.texels.len())
                    .into_par_iter()
                    .filter(|&i| {
                        moved.contains(&v.scene.triangles[texels.texels[i].triangle as usize].node)
                            || shadowed(old.frames[i].0)
                            || shadowed(v.frames[i].0)
                    })
                    .collect();
                let was = Baked {
                    version: old,
                    source: b.source.clone(),
                    hash: b.hash,
                    flux: b.flux,
                    ids: b.ids.clone(),
                    bound: b.bound,
                };
                b.version = v.clone();
                let b = &*b;
                let deltas: Vec<(DVec3, DVec3)> = picked
                    .par_iter()
                    .map(|&i| {
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
                Some(StepReport { cell: k, rebuilt: false, resolved: unit.priority, texels: picked.len() })
            }
        }
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
            .filter(|b| matches!(b.source, Source::Lights(_)))
            .fold(Vec3::ZERO, |a, b| a + b.flux);
        let mut pending = Vec3::ZERO;
        for u in &self.work {
            if let Work::Rebuild { remove, add } = &u.work {
                pending += add.iter().fold(Vec3::ZERO, |a, (_, c)| a + c.flux);
                pending -=
                    remove.iter().filter_map(|k| self.baked.get(k)).fold(Vec3::ZERO, |a, b| a + b.flux);
            }
        }
        let vpls = self
            .lights
            .values()
            .flat_map(|lp| lp.paths.iter().flat_map(|p| p.vertices.iter()))
            .fold(Vec3::ZERO, |a, x| a + x.power);
        Energy { baked, pending, vpls }
    }

    /// Whether the baked cells are disjoint (no cell inside another): no VPL counted twice.
    pub fn cells_disjoint(&self) -> bool {
        let cells: Vec<u64> = self
            .baked
            .keys()
            .filter_map(|k| match k {
                CellKey::Cell(c) => Some(*c),
                CellKey::Direct(_) => None,
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
                Source::Direct(_) => 1,
            })
            .sum();
        (self.baked.len(), lights)
    }
}

fn same_geometry(a: &Light, b: &Light) -> bool {
    a.kind == b.kind && a.position == b.position && a.direction == b.direction && a.range == b.range
}

/// A baked cell's (direct, indirect) irradiance at texel `i`, with its own version.
fn evaluate(b: &Baked, k: CellKey, i: usize, s: u32, seed: u64) -> (DVec3, DVec3) {
    let (p, n, eps) = b.version.frames[i];
    match &b.source {
        Source::Direct(l) => (
            prm::bvh::direct_irradiance(&b.version.bvh, std::slice::from_ref(l), p, n).as_dvec3(),
            DVec3::ZERO,
        ),
        Source::Lights(ls) => {
            let mut sum = DVec3::ZERO;
            let cell = match k {
                CellKey::Cell(c) => c,
                CellKey::Direct(id) => id as u64,
            };
            for (li, l) in ls.iter().enumerate() {
                let e = l.polygon.irradiance(p, n, eps);
                if e == Vec3::ZERO {
                    continue;
                }
                let mut rng =
                    stream(seed, 50 + li as u64, cell.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ i as u64);
                let r2_min = l.polygon.area() / l.samples.len().max(1) as f32;
                sum +=
                    (e * soft_visibility(&b.version.bvh, p, n, &l.samples, r2_min, s, &mut rng)).as_dvec3();
            }
            (DVec3::ZERO, sum)
        }
    }
}
