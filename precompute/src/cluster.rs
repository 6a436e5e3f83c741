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
        for (d, f) in d2.iter_mut().zip(&feats) {
            *d = d.min(dist2(f, &c));
        }
        centres.push(c);
    }

    let mut assignment: Vec<u32> = vec![0; n];
    for _ in 0..iterations.max(1) {
        let next: Vec<u32> = feats.par_iter().map(|f| nearest(f, &centres)).collect();
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
    assignment = feats.par_iter().map(|f| nearest(f, &centres)).collect();
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
