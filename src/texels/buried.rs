//! Buried sample points: a texel whose point lies under something sitting on its surface.
//!
//! A pillar standing on a floor covers part of the floor's texels. When a texel's centre falls
//! under the pillar, its sample point (the centre clamped into the owning triangle) sees only
//! the pillar's inside: every estimator reads black there, while the visible part of the
//! texel, which bilinear lookups show next to the pillar, is lit. Measured on the chamber with
//! its own lights: 309 such texels (0.8 % of them) held 25 % of the PRM's squared error against
//! the ground truth, both sides computing the same point faithfully.
//!
//! [`TexelSet::unbury`] moves such a point to the visible part of its texel: the first point of
//! a 4 x 4 grid over the texel's square, nearest the centre first, clamped into the owning
//! triangle, that is not buried. A texel with no visible point is no exit point at all: it is
//! dropped from the covered set and filled from its neighbours like the gutter, so bilinear
//! lookups next to the pillar read the light beside it, not the black beneath it.
//!
//! A point is buried when at least 3/4 of [`BURIAL_RAYS`] fixed cosine-distributed rays from it
//! hit the back of a one-sided surface (closed solids have one-sided walls).

use glam::{DVec2, Vec3};
use rayon::prelude::*;

use super::{closest_barycentrics, make_texel, Candidate, Texel, TexelSet};
use crate::sampling::{cosine_direction, radical_inverse};
use crate::{Bvh, Scene};

/// Rays a sample point sends to decide whether it is buried.
pub const BURIAL_RAYS: u32 = 16;
/// Points per side of the grid tried inside a texel whose centre is buried.
const GRID: u32 = 4;

/// True when at least 3/4 of [`BURIAL_RAYS`] cosine rays from surface point `p` (unit normal
/// `n`) hit the back of a one-sided surface. The directions are a fixed stratified set, so the
/// answer depends on the geometry only.
pub fn is_buried(scene: &Scene, bvh: &Bvh, p: Vec3, n: Vec3) -> bool {
    let mut back = 0;
    for k in 0..BURIAL_RAYS {
        let d = cosine_direction(n, (k as f32 + 0.5) / BURIAL_RAYS as f32, radical_inverse(k));
        if let Some(h) = bvh.trace_from_surface(p, n, d) {
            back += scene.facing_normal(h.triangle as usize, d).is_none() as u32;
        }
    }
    back * 4 >= BURIAL_RAYS * 3
}

/// What [`TexelSet::unbury`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Burial {
    /// Texels whose sample point moved to the visible part of their square.
    pub moved: usize,
    /// Texels with no visible point, dropped from the covered set.
    pub dropped: usize,
}

impl TexelSet {
    /// [`TexelSet::build`], then [`TexelSet::unbury`]: the texel set every estimator uses.
    pub fn build_visible(scene: &Scene, bvh: &Bvh, width: u32, height: u32) -> TexelSet {
        let mut set = TexelSet::build(scene, width, height);
        set.unbury(scene, bvh);
        set
    }

