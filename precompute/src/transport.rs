//! Light transport from entry clusters to exit texels: the panes' contents.
//!
//! Two estimators of the same quantity, `pane_c(x)` = indirect irradiance at texel x when the
//! entries of cluster c receive 1 W/m² (DESIGN.md §4):
//!
//! - [`Estimator::Scatter`] is paper 004's: from each entry, M cosine-sampled Russian-roulette
//!   walks (continuation probability = albedo luminance); every vertex, **the entry itself
//!   included**, is a virtual point light of flux
//!   `Phi_l = a(z_0) A/N prod_{i=1..l} a(z_i) / prod_{i=1..l-1} q_i` (per path, / M), and adds
//!   `Phi_l V cos cos / (pi max(r², r_c²))` to every texel. `r_c = clamp x sqrt(A/N)` bounds the
//!   1/r² spike (clamp 0: unbiased, spiky). Cost: every virtual light against every texel.
//! - [`Estimator::Gather`] reverses the same paths: from each texel, K cosine walks with the same
//!   roulette; the k-th vertex y_k adds its throughput `beta_k = prod_{i<=k} a(y_i) /
//!   prod_{i<k} q_i` to the cluster whose region y_k lies in. A cluster's region is the set of
//!   lightmap texels whose nearest compatible, visible entry is one of its members (nearest in
//!   space among entries facing within 60 degrees; visibility is checked so a thin wall does not
//!   hand one room's light to the other). The owner of every texel is found once, so a vertex's
//!   cluster is a lookup of the texel under its lightmap UV. No 1/r² term appears at all, so
//!   there is no spike to clamp, and the cost is per texel, not per texel x light.
//!
//! - [`Estimator::Mis`] is the gather with the first bounce estimated twice and combined by
//!   multiple importance sampling (balance heuristic): the gather's first vertex y (density
//!   `p_B = cos_x cos_y / (pi r²)` per walk, K walks) and, for every cluster c, one of its entries
//!   z picked at random as an area sample of its region (density `1 / A_c`, A_c = |c| A/N). The
//!   entry adds `a(z) (G/pi) V A_c / (1 + K (G/pi) A_c)`, the walk's first vertex
//!   `a(y) / (1 + 1 / (K p_B A_c))` / K. Far clusters are found by the entries (a small bright
//!   region is sampled every time, not hit by chance), near ones by the walks (where 1/r² would
//!   spike, the entry's weight goes to zero). Deeper bounces are the gather's. Cost: one shadow
//!   ray per facing cluster per texel on top of the walks.
//!
//! All three are unbiased for a direct-light field that is constant over each cluster's region
//! (scatter only with clamp 0); their expectations agree (tested on a tiny scene, and in the
//! furnace).

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::{IVec3, Vec3};
use prm::prm_file::Entry;
use prm::{luminance, Bvh, Scene, Texel};
use rand::Rng;
use rayon::prelude::*;

use crate::entries::stream;
use crate::ground_truth::cosine_direction;

/// How pane contents are estimated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Estimator {
    /// Texel-side walks credited to the cluster whose region each vertex hits.
    Gather,
    /// Paper 004's virtual point lights, with 1/r² clamped below `clamp x sqrt(A/N)`.
    Scatter { clamp: f32 },
    /// Gather walks plus one entry per cluster, first bounce combined by MIS.
    Mis,
}

impl std::fmt::Display for Estimator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Estimator::Gather => write!(f, "gather"),
            Estimator::Mis => write!(f, "mis"),
            Estimator::Scatter { clamp } => write!(f, "scatter(clamp {clamp})"),
        }
    }
}

/// Per-texel pane contributions: (cluster, irradiance per unit cluster irradiance), ascending.
pub type TexelPanes = Vec<(u32, Vec3)>;

/// Counters of a transport run.
#[derive(Debug, Default)]
pub struct TransportStats {
    pub rays: AtomicUsize,
    /// Walks cut by the bounce cap (energy lost, reported).
    pub truncated: AtomicUsize,
    /// Gather vertices no compatible entry was found for (their light is lost, reported).
    pub unowned: AtomicUsize,
    /// Virtual point lights (scatter).
    pub vpls: AtomicUsize,
}

/// The run was stopped by the caller.
#[derive(Debug, thiserror::Error)]
#[error("stopped before the end")]
pub struct Cancelled;

