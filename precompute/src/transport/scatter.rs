//! Paper 004's scatter estimator: every vertex of every entry's walks is a virtual point light
//! evaluated at every texel, its 1/r² spike bounded by the clamp (module doc of [`super`]).

use std::sync::atomic::Ordering;

use glam::Vec3;
use prm::sampling::{cosine_direction, stream};
use prm::Texel;
use rand::Rng;
use rayon::prelude::*;

use super::{bounce, Scratch, TexelPanes, Transport};

impl Transport<'_> {
    /// Virtual point lights of every entry's walks, for unit entry irradiance: (position,
    /// normal, flux, the entry whose walk it is on).
    pub fn vpls(&self) -> Vec<(Vec3, Vec3, Vec3, u32)> {
        let m = self.paths.max(1);
        let per_entry: Vec<Vec<(Vec3, Vec3, Vec3, u32)>> = self
            .entries
            .par_iter()
            .enumerate()
            .map(|(j, e)| {
                let c = j as u32;
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

    pub(super) fn scatter_texel(
        &self,
        scratch: &mut Scratch,
        t: &Texel,
        vpls: &[(Vec3, Vec3, Vec3, u32)],
        rc2: f32,
    ) -> TexelPanes {
        for &(z, nz, phi, j) in vpls {
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
            let c = self.assignment[j as usize];
            scratch.accumulate(c, phi * (cz * cx / (std::f32::consts::PI * r2.max(rc2))));
        }
        scratch.take(1.0)
    }
}