    /// Move buried sample points to the visible part of their texel, and drop texels with none
    /// (module doc). Deterministic: the same geometry gives the same set at any thread count.
    pub fn unbury(&mut self, scene: &Scene, bvh: &Bvh) -> Burial {
        let size = DVec2::new(self.width as f64, self.height as f64);
        let width = self.width;
        // None: keep as it is; Some(Some(t)): moved to t; Some(None): dropped.
        let verdicts: Vec<Option<Option<Texel>>> = self
            .texels
            .par_iter()
            .map(|t| {
                if !is_buried(scene, bvh, t.position, t.normal) {
                    return None;
                }
                let uv = scene.uv1_corners(t.triangle as usize).map(|v| v.as_dvec2() * size);
                let centre = DVec2::new(t.i as f64 + 0.5, t.j as f64 + 0.5);
                let mut grid: Vec<DVec2> = (0..GRID * GRID)
                    .map(|k| {
                        let (a, b) = ((k % GRID) as f64 + 0.5, (k / GRID) as f64 + 0.5);
                        DVec2::new(t.i as f64 + a / GRID as f64, t.j as f64 + b / GRID as f64)
                    })
                    .collect();
                grid.sort_by(|a, b| {
                    (*a - centre).length_squared().total_cmp(&(*b - centre).length_squared())
                });
                let flat = t.j * width + t.i;
                Some(grid.into_iter().find_map(|s| {
                    let c = Candidate {
                        flat,
                        triangle: t.triangle,
                        distance: 0.0,
                        bary: closest_barycentrics(s, &uv),
                    };
                    let moved = make_texel(scene, &c, size, width);
                    (!is_buried(scene, bvh, moved.position, moved.normal)).then_some(moved)
                }))
            })
            .collect();
        let mut burial = Burial::default();
        self.buried_centres.clear();
        if verdicts.iter().all(Option::is_none) {
            return burial;
        }
        let old = std::mem::take(&mut self.texels);
        self.index.fill(Self::EMPTY);
        for (t, v) in old.into_iter().zip(verdicts) {
            if v.is_some() {
                self.buried_centres.push(t.j * width + t.i);
            }
            let kept = match v {
                None => t,
                Some(Some(moved)) => {
                    burial.moved += 1;
                    moved
                }
                Some(None) => {
                    burial.dropped += 1;
                    continue;
                }
            };
            self.index[(kept.j * width + kept.i) as usize] = self.texels.len() as u32;
            self.texels.push(kept);
        }
        self.buried = burial;
        self.dilation = self.dilation_ring();
        self.shared_gutter_texels = self.count_shared_gutters(&crate::uv::charts(scene));
        burial
    }
}

impl TexelSet {
    /// [`TexelSet::covered_areas`] less the part of each texel that lies inside a solid (a
    /// floor texel half under a pillar stands for the visible half only: its value is that
    /// half's light). Texels within one texel of one whose centre [`TexelSet::unbury`] found
    /// buried are tried at a 4 x 4 grid of points over their square (clamped into the owning
    /// triangle, as `unbury` does) and keep the share of their area whose points are not
    /// buried; the rest keep their covered area. On the chamber 17 m^2 of the 1,208 lie under
    /// its plinths and pillars, and counted, its pillars' panes read 3-7 % more power than they
    /// deliver.
    pub fn visible_areas(&self, scene: &Scene, bvh: &Bvh) -> Vec<f32> {
        let mut areas = self.covered_areas(scene);
        let (w, h) = (self.width as i64, self.height as i64);
        let mut near = vec![false; self.texels.len()];
        for &flat in &self.buried_centres {
            let (i, j) = ((flat % self.width) as i64, (flat / self.width) as i64);
            for (x, y) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (i + dx, j + dy))) {
                if (0..w).contains(&x) && (0..h).contains(&y) {
                    let k = self.index[(y * w + x) as usize];
                    if k != Self::EMPTY {
                        near[k as usize] = true;
                    }
                }
            }
        }
        let size = DVec2::new(self.width as f64, self.height as f64);
        let tried: Vec<(usize, f32)> = (0..self.texels.len())
            .into_par_iter()
            .filter(|&k| near[k])
            .map(|k| {
                let t = &self.texels[k];
                let uv = scene.uv1_corners(t.triangle as usize).map(|v| v.as_dvec2() * size);
                let open = (0..GRID * GRID)
                    .filter(|&g| {
                        let (a, b) = ((g % GRID) as f64 + 0.5, (g / GRID) as f64 + 0.5);
                        let s = DVec2::new(t.i as f64 + a / GRID as f64, t.j as f64 + b / GRID as f64);
                        let c = Candidate {
                            flat: t.j * self.width + t.i,
                            triangle: t.triangle,
                            distance: 0.0,
                            bary: closest_barycentrics(s, &uv),
                        };
                        let p = make_texel(scene, &c, size, self.width);
                        !is_buried(scene, bvh, p.position, p.normal)
                    })
                    .count();
                (k, open as f32 / (GRID * GRID) as f32)
            })
            .collect();
        for (k, share) in tried {
            areas[k] *= share;
        }
        areas
    }
}
