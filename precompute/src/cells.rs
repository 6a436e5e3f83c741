//! Entry cells (DESIGN.md §4, `prm::prm_file::Cells`): the surface each entry point stands for.
//!
//! The runtime weights an entry by the power its cell receives over the entry's area, so the
//! cells must tile the lit surfaces: then the weights carry all the power that reaches them,
//! however close a light comes (a point sample misses a hot spot smaller than the entry
//! spacing). A cell is the entry's Voronoi region among the entries of its own triangle,
//! clipped to the triangle and cut into a fan of triangles around the entry.
//!
//! A triangle too small to get an entry joins the cell of an entry on the same surface: the
//! nearest one reached across shared edges (welded positions) between triangles facing that
//! entry's way (normals within ~45°), at most a few entry spacings along the way. Nearness in
//! space alone is not enough: the gather once credited a walk's hit to the nearest entry
//! facing the same way (the first of four it could see, else the nearest), and on the top of
//! a plinth 30 cm high that was the floor beside it, so a lamp lighting the floor lit the
//! plinth top in the panes (the chamber's pillar bases 2-3x too bright). Where no edge path
//! leads (an unwelded mesh, a detail of its own), the nearest entry facing the same way whose
//! nearly parallel plane lies within half a spacing is taken; what no entry takes is reported.
//! Entries inside solids are dropped before the cells are cut: the kept entries of a triangle
//! share all of it, and a triangle whose entries were all dropped joins a neighbour's cell as
//! one without entries does (a plinth top whose entries stood under its pillar).
//!
//! [`CellOwners`] answers which cell holds a given point of a triangle, by the same rules, so
//! the gather credits a walk's hit to exactly the cell whose power weights it.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};

use glam::{DVec2, IVec3, Vec3};
use prm::prm_file::{Cells, Entry};
use prm::Scene;
use rayon::prelude::*;

/// The cells and what they leave out.
#[derive(Clone, Debug, Default)]
pub struct CellReport {
    /// Area of the triangles no entry took (no entry of theirs, none near enough).
    pub area_without_entry: f64,
}

/// Which kept entry's cell holds each point of each triangle ([`entry_cells`]'s rules).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct CellOwners {
    /// Per triangle, `first[t]..first[t + 1]` into `sites`.
    first: Vec<u32>,
    /// The kept entries on each triangle in sampled order: position and kept index.
    sites: Vec<(Vec3, u32)>,
    /// Per triangle without a kept entry: the kept entry whose cell it joined, or [`NONE`].
    joined: Vec<u32>,
    /// Per triangle, its site grid in `grids` ([`NONE`]: up to [`FEW_SITES`] sites, tried in
    /// turn). A floor of two triangles holds hundreds of sites, and the gather asks for the
    /// owner of every walk vertex.
    grid_of: Vec<u32>,
    grids: Vec<SiteGrid>,
}

/// A triangle's sites on a grid in its own plane, cells one entry spacing wide.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct SiteGrid {
    origin: Vec3,
    /// Unit in-plane axes.
    axes: [Vec3; 2],
    cell: f32,
    size: [i32; 2],
    /// Per cell (row-major), `first[c]..first[c + 1]` into `items`: site indices.
    first: Vec<u32>,
    items: Vec<u32>,
}

impl SiteGrid {
    fn new(corners: [Vec3; 3], sites: &[(Vec3, u32)], offset: usize, cell: f32) -> SiteGrid {
        let u = (corners[1] - corners[0]).normalize_or_zero();
        let n = (corners[1] - corners[0]).cross(corners[2] - corners[0]);
        let v = n.cross(u).normalize_or_zero();
        let (mut lo, mut hi) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
        for c in corners {
            let q = glam::Vec2::new(u.dot(c - corners[0]), v.dot(c - corners[0]));
            (lo, hi) = (lo.min(q), hi.max(q));
        }
        let origin = corners[0] + u * lo.x + v * lo.y;
        let size = [((hi.x - lo.x) / cell).floor() as i32 + 1, ((hi.y - lo.y) / cell).floor() as i32 + 1];
        let mut grid = SiteGrid { origin, axes: [u, v], cell, size, first: Vec::new(), items: Vec::new() };
        let cells = (size[0] * size[1]) as usize;
        let mut lists = vec![Vec::new(); cells];
        for (i, &(q, _)) in sites.iter().enumerate() {
            let [x, y] = grid.coords(q);
            lists[(y * size[0] + x) as usize].push((offset + i) as u32);
        }
        grid.first.push(0);
        for l in lists {
            grid.items.extend(l);
            grid.first.push(grid.items.len() as u32);
        }
        grid
    }

