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
