//! Light transport from entry clusters to exit texels: the panes' contents.
//!
//! Three estimators of the same quantity, `pane_c(x)` = indirect irradiance at texel x when the
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
//!   prod_{i<k} q_i` to the cluster whose region y_k lies in. A cluster's region is its
//!   members' cells (`crate::cells::CellOwners`: the cell holding y_k on the triangle it hit),
//!   the same surface whose power weights the cluster at run time; the two sides of a thin wall
//!   are different triangles, so one room's light never goes to the other. Where the near
//!   links carry a cell's first bounce exactly, the first vertex leaves it to them
//!   ([`LinkedCells`]). No 1/r² term appears at all, so there is no spike to clamp, and the
//!   cost is per texel, not per texel x light. With a [`NextBounce`] table (the default with
//!   the near links and the far field) no hit is credited where the table reaches: the
//!   texel's own first bounce is given whole (links plus far field), and each vertex y_k adds
//!   `beta_k F_c(y_k)` for every cluster c, the first bounce c sends to y_k's cell, read
//!   from the table (module `next`).
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
//!
//! Files: `region` (which cluster owns a surface point), `gather` (the gather and MIS
//! estimators), `scatter` (paper 004's virtual point lights); here the walk primitives they
//! share and the dispatch.

mod gather;
mod next;
mod scatter;

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{Vec3, Vec3A};
use prm::prm_file::Entry;
use prm::{luminance, Bvh, Scene, Texel};
use rand::Rng;

use crate::cells::CellOwners;
use crate::parallel::{par_texels, Cancelled, Control};
use crate::update::{Recorder, VoxelGrid};
pub use gather::MisTables;
pub use next::{CellSamples, Cutoff, NextBounce};
use prm::rooms::Rooms;

/// How pane contents are estimated.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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
    /// Walk vertices in a cell whose next-bounce row was left out (`NextBounce::left_out`):
    /// an update that made only some rows refuses when this is not zero.
    pub rows_left_out: AtomicUsize,
}

/// Accumulates one texel's contributions densely, then emits them sparse.
struct Scratch<'f> {
    /// Per cluster, in SIMD lanes (the same sums as `Vec3`'s, lane by lane: add_visits' rows,
    /// a third of a chamber's precompute, go about twice as fast).
    dense: Vec<Vec3A>,
    touched: Vec<u32>,
    /// Per entry, the walks' throughput at vertices in its cell (sized on first use), and
    /// the entries with any ([`NextBounce`]).
    visits: Vec<Vec3>,
    visited: Vec<u32>,
    /// Where the texel's walks go, when recorded ([`Transport::run_traced`]).
    trace: Option<Tracing<'f>>,
}

/// A texel's walks as recorded for `prm precompute --update` (`crate::update`).
struct Tracing<'f> {
    grid: &'f VoxelGrid,
    voxels: Recorder,
    /// The level's rooms, and those the texel's walks' segments lay in (sorted).
    rooms: &'f Rooms,
    /// The voxels of the last segment's points, looked up when the next segment (or the
    /// texel's end) is recorded ([`Rooms::segment_voxels`]: their labels are fetched while
    /// the next ray is traced).
    pending: Vec<u32>,
    found: Vec<u32>,
    /// Whether any walk of the texel was placed in a room.
    placed: bool,
    truncated: u64,
    unowned: u64,
}

impl Tracing<'_> {
    /// Looks up the rooms of the points [`Tracing::pending`] holds.
    fn place_pending(&mut self) {
        for v in self.pending.drain(..) {
            if let Some(r) = self.rooms.room_of_voxel(v) {
                self.placed = true;
                if let Err(at) = self.found.binary_search(&r) {
                    self.found.insert(at, r);
                }
            }
        }
    }
}

/// A texel's rooms ([`Trace::rooms`]) when none of its walks' segments could be placed in a
/// room: its walks may have been anywhere.
pub const ANY_ROOM: u32 = u32::MAX;