    /// The cell holding `p` (clamped into the grid).
    fn coords(&self, p: Vec3) -> [i32; 2] {
        let d = p - self.origin;
        let c = |k: usize| ((self.axes[k].dot(d) / self.cell).floor() as i32).clamp(0, self.size[k] - 1);
        [c(0), c(1)]
    }

    fn cell(&self, x: i32, y: i32) -> &[u32] {
        if x < 0 || y < 0 || x >= self.size[0] || y >= self.size[1] {
            return &[];
        }
        let c = (y * self.size[0] + x) as usize;
        &self.items[self.first[c] as usize..self.first[c + 1] as usize]
    }
}

/// Up to this many sites on a triangle, the owner is found by trying each.
const FEW_SITES: usize = 8;
/// Grid rings searched around a point before trying every site of its triangle.
const MAX_RING: i32 = 6;

/// No entry.
const NONE: u32 = u32::MAX;

impl CellOwners {
    /// The kept entry whose cell holds point `p` of triangle `triangle`: the nearest kept
    /// entry on the triangle (ties to the lower index, as the Voronoi fans), else the entry the
    /// triangle joined.
    pub fn owner(&self, triangle: usize, p: Vec3) -> Option<u32> {
        let (a, b) = (*self.first.get(triangle)? as usize, self.first[triangle + 1] as usize);
        let owner = if a == b {
            self.joined.get(triangle).copied().unwrap_or(NONE)
        } else {
            match self.grid_of.get(triangle) {
                Some(&g) if g != NONE => self.nearest_on_grid(p, &self.grids[g as usize], a..b),
                _ => self.nearest(p, a..b),
            }
        };
        (owner != NONE).then_some(owner)
    }

    /// The kept index of the site in `range` nearest `p` (ties to the first).
    fn nearest(&self, p: Vec3, range: std::ops::Range<usize>) -> u32 {
        let mut best = (f32::INFINITY, NONE);
        for &(q, k) in &self.sites[range] {
            let d2 = q.distance_squared(p);
            if d2 < best.0 {
                best = (d2, k);
            }
        }
        best.1
    }

    /// [`CellOwners::nearest`] through the triangle's grid: rings of cells around `p` until no
    /// further ring can hold a nearer site; every site past [`MAX_RING`].
    fn nearest_on_grid(&self, p: Vec3, grid: &SiteGrid, range: std::ops::Range<usize>) -> u32 {
        let [hx, hy] = grid.coords(p);
        // (distance², site index): the lower index wins a tie, as in a plain scan.
        let mut best = (f32::INFINITY, usize::MAX);
        let visit = |best: &mut (f32, usize), x: i32, y: i32| {
            for &i in grid.cell(x, y) {
                let i = i as usize;
                let d2 = self.sites[i].0.distance_squared(p);
                if d2 < best.0 || (d2 == best.0 && i < best.1) {
                    *best = (d2, i);
                }
            }
        };
        for ring in 0..=MAX_RING {
            if ring == 0 {
                visit(&mut best, hx, hy);
            } else {
                for d in -ring..=ring {
                    visit(&mut best, hx + d, hy - ring);
                    visit(&mut best, hx + d, hy + ring);
                }
                for d in 1 - ring..ring {
                    visit(&mut best, hx - ring, hy + d);
                    visit(&mut best, hx + ring, hy + d);
                }
            }
            // Sites outside rings 0..=ring lie at least `ring` cells away in the plane.
            let reach = ring as f32 * grid.cell;
            if best.1 != usize::MAX && best.0 <= reach * reach {
                return self.sites[best.1].1;
            }
        }
        self.nearest(p, range)
    }
}

/// Smallest cosine between a triangle without an entry and the entry whose cell it joins.
const MIN_NORMAL_COS: f32 = 0.7;
/// How far (in entry spacings, sqrt(A / N)) such a triangle's centroid may be from that entry,
/// along the surface.
const MAX_SPACINGS: f32 = 6.0;
/// Without an edge path: how far (in entry spacings) the entry may be, and how far off the
/// triangle's plane.
const MAX_SPACINGS_APART: f32 = 3.0;
const MAX_PLANE_OFFSET: f32 = 0.5;

