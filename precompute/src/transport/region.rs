//! Which cluster owns a surface point, for the gather estimators: a cluster's region is the
//! set of surface points whose nearest compatible, visible entry is one of its members.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};

use glam::{IVec3, Vec3};
use prm::prm_file::Entry;
use prm::{Bvh, Scene};

use super::TransportStats;
use crate::parallel::{par_texels, Cancelled, Control};

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
    /// Find every covered texel's owning entry and record its cluster (a pass over the texels
    /// of its own, stopped by the run's cancel flag; its progress is not reported).
    pub fn build(
        set: &prm::TexelSet,
        lookup: &RegionLookup,
        assignment: &[u32],
        bvh: &Bvh,
        stats: &TransportStats,
        cancel: &AtomicBool,
    ) -> Result<OwnerMap, Cancelled> {
        let control = Control { progress: &|_| {}, cancel };
        let owners = par_texels(
            &set.texels,
            control,
            || (),
            |_, t| {
                lookup.owner(t.position, t.normal, bvh, stats).map_or(u32::MAX, |e| assignment[e as usize])
            },
        )?;
        let mut cluster = vec![u32::MAX; set.index.len()];
        for (t, c) in set.texels.iter().zip(owners) {
            cluster[(t.j * set.width + t.i) as usize] = c;
        }
        Ok(OwnerMap { width: set.width, height: set.height, cluster })
    }

    /// The cluster owning the surface point at barycentrics `bary` of triangle `tri`.
    pub(super) fn at(&self, scene: &Scene, tri: usize, bary: Vec3) -> Option<u32> {
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