/// What [`Transport::run_traced`] says of one texel's walks besides its contributions: the
/// voxels their segments passed through (each once), the rooms their segments lie in (sorted;
/// [`ANY_ROOM`] when no segment could be placed), the walks cut at the bounce cap and the
/// vertices no entry owned.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trace {
    pub voxels: Vec<u32>,
    pub rooms: Vec<u32>,
    pub truncated: u64,
    pub unowned: u64,
}

impl<'f> Scratch<'f> {
    fn new(clusters: usize, grid: Option<(&'f VoxelGrid, &'f Rooms)>) -> Self {
        Scratch {
            dense: vec![Vec3A::ZERO; clusters],
            touched: Vec::with_capacity(clusters),
            visits: Vec::new(),
            visited: Vec::new(),
            trace: grid.map(|(grid, rooms)| Tracing {
                grid,
                voxels: Recorder::new(grid),
                rooms,
                pending: Vec::new(),
                found: Vec::new(),
                placed: false,
                truncated: 0,
                unowned: 0,
            }),
        }
    }

    /// Record a walk segment from `x` along `d` to `end` (None: it left the level, or met the
    /// back of a surface, and is recorded to the level's edge): its voxels and the rooms it
    /// lies in ([`Rooms::rooms_on_segment`]; past a surface's back that may name a room it
    /// never reached, which only widens what an update walks again).
    fn segment(&mut self, x: Vec3, d: Vec3, end: Option<Vec3>) {
        if let Some(t) = self.trace.as_mut() {
            // The last segment's points, fetched while this segment's ray was traced.
            t.place_pending();
            let end = end.unwrap_or_else(|| t.grid.exit(x, d));
            t.grid.segment(x, end, |v| t.voxels.mark(v));
            t.rooms.segment_voxels(x, end, |v| t.pending.push(v));
        }
    }

    fn take_trace(&mut self) -> Trace {
        match self.trace.as_mut() {
            Some(t) => {
                t.place_pending();
                // Every walk of a texel starts at the same point, so all lie in the room of any
                // one placed; a texel none of whose walks was placed may have been anywhere.
                if !std::mem::take(&mut t.placed) {
                    t.found = vec![ANY_ROOM];
                }
                Trace {
                    voxels: t.voxels.take(),
                    rooms: std::mem::take(&mut t.found),
                    truncated: std::mem::take(&mut t.truncated),
                    unowned: std::mem::take(&mut t.unowned),
                }
            }
            None => Trace::default(),
        }
    }
    /// Adds `v` to cluster `c`'s pane value, listing `c` the first time.
    fn accumulate(&mut self, c: u32, v: Vec3) {
        self.accumulate_a(c, Vec3A::from(v));
    }

    /// [`Scratch::accumulate`] in SIMD lanes.
    #[inline]
    fn accumulate_a(&mut self, c: u32, v: Vec3A) {
        let d = &mut self.dense[c as usize];
        if *d == Vec3A::ZERO {
            self.touched.push(c);
        }
        *d += v;
        if *d == Vec3A::ZERO {
            // Keep it listed; a sum that lands on exactly zero is rare and harmless.
            *d = Vec3A::splat(f32::MIN_POSITIVE);
        }
    }

    /// Notes a walk vertex in entry `e`'s cell (of `entries`) with throughput `beta`.
    fn visit(&mut self, e: u32, beta: Vec3, entries: usize) {
        if self.visits.len() != entries {
            self.visits = vec![Vec3::ZERO; entries];
        }
        let slot = &mut self.visits[e as usize];
        if *slot == Vec3::ZERO {
            self.visited.push(e);
        }
        *slot += beta;
    }

    /// Adds each visited cell's row of `next`, times the throughput noted there, and forgets
    /// the visits.
    fn add_visits(&mut self, next: &NextBounce) {
        let mut visited = std::mem::take(&mut self.visited);
        visited.sort_unstable();
        for &e in &visited {
            let w = std::mem::take(&mut self.visits[e as usize]);
            let Some(row) = next.row(e) else { continue };
            // The row's step folded into the throughput once: each element is then whole steps.
            add_row(&mut self.dense, &mut self.touched, &row, Vec3A::from(w * row.unit));
        }
        visited.clear();
        self.visited = visited;
    }