/// The cells of `entries` (all sampled entries, in order); those with `keep[j]` false are
/// dropped from the result. The result is in the kept entries' order, with the owners of the
/// level's points in that order too.
pub fn entry_cells(scene: &Scene, entries: &[Entry], keep: &[bool]) -> (Cells, CellOwners, CellReport) {
    entry_cells_in_rooms(scene, entries, keep, None)
}

/// [`entry_cells`], a triangle without an entry joining only an entry of its own room
/// (`rooms` and the entries' rooms, [`entry_rooms`]; where both rooms are known). Without rooms a small floor triangle by the wall
/// to the next room could join that room's floor entry, a spacing or two away in the same
/// plane (tested: two rooms 30 cm apart): the walks would credit its light to the other room's
/// cluster, and the next-bounce table's row of that cell would name clusters of both rooms,
/// as the far field's texels by a wall did on the 16 chambers (`crate::far`).
pub fn entry_cells_in_rooms(
    scene: &Scene,
    entries: &[Entry],
    keep: &[bool],
    rooms: Option<(&prm::rooms::Rooms, &[Option<u32>])>,
) -> (Cells, CellOwners, CellReport) {
    // Only kept entries share out their triangles: a triangle whose entries were all dropped
    // (inside a solid) is as one without entries, and is joined to a neighbour's cell.
    let mut by_triangle: Vec<Vec<usize>> = vec![Vec::new(); scene.triangles.len()];
    for (j, e) in entries.iter().enumerate().filter(|&(j, _)| keep[j]) {
        by_triangle[e.triangle as usize].push(j);
    }
    let mut lists: Vec<Vec<[Vec3; 3]>> = (0..entries.len())
        .into_par_iter()
        .map(|j| {
            let e = &entries[j];
            let t = e.triangle as usize;
            if !keep[j] {
                return Vec::new();
            }
            let others = by_triangle[t].iter().filter(|&&k| k != j).map(|&k| (k, entries[k].position));
            voronoi_fan(scene.corners(t), (j, e.position), others)
        })
        .collect();
    let mut kept_index = vec![NONE; entries.len()];
    let mut k = 0;
    for (j, &keep) in keep.iter().enumerate() {
        if keep {
            kept_index[j] = k;
            k += 1;
        }
    }
    let spacing = entries.first().map_or(0.0, |e| e.area.sqrt());
    let (entry_room, triangle_room): (&[Option<u32>], Vec<Option<u32>>) = match rooms {
        Some((rooms, entry)) => {
            let triangle = (0..scene.triangles.len())
                .into_par_iter()
                .map(|t| {
                    by_triangle[t]
                        .is_empty()
                        .then(|| rooms.room_of_triangle(scene.corners(t), scene.face_normal(t)))
                        .flatten()
                })
                .collect();
            (entry, triangle)
        }
        None => (&[], Vec::new()),
    };
    // Whether triangle t may join entry j: not when both rooms are known and differ.
    let same_room = |t: usize, j: usize| match (triangle_room.get(t), entry_room.get(j)) {
        (Some(Some(a)), Some(Some(b))) => a == b,
        _ => true,
    };
    let mut joined = join_along_surfaces(scene, entries, &by_triangle, spacing, &same_room);
    let mut report = CellReport::default();
    for (t, members) in by_triangle.iter().enumerate() {
        if !members.is_empty() || scene.area(t) <= 0.0 {
            continue;
        }
        let corners = scene.corners(t);
        if joined[t] == NONE {
            joined[t] = nearest_in_plane(entries, keep, corners, spacing, |j| same_room(t, j));
        }
        match joined[t] {
            NONE => report.area_without_entry += scene.area(t) as f64,
            j => lists[j as usize].push(corners),
        }
    }
    let mut first = Vec::with_capacity(by_triangle.len() + 1);
    let mut sites = Vec::with_capacity(entries.len());
    first.push(0);
    for members in &by_triangle {
        sites.extend(members.iter().map(|&j| (entries[j].position, kept_index[j])));
        first.push(sites.len() as u32);
    }
    let joined = joined.iter().map(|&j| if j == NONE { NONE } else { kept_index[j as usize] }).collect();
    let (mut grid_of, mut grids) = (vec![NONE; by_triangle.len()], Vec::new());
    for t in 0..by_triangle.len() {
        let (a, b) = (first[t] as usize, first[t + 1] as usize);
        if b - a > FEW_SITES && spacing > 0.0 {
            grid_of[t] = grids.len() as u32;
            grids.push(SiteGrid::new(scene.corners(t), &sites[a..b], a, spacing));
        }
    }
    let kept_lists = lists.drain(..).zip(keep).filter(|(_, &k)| k).map(|(l, _)| l).collect();
    (Cells::from_lists(kept_lists), CellOwners { first, sites, joined, grid_of, grids }, report)
}