/// Which entry owns a surface point: nearest compatible, visible entry, found on a grid.
pub struct RegionLookup<'a> {
    entries: &'a [Entry],
    cell: f32,
    grid: HashMap<IVec3, Vec<u32>>,
}

/// Entries whose normal is within 60 degrees of the point's may own it.
const OWNER_MIN_COS: f32 = 0.5;
/// Candidates tried for visibility, nearest first.
const OWNER_TRIES: usize = 4;
/// Grid rings searched before giving up.
const OWNER_MAX_RING: i32 = 6;

impl<'a> RegionLookup<'a> {
    pub fn new(entries: &'a [Entry], total_area: f64) -> Self {
        let spacing = (total_area / entries.len().max(1) as f64).sqrt() as f32;
        let cell = (2.0 * spacing).max(f32::MIN_POSITIVE);
        let mut grid: HashMap<IVec3, Vec<u32>> = HashMap::new();
        for (i, e) in entries.iter().enumerate() {
            grid.entry((e.position / cell).floor().as_ivec3()).or_default().push(i as u32);
        }
        RegionLookup { entries, cell, grid }
    }

    /// The owning entry of point `p` with unit normal `n`, or `None`.
    pub fn owner(&self, p: Vec3, n: Vec3, bvh: &Bvh, stats: &TransportStats) -> Option<u32> {
        let home = (p / self.cell).floor().as_ivec3();
        let mut found: Vec<(f32, u32)> = Vec::new();
        for ring in 0..=OWNER_MAX_RING {
            for dz in -ring..=ring {
                for dy in -ring..=ring {
                    for dx in -ring..=ring {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                            continue;
                        }
                        if let Some(list) = self.grid.get(&(home + IVec3::new(dx, dy, dz))) {
                            for &i in list {
                                let e = &self.entries[i as usize];
                                if e.normal.dot(n) >= OWNER_MIN_COS {
                                    found.push(((e.position - p).length_squared(), i));
                                }
                            }
                        }
                    }
                }
            }
            // Everything within `ring` cells of the home cell has been seen: stop once enough
            // candidates are closer than anything a further ring could hold.
            let reach = ring as f32 * self.cell;
            let sure = found.iter().filter(|(d, _)| *d <= reach * reach).count();
            if sure >= OWNER_TRIES || (ring == OWNER_MAX_RING && !found.is_empty()) {
                break;
            }
        }
        found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(_, i) in found.iter().take(OWNER_TRIES) {
            let e = &self.entries[i as usize];
            stats.rays.fetch_add(1, Ordering::Relaxed);
            if bvh.visible(p, n, e.position, e.normal) {
                return Some(i);
            }
        }
        found.first().map(|&(_, i)| i)
    }
}

/// The cluster owning each atlas texel (`u32::MAX` where no entry qualifies).
pub struct OwnerMap {
    width: u32,
    height: u32,
    cluster: Vec<u32>,
}

impl OwnerMap {
    /// Find every covered texel's owning entry and record its cluster.
    pub fn build(
        set: &prm::TexelSet,
        lookup: &RegionLookup,
        assignment: &[u32],
        bvh: &Bvh,
        stats: &TransportStats,
    ) -> OwnerMap {
        let owners: Vec<u32> = set
            .texels
            .par_iter()
            .map(|t| {
                lookup.owner(t.position, t.normal, bvh, stats).map_or(u32::MAX, |e| assignment[e as usize])
            })
            .collect();
        let mut cluster = vec![u32::MAX; set.index.len()];
        for (t, c) in set.texels.iter().zip(owners) {
            cluster[(t.j * set.width + t.i) as usize] = c;
        }
        OwnerMap { width: set.width, height: set.height, cluster }
    }

    /// The cluster owning the surface point at barycentrics `bary` of triangle `tri`.
    fn at(&self, scene: &Scene, tri: usize, bary: Vec3) -> Option<u32> {
        let [a, b, c] = scene.uv1_corners(tri);
        let uv = a * bary.x + b * bary.y + c * bary.z;
        let (i, j) = ((uv.x * self.width as f32).floor(), (uv.y * self.height as f32).floor());
        if !(i >= 0.0 && j >= 0.0 && i < self.width as f32 && j < self.height as f32) {
            return None;
        }
        let c = self.cluster[(j as u32 * self.width + i as u32) as usize];
        (c != u32::MAX).then_some(c)
    }
}

/// Per-cluster members and region areas for [`Estimator::Mis`].
struct MisTables {
    members: Vec<Vec<u32>>,
    /// Region area of each cluster: |c| A / N.
    area: Vec<f32>,
}