    fn take(&mut self, scale: f32) -> TexelPanes {
        self.touched.sort_unstable();
        let out = self.touched.iter().map(|&c| (c, Vec3::from(self.dense[c as usize] * scale))).collect();
        for &c in &self.touched {
            self.dense[c as usize] = Vec3A::ZERO;
        }
        self.touched.clear();
        out
    }
}

/// Adds `w` times each element of `row` to `dense`, listing in `touched` each cluster it finds
/// at zero ([`Scratch::accumulate_a`]'s sums, a third of a chamber's precompute). Neither `w`
/// nor a row's steps have a negative lane, so a listed sum cannot come back to zero and only
/// the first addition to a cluster needs the zero test; and with `dense` and `touched` apart
/// from the rest of the scratch, the loop keeps their addresses in registers.
#[inline]
fn add_row(dense: &mut [Vec3A], touched: &mut Vec<u32>, row: &next::Row<'_>, w: Vec3A) {
    for (&c, &q) in row.cluster.iter().zip(row.value) {
        let v = w * Vec3A::from(next::steps(q));
        let d = &mut dense[usize::from(c)];
        if *d == Vec3A::ZERO {
            touched.push(u32::from(c));
            *d = if v == Vec3A::ZERO { Vec3A::splat(f32::MIN_POSITIVE) } else { v };
        } else {
            *d += v;
        }
    }
}

/// An estimator's tables, built once per run ([`Transport::prepare`]).
pub enum Prepared {
    /// The gather, with the MIS tables or without.
    Gather(Option<MisTables>),
    /// The scatter's virtual lights (position, normal, power, cluster) and squared clamp.
    Scatter { vpls: Vec<(Vec3, Vec3, Vec3, u32)>, rc2: f32 },
}

/// Everything an estimator needs.
pub struct Transport<'a> {
    pub scene: &'a Scene,
    pub bvh: &'a Bvh,
    pub entries: &'a [Entry],
    /// Which entry's cell holds a point (the gather credits hits by it).
    pub owners: &'a CellOwners,
    /// The first bounce the near links carry exactly, left out of the gather's first hits
    /// (None: nothing left out).
    pub linked: Option<&'a LinkedCells<'a>>,
    /// The next bounce at each vertex from a table (None: the hits say it; `next`).
    pub next: Option<&'a NextBounce>,
    /// Cluster of each entry.
    pub assignment: &'a [u32],
    pub clusters: usize,
    /// Paths per texel (gather) or per entry (scatter).
    pub paths: u32,
    pub max_bounces: u32,
    pub seed: u64,
    pub stats: TransportStats,
}

/// The cells a texel's near links (`crate::near`) carry the first bounce of, in closed form:
/// a gather walk's first hit in such a cell keeps only the share of it the links leave to the
/// far field (`keep`, 0 within the links' reach), and the panes get the rest exactly
/// (`precompute::exact_first_bounce`), added after smoothing. A pane and the near field then say the same
/// thing of every linked cell, so their difference is the deviation alone: before, a texel at
/// a wall's foot took 30 % of a hot cluster's pane from one cell that its link took back, and
/// the walks' noise on it (128 paths) was left over as error larger than the light (the
/// chamber's floor along a lit wall 0.0-1.0 against 0.3-0.5 W/m²).
pub struct LinkedCells<'a> {
    /// Sorted by atlas texel, then entry ([`prm::prm_file::NearLink`]).
    pub links: &'a [prm::prm_file::NearLink],
    /// Per link: the share of its cell's first bounce the walks keep.
    pub keep: &'a [f32],
}

impl LinkedCells<'_> {
    /// The links of atlas texel `texel` and their shares kept.
    pub fn of(&self, texel: u32) -> (&[prm::prm_file::NearLink], &[f32]) {
        let from = self.links.partition_point(|l| l.texel < texel);
        let to = from + self.links[from..].partition_point(|l| l.texel == texel);
        (&self.links[from..to], &self.keep[from..to])
    }
}