/// Each entry's room (`prm::rooms`): the one in front of its point, else the first found among
/// the entries on its triangle (an entry 5 cm from a wall stands in the wall's voxels; its
/// triangle's centroid may lie under a pillar on that floor, in the pillar's hollow), else None.
pub fn entry_rooms(rooms: &prm::rooms::Rooms, entries: &[Entry]) -> Vec<Option<u32>> {
    let found: Vec<Option<u32>> = entries.par_iter().map(|e| rooms.room_of(e.position, e.normal)).collect();
    let mut of_triangle: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
    for (e, f) in entries.iter().zip(&found) {
        if let Some(r) = f {
            of_triangle.entry(e.triangle).or_insert(*r);
        }
    }
    entries.iter().zip(found).map(|(e, f)| f.or_else(|| of_triangle.get(&e.triangle).copied())).collect()
}

/// The rooms with each entry that has none ([`entry_rooms`]) given the room of the nearest
/// entry before it that has one (entries follow their triangles, so that is its neighbour),
/// or after it.
pub fn filled_rooms(found: &[Option<u32>]) -> Vec<u32> {
    let mut last = found.iter().flatten().next().copied().unwrap_or(0);
    found
        .iter()
        .map(|f| {
            last = f.unwrap_or(last);
            last
        })
        .collect()
}

/// For each triangle without an entry, the kept entry (sampled index) nearest along the
/// surface: a shortest path over triangle centroids from the triangles holding kept entries,
/// across edges shared by welded positions, through triangles without entries that face the
/// entry's way and lie in its room (`same_room(triangle, entry)`), no longer than
/// [`MAX_SPACINGS`]. [`NONE`] where none is reached.
fn join_along_surfaces(
    scene: &Scene,
    entries: &[Entry],
    by_triangle: &[Vec<usize>],
    spacing: f32,
    same_room: &(dyn Fn(usize, usize) -> bool + Sync),
) -> Vec<u32> {
    let n = scene.triangles.len();
    let mut joined = vec![NONE; n];
    if !(spacing > 0.0) {
        return joined;
    }
    let neighbours = edge_neighbours(scene);
    let centroid = |t: usize| {
        let [a, b, c] = scene.corners(t);
        (a + b + c) / 3.0
    };
    let limit = MAX_SPACINGS * spacing;
    // (length in f32 bits: non-negative floats order as their bits; entry; triangle)
    let mut heap = BinaryHeap::new();
    for (t, members) in by_triangle.iter().enumerate() {
        for &j in members {
            heap.push(Reverse((entries[j].position.distance(centroid(t)).to_bits(), j as u32, t as u32)));
        }
    }
    let mut done = vec![false; n];
    while let Some(Reverse((d, j, t))) = heap.pop() {
        let t = t as usize;
        if done[t] {
            continue;
        }
        done[t] = true;
        if by_triangle[t].is_empty() {
            joined[t] = j;
        }
        let (d, normal) = (f32::from_bits(d), entries[j as usize].normal);
        for &u in &neighbours[t] {
            let u = u as usize;
            if done[u]
                || !by_triangle[u].is_empty()
                || scene.face_normal(u).dot(normal) < MIN_NORMAL_COS
                || !same_room(u, j as usize)
            {
                continue;
            }
            let du = d + centroid(t).distance(centroid(u));
            if du <= limit {
                heap.push(Reverse((du.to_bits(), j, u as u32)));
            }
        }
    }
    joined
}

