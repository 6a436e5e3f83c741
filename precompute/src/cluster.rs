//! Entry clustering (paper 004 §3): entries that are close and similarly oriented share a pane
//! and, at run time, one weight (the mean irradiance of the members).
//!
//! k-means (Lloyd's algorithm, k-means++ seeding) on 6-D features
//! `(p / L, n)`, with `L = sqrt(A / C)` the side of a square of one cluster's share of the
//! surface. So a cluster spans about L, and two entries whose normals differ by 90 degrees are
//! as far apart as two entries 1.4 L apart on one plane: walls meeting at a corner, and the two
//! faces of a thin wall, fall into different clusters. Scaling by L makes the result independent
//! of the level's units.
//!
//! The `kmeans` crate named in the brief needs a nightly compiler (`portable_simd`) in every
//! published version, so this is our own: deterministic (seeded init, fixed iteration order,
//! ties to the lower index) and parallel only where the result cannot depend on it.

use glam::Vec3;
use prm::prm_file::Entry;
use rand::Rng;
use rayon::prelude::*;

use prm::sampling::stream;

/// The clusters of a set of entries.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Clustering {
    /// Cluster of each entry.
    pub assignment: Vec<u32>,
    /// Entries of each cluster, ascending.
    pub members: Vec<Vec<u32>>,
}

type Feature = [f32; 6];

fn feature(e: &Entry, inv_l: f32) -> Feature {
    let p = e.position * inv_l;
    [p.x, p.y, p.z, e.normal.x, e.normal.y, e.normal.z]
}

fn dist2(a: &Feature, b: &Feature) -> f32 {
    let mut s = 0.0;
    for k in 0..6 {
        let d = a[k] - b[k];
        s += d * d;
    }
    s
}

/// The nearest centre, ties to the lower index, by testing every one (the grid's twin).
#[cfg(test)]
fn nearest(f: &Feature, centres: &[Feature]) -> u32 {
    let mut best = (f32::INFINITY, 0u32);
    for (c, centre) in centres.iter().enumerate() {
        let d = dist2(f, centre);
        if d < best.0 {
            best = (d, c as u32);
        }
    }
    best.1
}

/// A grid over the features' positions (`p / L`): the normal part of a feature distance is at
/// most 4, the position part grows with distance, so a nearest centre, or an entry a new
/// centre comes nearer to, is found among the cells around a point. The answers are exactly
/// those of testing everything (the bounds keep a margin over f32 rounding), so the clusters,
/// and the file, are the same; the cost of a level of many rooms grows with its entries, not
/// with entries x clusters.
struct Grid {
    lo: Vec3,
    /// Cell side (in units of L): 1, or larger where the level is so sparse that unit cells
    /// would outnumber the items many times over.
    side: f32,
    dims: [i32; 3],
}

/// Relative slack on distance bounds: an f32 distance sum may come out this much under the
/// exact one.
const BOUND_SLACK: f32 = 1e-4;

impl Grid {
    fn new(feats: &[Feature], items: usize) -> Grid {
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for f in feats {
            let p = Vec3::new(f[0], f[1], f[2]);
            lo = lo.min(p);
            hi = hi.max(p);
        }
        if !(lo.is_finite() && hi.is_finite()) {
            (lo, hi) = (Vec3::ZERO, Vec3::ZERO);
        }
        let extent = (hi - lo).max(Vec3::ZERO);
        let budget = (8 * items + 64) as f32;
        let mut side = 1.0f32;
        while ((extent / side).floor() + Vec3::ONE).element_product() > budget {
            side *= 2.0;
        }
        let d = (extent / side).floor() + Vec3::ONE;
        Grid { lo, side, dims: [d.x as i32, d.y as i32, d.z as i32] }
    }

