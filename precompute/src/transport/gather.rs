//! The gather estimator and its multiple-importance-sampled variant (module doc of
//! [`super`]): walks from each texel, each vertex credited to the cluster owning it.

use std::sync::atomic::Ordering;

use glam::Vec3;
use prm::prm_file::Entry;
use prm::sampling::{cosine_direction, shifted_hammersley, stream};
use prm::Texel;
use rand::Rng;

use super::{bounce, kept_share, Scratch, TexelPanes, Transport};

/// Per-cluster members and region areas for [`super::Estimator::Mis`].
pub struct MisTables {
    members: Vec<Vec<u32>>,
    /// Region area of each cluster: |c| A / N.
    area: Vec<f32>,
}

impl MisTables {
    pub(super) fn new(entries: &[Entry], assignment: &[u32], clusters: usize, total_area: f64) -> Self {
        let mut members = vec![Vec::new(); clusters];
        for (i, &c) in assignment.iter().enumerate() {
            members[c as usize].push(i as u32);
        }
        let per_entry = (total_area / entries.len().max(1) as f64) as f32;
        let area = members.iter().map(|m| m.len() as f32 * per_entry).collect();
        MisTables { members, area }
    }
}

impl Transport<'_> {
    pub(super) fn gather_texel(
        &self,
        scratch: &mut Scratch,
        t: &Texel,
        width: u32,
        mis: Option<&MisTables>,
    ) -> TexelPanes {
        let mut rng = stream(self.seed, 3, t.j as u64 * width as u64 + t.i as u64);
        let k = self.paths.max(1);
        // First directions: a Hammersley set shifted by a random rotation (Cranley-Patterson),
        // so each is uniformly distributed (unbiased) while together they stratify the
        // hemisphere; the first bounce carries most of the indirect light.
        let shift: (f32, f32) = (rng.random(), rng.random());
        let linked = self.linked.map(|l| l.of(t.j * width + t.i));
        // The table's next bounce (module `next`): not with MIS, whose first bounce is its own.
        let next = self.next.filter(|_| mis.is_none());
        let whole = next.is_some_and(|n| n.whole(t.j * width + t.i));
        for path in 0..k {
            let (mut x, mut n) = (t.position, t.normal);
            let mut beta = Vec3::ONE;
            let mut depth = 0;
            // Whether the bounce to the next hit is given (the texel's exact panes, then the
            // table's row at each vertex).
            let mut given = whole;
            loop {
                let (u1, u2) = if depth == 0 {
                    shifted_hammersley(path, k, shift)
                } else {
                    (rng.random(), rng.random())
                };
                let d = cosine_direction(n, u1, u2);
                let hit = bounce(self.scene, self.bvh, x, n, d, &self.stats);
                // A back-facing hit ends the walk too; its segment is recorded to the level's
                // edge (more than it went, which only widens the footprint).
                scratch.segment(x, d, hit.as_ref().map(|v| v.position));
                let Some(v) = hit else { break };
                let (y, ny, a) = (v.position, v.normal, v.albedo);
                beta *= a;
                if beta == Vec3::ZERO {
                    break;
                }
                // Cells lie on the front of their triangles (entries face that way); the back of
                // a double-sided one has none, and its light is lost (counted).
                let front = ny.dot(self.scene.face_normal(v.triangle)) > 0.0;
                let owner = if front { self.owners.owner(v.triangle, y) } else { None };
                // A linked cell's first bounce is the links' (the walk goes on through it); a
                // bounce the table gives is the table's.
                let credit = match (depth, owner, linked) {
                    _ if given && next.is_some_and(|n| n.reaches(x.distance(y))) => 0.0,
                    (0, Some(e), Some(linked)) => kept_share(linked, e),
                    _ => 1.0,
                };
                given = false;
                // The row is the bounce after this vertex's own: only within the cap.
                if let (Some(n), Some(e)) = (next, owner) {
                    if depth + 1 < self.max_bounces && n.row(e).is_some() {
                        scratch.visit(e, beta, self.entries.len());
                        given = true;
                    } else if depth + 1 < self.max_bounces && n.left_out(e) {
                        // A row an update did not make: the walk is not what a full bake's is.
                        self.stats.rows_left_out.fetch_add(1, Ordering::Relaxed);
                    }
                }
                match owner.map(|e| self.assignment[e as usize]) {
                    Some(_) if credit == 0.0 => {}
                    Some(c) if depth == 0 && mis.is_some() => {
                        // First vertex under MIS: weight against the entry samples of c.
                        let area_c = mis.map_or(0.0, |m| m.area[c as usize]);
                        let r2 = (y - t.position).length_squared();
                        let p_b = (t.normal.dot(y - t.position).max(0.0) * ny.dot(t.position - y).max(0.0))
                            / (std::f32::consts::PI * r2 * r2);
                        let w = 1.0 / (1.0 + 1.0 / (k as f32 * p_b * area_c).max(1e-30));
                        scratch.accumulate(c, beta * w);
                    }
                    Some(c) => scratch.accumulate(c, beta * credit),
                    None => {
                        self.stats.unowned.fetch_add(1, Ordering::Relaxed);
                        if let Some(t) = scratch.trace.as_mut() {
                            t.unowned += 1;
                        }
                    }
                }
                depth += 1;
                let Some(q) = self.roulette(depth, a, &mut rng) else {
                    if let Some(t) = scratch.trace.as_mut() {
                        t.truncated += (depth >= self.max_bounces) as u64;
                    }
                    break;
                };
                beta /= q;
                x = y;
                n = ny;
            }
        }
        if let Some(n) = next {
            scratch.add_visits(n);
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
                scratch.accumulate(c as u32, value * k as f32);
            }
        }
        scratch.take(1.0 / k as f32)
    }

    /// The gather estimator evaluated directly for one direct-light field (per-cluster
    /// irradiance `weights`), with the same random streams as [`Transport::run`]: the twin the
    /// superposition test holds the pane sum to.
    pub fn gather_field(&self, set: &prm::TexelSet, weights: &[Vec3]) -> Vec<Vec3> {
        let mut scratch = Scratch::new(self.clusters, None);
        set.texels
            .iter()
            .map(|t| {
                self.gather_texel(&mut scratch, t, set.width, None)
                    .iter()
                    .map(|&(c, v)| v * weights[c as usize])
                    .fold(Vec3::ZERO, |a, b| a + b)
            })
            .collect()
    }
}