/// Per triangle, the triangles sharing an edge with it (corners welded at 1e-6 of the level's
/// size, so meshes split per face still connect).
fn edge_neighbours(scene: &Scene) -> Vec<Vec<u32>> {
    let weld = (1e-6 * scene.diagonal()).max(f32::MIN_POSITIVE);
    let mut ids: HashMap<IVec3, u32> = HashMap::new();
    let mut id = |p: Vec3| {
        let next = ids.len() as u32;
        *ids.entry((p / weld).round().as_ivec3()).or_insert(next)
    };
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for t in 0..scene.triangles.len() {
        let c = scene.corners(t).map(&mut id);
        for (a, b) in [(c[0], c[1]), (c[1], c[2]), (c[2], c[0])] {
            if a != b {
                edges.entry((a.min(b), a.max(b))).or_default().push(t as u32);
            }
        }
    }
    let mut neighbours = vec![Vec::new(); scene.triangles.len()];
    let mut shared: Vec<_> = edges.into_values().filter(|ts| ts.len() > 1).collect();
    shared.sort_unstable();
    for ts in shared {
        for &a in &ts {
            neighbours[a as usize].extend(ts.iter().filter(|&&b| b != a));
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    neighbours
}

/// The nearest kept entry (sampled index) facing the way of the triangle `corners`, within
/// [`MAX_SPACINGS_APART`] of its centroid and [`MAX_PLANE_OFFSET`] spacings of its plane (a
/// coplanar neighbour that shares no edge with it, or the pillar face 15 cm behind a plinth
/// side that got no entry; not the floor 30 cm under a plinth top); [`NONE`] if there is none.
fn nearest_in_plane(
    entries: &[Entry],
    keep: &[bool],
    corners: [Vec3; 3],
    spacing: f32,
    same_room: impl Fn(usize) -> bool,
) -> u32 {
    let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
    let n = (corners[1] - corners[0]).cross(corners[2] - corners[0]).normalize_or_zero();
    (0..entries.len())
        .filter(|&j| keep[j] && entries[j].normal.dot(n) >= MIN_NORMAL_COS && same_room(j))
        .filter(|&j| n.dot(entries[j].position - centroid).abs() <= MAX_PLANE_OFFSET * spacing)
        .map(|j| (j, entries[j].position.distance_squared(centroid)))
        .filter(|&(_, d2)| d2 <= (MAX_SPACINGS_APART * spacing).powi(2))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
        .map_or(NONE, |(j, _)| j as u32)
}

/// Entry `me`'s Voronoi region among `others` (entries on the same triangle), clipped to the
/// triangle `corners` and fanned around the entry: triangles counter-clockwise seen from the
/// triangle's front. Entries at the same point: the lower index takes the region.
fn voronoi_fan(
    corners: [Vec3; 3],
    me: (usize, Vec3),
    others: impl Iterator<Item = (usize, Vec3)>,
) -> Vec<[Vec3; 3]> {
    let [p0, p1, p2] = corners;
    let normal = (p1 - p0).cross(p2 - p0);
    if !(normal.length_squared() > 0.0) {
        return Vec::new();
    }
    // A 2D frame in the triangle's plane, counter-clockwise from the front; f64 so clipped
    // corners shared by neighbouring cells agree closely.
    let u = (p1 - p0).normalize().as_dvec3();
    let v = normal.normalize().as_dvec3().cross(u);
    let origin = p0.as_dvec3();
    let to_2d = |p: Vec3| {
        let d = p.as_dvec3() - origin;
        DVec2::new(d.dot(u), d.dot(v))
    };
    let to_3d = |q: DVec2| (origin + u * q.x + v * q.y).as_vec3();
    let z = to_2d(me.1);
    let mut poly: Vec<DVec2> = corners.iter().map(|&c| to_2d(c)).collect();
    let mut near: Vec<(f64, usize, DVec2)> = others
        .map(|(k, p)| {
            let q = to_2d(p);
            (q.distance_squared(z), k, q)
        })
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    for (d2, k, q) in near {
        // Past twice the farthest corner of the region, no bisector can cut it.
        let reach = poly.iter().map(|p| p.distance_squared(z)).fold(0.0, f64::max);
        if d2 > 4.0 * reach {
            break;
        }
        if d2 == 0.0 {
            if k < me.0 {
                return Vec::new();
            }
            continue;
        }
        // Keep the side nearer to z: (p - midpoint) . (q - z) <= 0.
        poly = clip(&poly, (z + q) * 0.5, q - z);
        if poly.is_empty() {
            return Vec::new();
        }
    }
    let zp = me.1;
    (0..poly.len())
        .filter_map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            // Only pieces with area (the entry on an edge makes slivers of none).
            ((a - z).perp_dot(b - z) > 0.0).then(|| [zp, to_3d(a), to_3d(b)])
        })
        .collect()
}