/// The share of entry `entry`'s cell's first bounce the walks keep, given a texel's links and
/// shares ([`LinkedCells::of`]): 1 for a cell not linked to it.
fn kept_share((links, keep): (&[prm::prm_file::NearLink], &[f32]), entry: u32) -> f32 {
    links.binary_search_by_key(&entry, |l| l.entry).map_or(1.0, |k| keep[k])
}

/// A front-facing path vertex.
struct Vertex {
    position: Vec3,
    normal: Vec3,
    albedo: Vec3,
    triangle: usize,
}

/// One cosine bounce from `(x, n)`: the front-facing hit.
fn bounce(scene: &Scene, bvh: &Bvh, x: Vec3, n: Vec3, d: Vec3, stats: &TransportStats) -> Option<Vertex> {
    stats.rays.fetch_add(1, Ordering::Relaxed);
    let hit = bvh.trace_from_surface(x, n, d)?;
    let t = hit.triangle as usize;
    let nh = scene.facing_normal(t, d)?;
    let bary = hit.bary();
    Some(Vertex { position: scene.point(t, bary), normal: nh, albedo: scene.albedo(t, bary), triangle: t })
}

impl<'a> Transport<'a> {
    /// Pane contributions at every texel; `control` reports texels done and
    /// stops the run.
    pub fn run(
        &self,
        estimator: Estimator,
        set: &prm::TexelSet,
        control: Control,
    ) -> Result<Vec<TexelPanes>, Cancelled> {
        self.run_texels(&self.prepare(estimator), &set.texels, set.width, control)
    }

    /// What `estimator` builds once before any texel (the MIS tables, the virtual lights).
    pub fn prepare(&self, estimator: Estimator) -> Prepared {
        let total_area = self.scene.total_area();
        match estimator {
            Estimator::Gather => Prepared::Gather(None),
            Estimator::Mis => Prepared::Gather(Some(MisTables::new(
                self.entries,
                self.assignment,
                self.clusters,
                total_area,
            ))),
            Estimator::Scatter { clamp } => {
                let vpls = self.vpls();
                self.stats.vpls.store(vpls.len(), Ordering::Relaxed);
                let spacing = (total_area / self.entries.len().max(1) as f64).sqrt() as f32;
                Prepared::Scatter { vpls, rc2: (clamp * spacing).powi(2) }
            }
        }
    }

    /// The panes' contents at `texels` (any run of a texel set `width` texels wide, in its
    /// order): each texel's result depends on that texel alone, so runs give the same values
    /// as one run over the whole set, which is what lets the precompute walk a band at a time.
    pub fn run_texels(
        &self,
        prepared: &Prepared,
        texels: &[Texel],
        width: u32,
        control: Control,
    ) -> Result<Vec<TexelPanes>, Cancelled> {
        let init = || Scratch::new(self.clusters, None);
        match prepared {
            Prepared::Gather(mis) => par_texels(texels, control, init, |scratch, t| {
                self.gather_texel(scratch, t, width, mis.as_ref())
            }),
            Prepared::Scatter { vpls, rc2 } => {
                par_texels(texels, control, init, |scratch, t| self.scatter_texel(scratch, t, vpls, *rc2))
            }
        }
    }

    /// The gather's contributions at `texels` (as [`Transport::run_texels`]) with where each
    /// texel's walks went, on `grid` ([`Trace`]).
    pub fn run_traced(
        &self,
        texels: &[Texel],
        width: u32,
        grid: &VoxelGrid,
        rooms: &Rooms,
        control: Control,
    ) -> Result<Vec<(TexelPanes, Trace)>, Cancelled> {
        let init = || Scratch::new(self.clusters, Some((grid, rooms)));
        par_texels(texels, control, init, |scratch, t| {
            let panes = self.gather_texel(scratch, t, width, None);
            (panes, scratch.take_trace())
        })
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
}