impl MisTables {
    fn new(entries: &[Entry], assignment: &[u32], clusters: usize, total_area: f64) -> Self {
        let mut members = vec![Vec::new(); clusters];
        for (i, &c) in assignment.iter().enumerate() {
            members[c as usize].push(i as u32);
        }
        let per_entry = (total_area / entries.len().max(1) as f64) as f32;
        let area = members.iter().map(|m| m.len() as f32 * per_entry).collect();
        MisTables { members, area }
    }
}

/// Accumulates one texel's contributions densely, then emits them sparse.
struct Scratch {
    dense: Vec<Vec3>,
    touched: Vec<u32>,
}

impl Scratch {
    fn new(clusters: usize) -> Self {
        Scratch { dense: vec![Vec3::ZERO; clusters], touched: Vec::new() }
    }
    fn add(&mut self, c: u32, v: Vec3) {
        if self.dense[c as usize] == Vec3::ZERO {
            self.touched.push(c);
        }
        self.dense[c as usize] += v;
        if self.dense[c as usize] == Vec3::ZERO {
            // Keep it listed; a sum that lands on exactly zero is rare and harmless.
            self.dense[c as usize] = Vec3::splat(f32::MIN_POSITIVE);
        }
    }
    fn take(&mut self, scale: f32) -> TexelPanes {
        self.touched.sort_unstable();
        let out = self.touched.iter().map(|&c| (c, self.dense[c as usize] * scale)).collect();
        for &c in &self.touched {
            self.dense[c as usize] = Vec3::ZERO;
        }
        self.touched.clear();
        out
    }
}

/// Everything an estimator needs.
pub struct Transport<'a> {
    pub scene: &'a Scene,
    pub bvh: &'a Bvh,
    pub entries: &'a [Entry],
    /// Cluster of each entry.
    pub assignment: &'a [u32],
    pub clusters: usize,
    /// Paths per texel (gather) or per entry (scatter).
    pub paths: u32,
    pub max_bounces: u32,
    pub seed: u64,
    pub stats: TransportStats,
}

/// Van der Corput radical inverse in base 2.
fn radical_inverse(i: u32) -> f32 {
    (i.reverse_bits() as f64 / 4_294_967_296.0) as f32
}

/// A front-facing path vertex.
struct Vertex {
    position: Vec3,
    normal: Vec3,
    albedo: Vec3,
    triangle: usize,
    bary: Vec3,
}

/// One cosine bounce from `(x, n)`: the front-facing hit.
fn bounce(scene: &Scene, bvh: &Bvh, x: Vec3, n: Vec3, d: Vec3, stats: &TransportStats) -> Option<Vertex> {
    stats.rays.fetch_add(1, Ordering::Relaxed);
    let hit = bvh.trace_from_surface(x, n, d)?;
    let t = hit.triangle as usize;
    let mut nh = scene.face_normal(t);
    if nh.dot(d) > 0.0 {
        if !scene.material(t).double_sided {
            return None; // back faces of one-sided surfaces absorb
        }
        nh = -nh;
    }
    let bary = hit.bary();
    Some(Vertex {
        position: scene.point(t, bary),
        normal: nh,
        albedo: scene.albedo(t, bary),
        triangle: t,
        bary,
    })
}

impl<'a> Transport<'a> {
    /// Pane contributions at every texel. `progress` gets texels done; `cancel` stops.
    pub fn run(
        &self,
        estimator: Estimator,
        set: &prm::TexelSet,
        progress: &(dyn Fn(usize) + Sync),
        cancel: &AtomicBool,
    ) -> Result<Vec<TexelPanes>, Cancelled> {
        let (texels, width) = (&set.texels[..], set.width);
        match estimator {
            Estimator::Gather | Estimator::Mis => {
                let total_area = self.scene.total_area();
                let lookup = RegionLookup::new(self.entries, total_area);
                let owners = OwnerMap::build(set, &lookup, self.assignment, self.bvh, &self.stats);
                let mis = (estimator == Estimator::Mis)
                    .then(|| MisTables::new(self.entries, self.assignment, self.clusters, total_area));
                self.per_texel(texels, progress, cancel, |scratch, t| {
                    self.gather_texel(scratch, t, width, &owners, mis.as_ref())
                })
            }
            Estimator::Scatter { clamp } => {
                let vpls = self.vpls();
                self.stats.vpls.store(vpls.len(), Ordering::Relaxed);
                let spacing = (self.scene.total_area() / self.entries.len().max(1) as f64).sqrt() as f32;
                let rc2 = (clamp * spacing).powi(2);
                self.per_texel(texels, progress, cancel, |scratch, t| {
                    self.scatter_texel(scratch, t, &vpls, rc2)
                })
            }
        }
    }