/// The convex polygon `poly` cut to the half-plane `(p - m) . dir <= 0` (Sutherland-Hodgman).
fn clip(poly: &[DVec2], m: DVec2, dir: DVec2) -> Vec<DVec2> {
    let side = |p: DVec2| (p - m).dot(dir);
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let (sa, sb) = (side(a), side(b));
        if sa <= 0.0 {
            out.push(a);
        }
        if (sa < 0.0 && sb > 0.0) || (sa > 0.0 && sb < 0.0) {
            out.push(a + (b - a) * (sa / (sa - sb)));
        }
    }
    out
}

/// Side of [`reflections`]' stratified grid of directions.
const STAY_SIDE: u32 = 16;
/// Cosine rays per entry in [`reflections`]: one per cell of the grid.
pub const STAY_RAYS: u32 = STAY_SIDE * STAY_SIDE;
/// Most rounds of [`reflections`]' fixed-point iteration for the bounce gains (it stops when a
/// round changes no gain by more than a part in a million): each round adds one bounce, and at
/// the brightest albedo our levels use (0.8) a round's step falls under 1e-6 of the gain
/// within about 55 rounds. Where albedos near 1 close a region the rounds stop short, and the
/// rest is added as a geometric series of the last step (`reflections`).
const GAIN_ROUNDS: usize = 64;

/// What the light an entry's cell reflects does on the level ([`reflections`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Reflections {
    /// Per entry, the share of its cell's reflected light that lands on the level, in [0, 1].
    pub stays: Vec<f32>,
    /// Per entry, `g_j`: the light that lands on the level over every bounce per unit its cell
    /// reflects, channel by channel (`prm::prm_file` module doc, *Bounce gains*).
    pub gains: Vec<Vec3>,
}

