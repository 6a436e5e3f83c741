//! A moving object's coherent shadow map as an occluder (paper 003 §3.3, after CSM, its reference 17):
//! orthographic depth maps of the object from many directions, for testing whether a segment
//! between two points *outside* the object passes through it.
//!
//! Directions are the pixel centres of a `dirs` x `dirs` cube map ([`super::cube`]). The map of
//! direction `d` covers the object's bounding sphere (centre `c`, radius `r`) with `res` x `res`
//! pixels on the plane through `c` normal to `d` (axes from `d.any_orthonormal_pair()`); a
//! pixel stores where a ray along `d` through its centre enters the object and where one along
//! `-d` enters it from the other side, both as 8-bit codes of the depth along `d` in `[-r, r]`
//! (entry 255: the pixel misses the object). A segment is tested in the map of the direction
//! nearest its own, where it crosses the object's middle (found from its point nearest `c`): blocked where its depth span overlaps
//! `[entry, exit]` (bilinear over the four pixels). Stored uncompressed: an object is small.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::cube;

/// Occluder maps of one object, in its rest frame (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Csm {
    /// Directions cube map resolution.
    pub dirs: u32,
    /// Pixels per side of each orthographic map.
    pub res: u32,
    pub centre: Vec3,
    pub radius: f32,
    /// Per direction, per pixel (row-major): (entry, exit) depth codes.
    pub depths: Vec<[u8; 2]>,
}

/// Entry code of a pixel that misses the object.
pub const MISS: u8 = u8::MAX;

impl Csm {
    /// The plane axes of direction `d`'s map.
    pub fn axes(d: Vec3) -> (Vec3, Vec3) {
        d.any_orthonormal_pair()
    }

    /// The world offset, within a map's plane, of pixel (x, y)'s centre.
    pub fn pixel_offset(&self, d: Vec3, x: u32, y: u32) -> Vec3 {
        let (e1, e2) = Self::axes(d);
        let to = |k: u32| (2.0 * (k as f32 + 0.5) / self.res as f32 - 1.0) * self.radius;
        e1 * to(x) + e2 * to(y)
    }

    /// The 8-bit code of depth `t` along a direction, `t` in `[-radius, radius]` (rounded down
    /// for an entry, up for an exit, so the stored span never shrinks).
    pub fn code(&self, t: f32, up: bool) -> u8 {
        let s = ((t / self.radius + 1.0) * 0.5 * 254.0).clamp(0.0, 254.0);
        (if up { s.ceil() } else { s.floor() }) as u8
    }

    fn depth(&self, code: u8) -> f32 {
        (code as f32 / 254.0 * 2.0 - 1.0) * self.radius
    }

    /// Fraction in [0, 1] of the segment `a` -> `b` (object rest frame) that the object blocks.
    pub fn blocks(&self, a: Vec3, b: Vec3) -> f32 {
        let ab = b - a;
        let len = ab.length();
        if !(len > 0.0) {
            return 0.0;
        }
        let u = ab / len;
        // Quick rejection: the segment misses the bounding sphere.
        let s = a + u * (self.centre - a).dot(u).clamp(0.0, len);
        if (s - self.centre).length_squared() > self.radius * self.radius {
            return 0.0;
        }
        let Some(k) = cube::pixel_of(u, self.dirs) else { return 0.0 };
        let d = cube::pixel_direction(k, self.dirs);
        let (e1, e2) = Self::axes(d);
        let r = self.res as usize;
        let base = k * r * r;
        let to = |t: f32| {
            ((t / self.radius + 1.0) * 0.5 * self.res as f32 - 0.5).clamp(0.0, self.res as f32 - 1.0)
        };
        let (ta, tb) = ((a - self.centre).dot(d), (b - self.centre).dot(d));
        let (lo, hi) = (ta.min(tb), ta.max(tb));
        // The map's lines run along d, the segment along u: read the map where the segment
        // crosses the object's middle (between entry and exit) at the pixel it passes, found
        // from its point nearest the centre in two steps. Exact for a thin slab.
        let mut p = s;
        if (tb - ta).abs() > 1e-6 * len {
            for _ in 0..2 {
                let rel = p - self.centre;
                // floor(t + 0.5), not round(): WGSL rounds halves to even, Rust away from zero.
                let (x, y) =
                    ((to(rel.dot(e1)) + 0.5).floor() as usize, (to(rel.dot(e2)) + 0.5).floor() as usize);
                let [entry, exit] = self.depths[base + y * r + x];
                if entry == MISS {
                    break;
                }
                let mid = 0.5 * (self.depth(entry) + self.depth(exit));
                let f = ((mid - ta) / (tb - ta)).clamp(0.0, 1.0);
                p = a + ab * f;
            }
        }
        let rel = p - self.centre;
        let (fx, fy) = (to(rel.dot(e1)), to(rel.dot(e2)));
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(r - 1), (y0 + 1).min(r - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        [
            (x0, y0, (1.0 - tx) * (1.0 - ty)),
            (x1, y0, tx * (1.0 - ty)),
            (x0, y1, (1.0 - tx) * ty),
            (x1, y1, tx * ty),
        ]
        .iter()
        .filter(|&&(x, y, w)| {
            let [entry, exit] = self.depths[base + y * r + x];
            w > 0.0 && entry != MISS && hi >= self.depth(entry) && lo <= self.depth(exit)
        })
        .map(|&(_, _, w)| w)
        .sum()
    }

    pub fn bytes(&self) -> usize {
        self.depths.len() * 2
    }

    pub fn check(&self) -> Result<(), String> {
        let expect = 6 * (self.dirs as usize).pow(2) * (self.res as usize).pow(2);
        if self.dirs == 0 || self.res == 0 || self.dirs > 64 || self.res > 256 {
            return Err(format!("occluder map sizes {} / {} out of range", self.dirs, self.res));
        }
        if self.depths.len() != expect
            || !(self.radius > 0.0 && self.radius.is_finite())
            || !self.centre.is_finite()
        {
            return Err("occluder maps of the wrong size or with a bad bounding sphere".into());
        }
        Ok(())
    }
}