    fn per_texel(
        &self,
        texels: &[Texel],
        progress: &(dyn Fn(usize) + Sync),
        cancel: &AtomicBool,
        f: impl Fn(&mut Scratch, &Texel) -> TexelPanes + Sync,
    ) -> Result<Vec<TexelPanes>, Cancelled> {
        let done = AtomicUsize::new(0);
        let chunks: Vec<Option<Vec<TexelPanes>>> = texels
            .par_chunks(64)
            .map_init(
                || Scratch::new(self.clusters),
                |scratch, chunk| {
                    if cancel.load(Ordering::Relaxed) {
                        return None;
                    }
                    let out: Vec<TexelPanes> = chunk.iter().map(|t| f(scratch, t)).collect();
                    progress(done.fetch_add(chunk.len(), Ordering::Relaxed) + chunk.len());
                    Some(out)
                },
            )
            .collect();
        let mut out = Vec::with_capacity(texels.len());
        for c in chunks {
            out.extend(c.ok_or(Cancelled)?);
        }
        Ok(out)
    }

    /// Paper 004's Russian roulette after a vertex of albedo `a` at walk depth `depth`:
    /// continue with probability q = luminance(a) and return q, or stop (also at the bounce
    /// cap, which is counted).
    fn roulette(&self, depth: u32, a: Vec3, rng: &mut impl Rng) -> Option<f32> {
        if depth >= self.max_bounces {
            self.stats.truncated.fetch_add(1, Ordering::Relaxed);
            return None;
        }
        let q = luminance(a);
        (q > 0.0 && rng.random::<f32>() < q).then_some(q)
    }

    fn gather_texel(
        &self,
        scratch: &mut Scratch,
        t: &Texel,
        width: u32,
        owners: &OwnerMap,
        mis: Option<&MisTables>,
    ) -> TexelPanes {
        let mut rng = stream(self.seed, 3, t.j as u64 * width as u64 + t.i as u64);
        let k = self.paths.max(1);
        // First directions: a Hammersley set shifted by a random rotation (Cranley-Patterson),
        // so each is uniformly distributed (unbiased) while together they stratify the
        // hemisphere; the first bounce carries most of the indirect light.
        let shift: (f32, f32) = (rng.random(), rng.random());
        for path in 0..k {
            let (mut x, mut n) = (t.position, t.normal);
            let mut beta = Vec3::ONE;
            let mut depth = 0;
            loop {
                let (u1, u2) = if depth == 0 {
                    (
                        ((path as f32 + 0.5) / k as f32 + shift.0).fract(),
                        (radical_inverse(path) + shift.1).fract(),
                    )
                } else {
                    (rng.random(), rng.random())
                };
                let d = cosine_direction(n, u1, u2);
                let Some(v) = bounce(self.scene, self.bvh, x, n, d, &self.stats) else { break };
                let (y, ny, a) = (v.position, v.normal, v.albedo);
                beta *= a;
                if beta == Vec3::ZERO {
                    break;
                }
                match owners.at(self.scene, v.triangle, v.bary) {
                    Some(c) if depth == 0 && mis.is_some() => {
                        // First vertex under MIS: weight against the entry samples of c.
                        let area_c = mis.map_or(0.0, |m| m.area[c as usize]);
                        let r2 = (y - t.position).length_squared();
                        let p_b = (t.normal.dot(y - t.position).max(0.0) * ny.dot(t.position - y).max(0.0))
                            / (std::f32::consts::PI * r2 * r2);
                        let w = 1.0 / (1.0 + 1.0 / (k as f32 * p_b * area_c).max(1e-30));
                        scratch.add(c, beta * w);
                    }
                    Some(c) => scratch.add(c, beta),
                    None => {
                        self.stats.unowned.fetch_add(1, Ordering::Relaxed);
                    }
                }
                depth += 1;
                let Some(q) = self.roulette(depth, a, &mut rng) else { break };
                beta /= q;
                x = y;
                n = ny;
            }
        }
        if let Some(m) = mis {
            // The entry strategy, already averaged (it is not one of the K walks): scale it by K
            // so the common 1/K below leaves it as it is.
            for c in 0..self.clusters {
                let members = &m.members[c];
                if members.is_empty() {
                    continue;
                }
                let e = &self.entries[members[rng.random_range(0..members.len())] as usize];
                let d = t.position - e.position;
                let r2 = d.length_squared();
                if !(r2 > 0.0) {
                    continue;
                }
                let (cz, cx) = (e.normal.dot(d), -t.normal.dot(d));
                if cz <= 0.0 || cx <= 0.0 {
                    continue;
                }
                let g_pi = cz * cx / (std::f32::consts::PI * r2 * r2);
                self.stats.rays.fetch_add(1, Ordering::Relaxed);
                if !self.bvh.visible(e.position, e.normal, t.position, t.normal) {
                    continue;
                }
                let area_c = m.area[c];
                let value = e.albedo * (g_pi * area_c / (1.0 + k as f32 * g_pi * area_c));
                scratch.add(c as u32, value * k as f32);
            }
        }
        scratch.take(1.0 / k as f32)
    }