/// Per entry, its stay share and its bounce gain. From each cell, [`STAY_RAYS`]
/// cosine-distributed rays from points spread over it by area (a stratified 16 x 16 grid of
/// directions, points by the entry's own stream): those that hit a surface make the stay share
/// `s_j` (the rest leave through an opening to the sky), and where they land the row `F_jk`,
/// the share of cell j's reflected light that lands in cell k. The gains solve
/// `g_j = s_j + sum_k F_jk rho_k g_k` (rho: the entry's albedo) by fixed-point iteration: the
/// light that lands after one bounce, plus what the cells it lands in send on; with at most
/// `bounces` landings where the walks stop there (`PrecomputeParams::max_bounces`: one gives
/// the stay share). A hit with no
/// cell (the back of a double-sided triangle) lands and goes no further, as in the walks; the
/// back of a one-sided surface absorbs, unless the ray's point is buried inside a solid
/// (`prm::texels::is_buried`: the part of a floor cell under a plinth, of a plinth's top
/// under its pillar): no light reaches such a point, and its ray is not counted at all. (One
/// ray straight up could not tell them apart: the chamber's pillars are open to their
/// capitals.) Counted as landing, the plinth tops
/// of the chamber read gains of 1.7-2.5 where the floor's are 2.8 (40 % of some tops lie
/// under the shaft), and in a cluster with a spot's floor cell they raised its weight by
/// up to 9 %. A cell of no area, or all inside, stays whole with gain 1.
///
/// The runtime weighs each entry's light in its cluster's mean by `rho_j g_j`: a pane answers
/// even light over its cluster, and under it every cell adds `rho_j g_j` to the pane's total;
/// weighted so, a cluster's pane carries the total its lit cells would (the stay share alone,
/// before, left the chamber 3-4 % too bright under a flashlight on a pillar at every seed:
/// `docs/near-lights.md`, *Bounce gains*).
pub fn reflections(
    scene: &prm::Scene,
    bvh: &prm::Bvh,
    cells: &Cells,
    owners: &CellOwners,
    albedo: &[Vec3],
    seed: u64,
    bounces: u32,
) -> Reflections {
    use rand::Rng;
    let n = cells.first.len().saturating_sub(1);
    // Per entry: its stay share and its row.
    let rows: Vec<(f32, Vec<(u32, f32)>)> = (0..n)
        .into_par_iter()
        .map(|j| {
            let spread = cells.spread(j);
            if !(spread.total > 0.0) {
                return (1.0, Vec::new());
            }
            let mut rng = prm::sampling::stream(seed, 8, j as u64);
            // Rays counted (those from points inside a solid are not), rays landing.
            let (mut counted, mut stays, mut row) = (0u32, 0u32, Vec::new());
            for k in 0..STAY_RAYS {
                let (p, normal) = spread.point(rng.random(), rng.random(), rng.random());
                let (u1, u2) = (
                    ((k % STAY_SIDE) as f32 + rng.random::<f32>()) / STAY_SIDE as f32,
                    ((k / STAY_SIDE) as f32 + rng.random::<f32>()) / STAY_SIDE as f32,
                );
                let dir = prm::sampling::cosine_direction(normal, u1.min(0.999_999), u2.min(0.999_999));
                let Some(hit) = bvh.trace_from_surface(p, normal, dir) else {
                    counted += 1;
                    continue;
                };
                let tri = hit.triangle as usize;
                // The back of a one-sided surface absorbs; but where the point lies inside a
                // solid (a floor cell under a plinth, a plinth's top under its pillar) no light
                // reaches it, and the ray is not the cell's.
                let Some(facing) = scene.facing_normal(tri, dir) else {
                    counted += !prm::texels::is_buried(scene, bvh, p, normal) as u32;
                    continue;
                };
                counted += 1;
                stays += 1;
                // Cells lie on the front of their triangles, as in the walks.
                let front = facing.dot(scene.face_normal(tri)) > 0.0;
                if let Some(o) = owners.owner(tri, scene.point(tri, hit.bary())).filter(|_| front) {
                    row.push(o);
                }
            }
            if counted == 0 {
                return (1.0, Vec::new());
            }
            // The row as (cell, share): a cell hit by several rays is one element.
            row.sort_unstable();
            let per = 1.0 / counted as f32;
            let mut shares: Vec<(u32, f32)> = Vec::new();
            for k in row {
                match shares.last_mut() {
                    Some(last) if last.0 == k => last.1 += per,
                    _ => shares.push((k, per)),
                }
            }
            (stays as f32 * per, shares)
        })
        .collect();
    let reflect = |k: u32| albedo.get(k as usize).copied().unwrap_or(Vec3::ZERO);
    let mut gains: Vec<Vec3> = rows.iter().map(|r| Vec3::splat(r.0)).collect();
    // Round r brings landing r + 2: a map of at most `bounces` bounces counts as many.
    let rounds = GAIN_ROUNDS.min(bounces.saturating_sub(1) as usize);
    // Each entry's step in the last two rounds.
    let (mut step, mut before): (Vec<Vec3>, Vec<Vec3>) = (Vec::new(), Vec::new());
    let mut settled = rounds == 0;
    for _ in 0..rounds {
        let next: Vec<Vec3> = rows
            .par_iter()
            .map(|(s, row)| {
                Vec3::splat(*s) + row.iter().map(|&(k, f)| reflect(k) * gains[k as usize] * f).sum::<Vec3>()
            })
            .collect();
        // Settled: another round changes no gain by more than a part in a million.
        settled =
            next.iter().zip(&gains).all(|(a, b)| (*a - *b).abs().max_element() <= 1e-6 * a.max_element());
        before = std::mem::replace(&mut step, next.iter().zip(&gains).map(|(a, b)| *a - *b).collect());
        gains = next;
        if settled {
            break;
        }
    }
    // Not settled within the rounds (albedos near 1): each further round's step is the last
    // one's times about the same factor lambda (the light its region keeps per bounce), so the
    // rounds left add the last step times lambda (1 - lambda^n) / (1 - lambda), n of them up to
    // the bounce cap; lambda entry by entry and channel by channel (two closed rooms of albedo
    // 0.99 and 0.95 each keep their own), and 1 where the steps no longer shrink (albedo 1:
    // the tail is the n bounces left). A closed box of albedo 0.99 reads its gains 100 so, 47
    // without.
    let left = bounces.saturating_sub(1) as usize - rounds;
    if !settled && left > 0 && before.len() == step.len() {
        let n = left.min(i32::MAX as usize) as f32;
        let series = |lambda: f32| {
            if lambda >= 1.0 - 1e-6 {
                n
            } else {
                lambda * (1.0 - lambda.powf(n)) / (1.0 - lambda)
            }
        };
        for ((g, d), b) in gains.iter_mut().zip(&step).zip(&before) {
            let tail = Vec3::from_array(std::array::from_fn(|c| {
                if b[c] > 0.0 && d[c] > 0.0 {
                    series((d[c] / b[c]).min(1.0))
                } else {
                    0.0
                }
            }));
            *g += *d * tail;
        }
    }
    Reflections { stays: rows.into_iter().map(|r| r.0).collect(), gains }
}