    fn cells(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    fn cell_of(&self, f: &Feature) -> [i32; 3] {
        let p = (Vec3::new(f[0], f[1], f[2]) - self.lo) / self.side;
        [0, 1, 2].map(|a| (p[a].floor() as i32).clamp(0, self.dims[a] - 1))
    }

    fn index(&self, c: [i32; 3]) -> usize {
        ((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]) as usize
    }

    /// Items binned by cell: (start per cell, items), each cell's items ascending.
    fn bin(&self, feats: &[Feature]) -> (Vec<u32>, Vec<u32>) {
        let cell: Vec<usize> = feats.iter().map(|f| self.index(self.cell_of(f))).collect();
        let mut start = vec![0u32; self.cells() + 1];
        for &c in &cell {
            start[c + 1] += 1;
        }
        for k in 0..self.cells() {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; feats.len()];
        for (i, &c) in cell.iter().enumerate() {
            items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        (start, items)
    }

    /// The cells within Chebyshev distance `r` of `c`, clipped to the grid, on the shell only.
    fn shell(&self, c: [i32; 3], r: i32, mut visit: impl FnMut([i32; 3])) {
        let lo = [0, 1, 2].map(|a| (c[a] - r).max(0));
        let hi = [0, 1, 2].map(|a| (c[a] + r).min(self.dims[a] - 1));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    let on = (x - c[0]).abs() == r || (y - c[1]).abs() == r || (z - c[2]).abs() == r;
                    if on {
                        visit([x, y, z]);
                    }
                }
            }
        }
    }
}

/// Centres binned in a [`Grid`], for exact nearest-centre queries.
struct Centres<'a> {
    grid: &'a Grid,
    centres: &'a [Feature],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl<'a> Centres<'a> {
    fn new(grid: &'a Grid, centres: &'a [Feature]) -> Centres<'a> {
        let (start, items) = grid.bin(centres);
        Centres { grid, centres, start, items }
    }

    /// The nearest centre to `f`, ties to the lower index: what testing every centre gives.
    fn nearest(&self, f: &Feature) -> u32 {
        let g = self.grid;
        let c0 = g.cell_of(f);
        let mut best = (f32::INFINITY, u32::MAX);
        let reach = g.dims.iter().copied().max().unwrap_or(1);
        for r in 0..=reach {
            // Every cell of ring r is at least (r - 1) cells from f: stop once that is beyond
            // the best distance (with slack, so a tie or a rounding cannot hide there).
            let gap = (r - 1).max(0) as f32 * g.side;
            if best.1 != u32::MAX && gap * gap > best.0 * (1.0 + BOUND_SLACK) + f32::MIN_POSITIVE {
                break;
            }
            g.shell(c0, r, |c| {
                let k = g.index(c);
                for &i in &self.items[self.start[k] as usize..self.start[k + 1] as usize] {
                    let d = dist2(f, &self.centres[i as usize]);
                    if d < best.0 || (d == best.0 && i < best.1) {
                        best = (d, i);
                    }
                }
            });
        }
        if best.1 == u32::MAX {
            0
        } else {
            best.1
        }
    }
}