    /// The gather estimator evaluated directly for one direct-light field (per-cluster
    /// irradiance `weights`), with the same random streams as [`Transport::run`]: the twin the
    /// superposition test holds the pane sum to.
    pub fn gather_field(&self, set: &prm::TexelSet, weights: &[Vec3]) -> Vec<Vec3> {
        let lookup = RegionLookup::new(self.entries, self.scene.total_area());
        let owners = OwnerMap::build(set, &lookup, self.assignment, self.bvh, &self.stats);
        let mut scratch = Scratch::new(self.clusters);
        set.texels
            .iter()
            .map(|t| {
                self.gather_texel(&mut scratch, t, set.width, &owners, None)
                    .iter()
                    .map(|&(c, v)| v * weights[c as usize])
                    .fold(Vec3::ZERO, |a, b| a + b)
            })
            .collect()
    }

    /// Virtual point lights of every entry's walks, for unit entry irradiance: (position,
    /// normal, flux, cluster).
    pub fn vpls(&self) -> Vec<(Vec3, Vec3, Vec3, u32)> {
        let m = self.paths.max(1);
        let per_entry: Vec<Vec<(Vec3, Vec3, Vec3, u32)>> = self
            .entries
            .par_iter()
            .enumerate()
            .map(|(j, e)| {
                let c = self.assignment[j];
                let mut rng = stream(self.seed, 4, j as u64);
                let phi0 = e.albedo * e.area;
                // The entry itself is the l = 0 light; every path shares it, so it is added once
                // with the full flux (the mean over M identical terms).
                let mut out = vec![(e.position, e.normal, phi0, c)];
                for _ in 0..m {
                    let (mut x, mut n) = (e.position, e.normal);
                    let mut phi = phi0 / m as f32;
                    let mut depth = 0;
                    loop {
                        let d = cosine_direction(n, rng.random(), rng.random());
                        let Some(v) = bounce(self.scene, self.bvh, x, n, d, &self.stats) else { break };
                        let (y, ny, a) = (v.position, v.normal, v.albedo);
                        phi *= a;
                        if phi == Vec3::ZERO {
                            break;
                        }
                        out.push((y, ny, phi, c));
                        depth += 1;
                        let Some(q) = self.roulette(depth, a, &mut rng) else { break };
                        phi /= q;
                        x = y;
                        n = ny;
                    }
                }
                out
            })
            .collect();
        per_entry.into_iter().flatten().collect()
    }

    fn scatter_texel(
        &self,
        scratch: &mut Scratch,
        t: &Texel,
        vpls: &[(Vec3, Vec3, Vec3, u32)],
        rc2: f32,
    ) -> TexelPanes {
        for &(z, nz, phi, c) in vpls {
            let d = t.position - z;
            let r2 = d.length_squared();
            if !(r2 > 0.0) {
                continue;
            }
            let r = r2.sqrt();
            let (cz, cx) = (nz.dot(d) / r, -t.normal.dot(d) / r);
            if cz <= 0.0 || cx <= 0.0 {
                continue;
            }
            self.stats.rays.fetch_add(1, Ordering::Relaxed);
            if !self.bvh.visible(z, nz, t.position, t.normal) {
                continue;
            }
            scratch.add(c, phi * (cz * cx / (std::f32::consts::PI * r2.max(rc2))));
        }
        scratch.take(1.0)
    }
}