/// k-means within each room (`room`: per entry, a room of `prm::rooms`; any ids), so that no
/// cluster takes entries from both sides of a wall. The k clusters are shared out by the
/// rooms' entry area (each room with entries gets at least one, and no more than it has
/// entries), each room's clusters are [`cluster_entries`]' with L from its own area, and the
/// clusters are numbered room after room in the order the rooms first appear. One room (or
/// fewer clusters than rooms): exactly `cluster_entries` over all.
pub fn cluster_by_room(
    entries: &[Entry],
    room: &[u32],
    k: usize,
    total_area: f64,
    iterations: usize,
    seed: u64,
) -> Clustering {
    let mut rooms: Vec<u32> = Vec::new();
    let mut index = std::collections::HashMap::new();
    let of: Vec<usize> = room
        .iter()
        .map(|&r| {
            *index.entry(r).or_insert_with(|| {
                rooms.push(r);
                rooms.len() - 1
            })
        })
        .collect();
    let n = entries.len();
    if rooms.len() <= 1 || k < rooms.len() || room.len() != n {
        return cluster_entries(entries, k, total_area, iterations, seed);
    }
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); rooms.len()];
    let mut area = vec![0.0f64; rooms.len()];
    for (e, &r) in of.iter().enumerate() {
        members[r].push(e as u32);
        area[r] += entries[e].area.max(0.0) as f64;
    }
    let whole: f64 = area.iter().sum::<f64>().max(f64::MIN_POSITIVE);
    // One cluster each, then the rest one at a time to the room with the most area per
    // cluster that still has entries to spare (ties to the first room).
    let mut share = vec![1usize; rooms.len()];
    let mut heap: std::collections::BinaryHeap<(OrdF64, std::cmp::Reverse<usize>)> = (0..rooms.len())
        .filter(|&r| members[r].len() > 1)
        .map(|r| (OrdF64(area[r]), std::cmp::Reverse(r)))
        .collect();
    let mut left = k.min(n) - rooms.len();
    while left > 0 {
        let Some((_, std::cmp::Reverse(r))) = heap.pop() else { break };
        share[r] += 1;
        left -= 1;
        if share[r] < members[r].len() {
            heap.push((OrdF64(area[r] / share[r] as f64), std::cmp::Reverse(r)));
        }
    }
    let mut out = Clustering { assignment: vec![0; n], members: Vec::with_capacity(k) };
    for (r, list) in members.iter().enumerate() {
        let sub: Vec<Entry> = list.iter().map(|&e| entries[e as usize]).collect();
        let room_area = total_area * area[r] / whole;
        let c = cluster_entries(
            &sub,
            share[r],
            room_area,
            iterations,
            seed ^ (r as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let base = out.members.len() as u32;
        for (i, &e) in list.iter().enumerate() {
            out.assignment[e as usize] = base + c.assignment[i];
        }
        out.members.extend(c.members.into_iter().map(|m| m.into_iter().map(|i| list[i as usize]).collect()));
    }
    out
}

/// An f64 ordered by `total_cmp` (for the shares' heap).
#[derive(Clone, Copy, PartialEq)]
struct OrdF64(f64);

impl Eq for OrdF64 {}

impl PartialOrd for OrdF64 {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for OrdF64 {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// Cluster `entries` into `k` clusters (at most one per entry) with `iterations` Lloyd steps.
pub fn cluster_entries(
    entries: &[Entry],
    k: usize,
    total_area: f64,
    iterations: usize,
    seed: u64,
) -> Clustering {
    let n = entries.len();
    let k = k.min(n).max(1);
    if n == 0 {
        return Clustering { assignment: Vec::new(), members: vec![Vec::new()] };
    }
    if k == n {
        return Clustering {
            assignment: (0..n as u32).collect(),
            members: (0..n as u32).map(|i| vec![i]).collect(),
        };
    }
    let l = ((total_area / k as f64).sqrt() as f32).max(f32::MIN_POSITIVE);
    let feats: Vec<Feature> = entries.iter().map(|e| feature(e, 1.0 / l)).collect();

    // k-means++ seeding.
    let mut rng = stream(seed, 2, 0);
    let mut centres: Vec<Feature> = vec![feats[rng.random_range(0..n)]];
    let mut d2: Vec<f32> = feats.iter().map(|f| dist2(f, &centres[0])).collect();
    let grid = Grid::new(&feats, n);
    let (start, by_cell) = grid.bin(&feats);
    let mut cell_max: Vec<f32> = (0..grid.cells())
        .map(|k| {
            by_cell[start[k] as usize..start[k + 1] as usize]
                .iter()
                .map(|&i| d2[i as usize])
                .fold(0.0, f32::max)
        })
        .collect();
    while centres.len() < k {
        let sum: f64 = d2.iter().map(|&d| d as f64).sum();
        let pick = if sum > 0.0 {
            let target = rng.random::<f64>() * sum;
            let mut acc = 0.0;
            let mut idx = n - 1;
            for (i, &d) in d2.iter().enumerate() {
                acc += d as f64;
                if acc > target {
                    idx = i;
                    break;
                }
            }
            idx
        } else {
            centres.len() % n
        };
        let c = feats[pick];
        // Only entries nearer the new centre than to every earlier one change: those in cells
        // whose box is nearer to it than the cell's largest distance (the rest would keep
        // `d.min(dist2)` = d anyway).
        let (cx, far) = (Vec3::new(c[0], c[1], c[2]), cell_max.iter().copied().fold(0.0f32, f32::max));
        let reach = far.sqrt() * (1.0 + BOUND_SLACK) + f32::MIN_POSITIVE;
        let span = |a: usize| {
            let lo = ((cx[a] - reach - grid.lo[a]) / grid.side).floor().max(0.0) as i32;
            let hi = ((cx[a] + reach - grid.lo[a]) / grid.side).floor().min((grid.dims[a] - 1) as f32) as i32;
            lo..=hi
        };
        for z in span(2) {
            for y in span(1) {
                for x in span(0) {
                    let k = grid.index([x, y, z]);
                    let box_lo = grid.lo + Vec3::new(x as f32, y as f32, z as f32) * grid.side;
                    let gap = (box_lo - cx).max(cx - (box_lo + Vec3::splat(grid.side))).max(Vec3::ZERO);
                    if gap.length_squared() > cell_max[k] * (1.0 + BOUND_SLACK) + f32::MIN_POSITIVE {
                        continue;
                    }
                    let mut m = 0.0f32;
                    for &i in &by_cell[start[k] as usize..start[k + 1] as usize] {
                        let d = &mut d2[i as usize];
                        *d = d.min(dist2(&feats[i as usize], &c));
                        m = m.max(*d);
                    }
                    cell_max[k] = m;
                }
            }
        }
        centres.push(c);
    }

    let mut assignment: Vec<u32> = vec![0; n];
    for _ in 0..iterations.max(1) {
        let index = Centres::new(&grid, &centres);
        let next: Vec<u32> = feats.par_iter().map(|f| index.nearest(f)).collect();
        let changed = next != assignment;
        assignment = next;
        let mut sums = vec![[0.0f64; 6]; k];
        let mut counts = vec![0usize; k];
        for (f, &c) in feats.iter().zip(&assignment) {
            counts[c as usize] += 1;
            for d in 0..6 {
                sums[c as usize][d] += f[d] as f64;
            }
        }
        for c in 0..k {
            if counts[c] > 0 {
                centres[c] = std::array::from_fn(|d| (sums[c][d] / counts[c] as f64) as f32);
            } else {
                // An empty cluster takes the entry farthest from its own centre.
                let far = (0..n)
                    .max_by(|&a, &b| {
                        let da = dist2(&feats[a], &centres[assignment[a] as usize]);
                        let db = dist2(&feats[b], &centres[assignment[b] as usize]);
                        da.total_cmp(&db).then(b.cmp(&a))
                    })
                    .unwrap_or(0);
                centres[c] = feats[far];
                assignment[far] = c as u32;
            }
        }
        if !changed {
            break;
        }
    }
    // Final assignment against the final centres; fill any cluster left empty.
    let index = Centres::new(&grid, &centres);
    assignment = feats.par_iter().map(|f| index.nearest(f)).collect();
    let mut members = vec![Vec::new(); k];
    for (i, &c) in assignment.iter().enumerate() {
        members[c as usize].push(i as u32);
    }
    members.retain(|m| !m.is_empty());
    for (c, m) in members.iter().enumerate() {
        for &i in m {
            assignment[i as usize] = c as u32;
        }
    }
    Clustering { assignment, members }
}

impl Clustering {
    /// The clustering that puts item i in cluster `assignment[i]`, of `count` clusters (all
    /// below it; a cluster may be empty).
    pub fn from_assignment(assignment: &[u32], count: u32) -> Clustering {
        let mut members = vec![Vec::new(); count as usize];
        for (i, &c) in assignment.iter().enumerate() {
            members[c as usize].push(i as u32);
        }
        Clustering { assignment: assignment.to_vec(), members }
    }
}

/// Mean member position of each cluster.
pub fn centroids(entries: &[Entry], clustering: &Clustering) -> Vec<Vec3> {
    clustering
        .members
        .iter()
        .map(|m| {
            m.iter().map(|&i| entries[i as usize].position).fold(Vec3::ZERO, |a, b| a + b)
                / m.len().max(1) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Entries on the floors and ceilings of two closed 6 x 3 x 8 m rooms a metre apart
    /// (coplanar edges a metre apart: what made k-means join the sixteen chambers' neighbours),
    /// and each entry's room from `prm::rooms`.
    fn two_rooms() -> (Vec<Entry>, Vec<u32>) {
        let mut corners = Vec::new();
        let mut entries = Vec::new();
        for x0 in [0.0f32, 7.0] {
            let (lo, hi) = (Vec3::new(x0, 0.0, 0.0), Vec3::new(x0 + 6.0, 3.0, 8.0));
            let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
            for q in [
                [v(lo.x, lo.y, lo.z), v(hi.x, lo.y, lo.z), v(hi.x, lo.y, hi.z), v(lo.x, lo.y, hi.z)],
                [v(lo.x, hi.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z)],
                [v(lo.x, lo.y, lo.z), v(lo.x, hi.y, lo.z), v(lo.x, hi.y, hi.z), v(lo.x, lo.y, hi.z)],
                [v(hi.x, lo.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(hi.x, lo.y, hi.z)],
                [v(lo.x, lo.y, lo.z), v(hi.x, lo.y, lo.z), v(hi.x, hi.y, lo.z), v(lo.x, hi.y, lo.z)],
                [v(lo.x, lo.y, hi.z), v(hi.x, lo.y, hi.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z)],
            ] {
                corners.push([q[0], q[1], q[2]]);
                corners.push([q[0], q[2], q[3]]);
            }
            for (y, n) in [(0.0, Vec3::Y), (3.0, -Vec3::Y)] {
                for i in 0..12 {
                    for k in 0..16 {
                        let position = Vec3::new(x0 + 0.25 + 0.5 * i as f32, y, 0.25 + 0.5 * k as f32);
                        entries.push(Entry {
                            position,
                            normal: n,
                            albedo: Vec3::splat(0.5),
                            area: 0.25,
                            triangle: 0,
                        });
                    }
                }
            }
        }
        let rooms = prm::rooms::Rooms::new(&corners);
        let room = entries.iter().map(|e| rooms.room_of(e.position, e.normal).unwrap()).collect();
        (entries, room)
    }

    /// k-means alone joins the two rooms' floors at the metre between them; by room, no
    /// cluster crosses, every cluster is used, the rooms share the clusters by area (equal
    /// here), and with one room the clusters are exactly k-means'.
    #[test]
    fn clusters_keep_to_one_room() {
        let (entries, room) = two_rooms();
        let area = entries.iter().map(|e| e.area as f64).sum::<f64>();
        assert_eq!(room.iter().collect::<std::collections::BTreeSet<_>>().len(), 2);
        let side = |e: u32| entries[e as usize].position.x > 6.5;
        let crossing =
            |c: &Clustering| c.members.iter().filter(|m| m.iter().any(|&e| side(e) != side(m[0]))).count();
        // The first even k at which k-means crosses the wall.
        let k = (2..=24).step_by(2).find(|&k| crossing(&cluster_entries(&entries, k, area, 20, 3)) > 0);
        let Some(k) = k else { panic!("the test wants k-means to cross the wall at some k") };
        let plain = cluster_entries(&entries, k, area, 20, 3);
        let by_room = cluster_by_room(&entries, &room, k, area, 20, 3);
        assert_eq!(crossing(&by_room), 0);
        assert_eq!(by_room.members.len(), k);
        assert!(by_room.members.iter().all(|m| !m.is_empty()));
        let left = by_room.members.iter().filter(|m| !side(m[0])).count();
        assert_eq!(left, k / 2, "equal rooms, equal shares");
        for (e, &c) in by_room.assignment.iter().enumerate() {
            assert!(by_room.members[c as usize].contains(&(e as u32)));
        }
        let one = vec![7u32; entries.len()];
        assert_eq!(cluster_by_room(&entries, &one, k, area, 20, 3), plain);
    }

    /// Features over three far-apart rooms, many sharing a position (ties), some sharing the
    /// whole feature (exact ties, which go to the lower index).
    fn features(n: usize, seed: u64) -> Vec<Feature> {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        (0..n)
            .map(|i| {
                let room = (i % 3) as f32 * 40.0;
                let p = Vec3::new(
                    room + rng.random::<f32>() * 6.0,
                    rng.random::<f32>() * 3.0,
                    rng.random::<f32>() * 9.0,
                );
                let p = if i % 7 == 0 { p.floor() } else { p };
                let n = [Vec3::X, Vec3::Y, Vec3::NEG_Z][i % 3];
                [p.x, p.y, p.z, n.x, n.y, n.z]
            })
            .collect()
    }

    #[test]
    fn the_grid_finds_what_testing_every_centre_finds() {
        for (n, k, seed) in [(3000, 97, 1), (500, 500, 2), (200, 3, 3), (1, 1, 4)] {
            let feats = features(n, seed);
            let mut centres: Vec<Feature> = features(k, seed + 10);
            centres.push([-50.0, 90.0, 3.0, 0.0, 0.0, 1.0]);
            centres.extend_from_slice(&feats[..k.min(n) / 2]);
            centres.extend_from_slice(&feats[..k.min(n) / 2]);
            // Some centres lie outside the entries' box (binned in its edge cells): still found.
            let grid = Grid::new(&feats, n);
            let index = Centres::new(&grid, &centres);
            for f in &feats {
                assert_eq!(index.nearest(f), nearest(f, &centres), "n {n} k {k}");
            }
        }
    }

    #[test]
    fn a_sparse_level_gets_coarser_cells() {
        let mut feats = features(100, 5);
        feats.push([1e6, 0.0, 1e6, 0.0, 1.0, 0.0]);
        let grid = Grid::new(&feats, feats.len());
        assert!(
            grid.side > 1.0 && grid.cells() <= 8 * feats.len() + 64,
            "{} cells of {}",
            grid.cells(),
            grid.side
        );
        let index = Centres::new(&grid, &feats[..10]);
        for f in &feats {
            assert_eq!(index.nearest(f), nearest(f, &feats[..10]));
        }
    }
}
