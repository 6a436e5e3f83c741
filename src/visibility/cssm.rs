//! One object's coherent surface shadow map (paper 003 §3.2): a depth cube map at every texel
//! of the object, in a coherent sequence, compressed along the sequence.
//!
//! Pixel `p` of cube map `k` (module [`super::cube`]) records the interval `[z1, z2)` between the
//! first and second surface its ray meets, as linear distance (Euclidean, metres) from the cube
//! map's origin: any depth in it answers every query about real surfaces, since a point at
//! distance <= z1 is seen and one at >= z2 is behind the first surface (the dual depth layers of
//! paper 003, reference 25). Pixels facing into the object (below the texel's tangent plane) are "don't
//! care", `[0, inf)`. Along the sequence, each pixel keeps one value while the intervals still
//! intersect (greedy: the fewest runs), so a pixel is stored as runs `(first cube map, depth)`.
//!
//! Depths are 16-bit codes, linear in `[0, far]` (`far`: the object's diameter, §3.2.1);
//! [`NOTHING`] means nothing lies behind the first surface along that pixel in the whole run,
//! so every query there is visible.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::cube;

/// A lookup counts as at an edge (`Visibility::between` asks the other end too) when its
/// filtered value is more than this from both 0 and 1: the bilinear weights of a lookup whose
/// taps all pass sum to 1 only within rounding.
pub const EDGE: f32 = 1e-3;

/// Relative depth slack of a query: 16-bit depth codes and the offset of cube map origins off
/// their surface are far below it.
pub const SLACK: f32 = 0.005;

/// Relative depth kept behind a first surface with nothing behind it (see `codes`).
pub const BEHIND: f32 = 0.2;

/// The interval of a "don't care" pixel: any depth will do.
pub const DONT_CARE: (f32, f32) = (f32::NEG_INFINITY, f32::INFINITY);

/// Depth code meaning "no second surface": every point along the pixel is visible.
pub const NOTHING: u16 = u16::MAX;
const STEPS: f32 = (u16::MAX - 1) as f32;

/// A compressed CSSM of one object (module doc). Origins are in the object's rest frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cssm {
    /// Pixels per cube face side.
    pub res: u32,
    /// Distance of depth code `u16::MAX - 1`, metres.
    pub far: f32,
    /// Cube map origins in sequence order (the texel's point lifted off its surface).
    pub origins: Vec<Vec3>,
    /// Pixel `p`'s runs are `run_start[offsets[p]..offsets[p + 1]]` (same for `run_depth`).
    pub offsets: Vec<u32>,
    /// First cube map (sequence index) of each run, increasing within a pixel, the first 0.
    pub run_start: Vec<u32>,
    /// Depth code of each run.
    pub run_depth: Vec<u16>,
}

/// Streams cube maps in sequence order into a [`Cssm`] (the greedy run compression).
pub struct CssmBuilder {
    res: u32,
    far: f32,
    origins: Vec<Vec3>,
    /// Per pixel: (first cube map of the open run, feasible low code, feasible high code).
    open: Vec<(u32, u16, u16)>,
    runs: Vec<Vec<(u32, u16)>>,
}

impl CssmBuilder {
    pub fn new(res: u32, far: f32) -> CssmBuilder {
        let pixels = 6 * (res * res) as usize;
        CssmBuilder {
            res,
            far,
            origins: Vec::new(),
            open: vec![(0, 0, NOTHING); pixels],
            runs: vec![Vec::new(); pixels],
        }
    }

    /// The interval `[lo, hi]` of codes whose depth lies in `[z1, z2)` (module doc); a first
    /// hit without room before the second keeps the first.
    fn codes(&self, z1: f32, z2: f32) -> (u16, u16) {
        if z1 == f32::NEG_INFINITY {
            return (0, NOTHING);
        }
        let up = |z: f32| {
            if z.is_finite() {
                (z / self.far * STEPS).ceil().clamp(0.0, STEPS) as u16
            } else {
                NOTHING
            }
        };
        let lo = up(z1);
        // Nothing behind the first surface along the pixel's own rays: outside a closed level.
        // A neighbouring direction's query may still land there (a wall's plane continued past
        // a corner), so the depth stays near the surface instead of "see everything".
        let z2 = if z1.is_finite() && !z2.is_finite() { z1 * (1.0 + BEHIND) } else { z2 };
        let hi = if z2.is_finite() { up(z2).saturating_sub(1).min(u16::MAX - 1) } else { NOTHING };
        (lo, hi.max(lo))
    }

    /// Append the next cube map: its origin and, per pixel, `(z1, z2)` (`f32::INFINITY` where
    /// there is no such hit; [`DONT_CARE`] for a pixel below the surface).
    pub fn push(&mut self, origin: Vec3, intervals: &[(f32, f32)]) {
        debug_assert_eq!(intervals.len(), self.open.len());
        let k = self.origins.len() as u32;
        self.origins.push(origin);
        for (p, &(z1, z2)) in intervals.iter().enumerate() {
            let (lo, hi) = self.codes(z1, z2);
            let (start, olo, ohi) = self.open[p];
            let (nlo, nhi) = (olo.max(lo), ohi.min(hi));
            if k == 0 || nlo <= nhi {
                self.open[p] = if k == 0 { (0, lo, hi) } else { (start, nlo, nhi) };
            } else {
                self.runs[p].push((start, pick(olo, ohi)));
                self.open[p] = (k, lo, hi);
            }
        }
    }

    pub fn finish(mut self) -> Cssm {
        let mut offsets = Vec::with_capacity(self.runs.len() + 1);
        let (mut run_start, mut run_depth) = (Vec::new(), Vec::new());
        offsets.push(0);
        for (p, runs) in self.runs.iter_mut().enumerate() {
            if !self.origins.is_empty() {
                let (start, lo, hi) = self.open[p];
                runs.push((start, pick(lo, hi)));
            }
            for &(s, d) in runs.iter() {
                run_start.push(s);
                run_depth.push(d);
            }
            offsets.push(run_start.len() as u32);
        }
        Cssm { res: self.res, far: self.far, origins: self.origins, offsets, run_start, run_depth }
    }
}

/// The value a run stores: nothing behind at all, or the middle of the feasible codes.
fn pick(lo: u16, hi: u16) -> u16 {
    if hi == NOTHING {
        NOTHING
    } else {
        ((lo as u32 + hi as u32) / 2) as u16
    }
}

impl Cssm {
    /// Cube maps in the sequence.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    /// Stored runs in all.
    pub fn runs(&self) -> usize {
        self.run_start.len()
    }

    /// Bytes the runs and offsets take (what a GPU upload would).
    pub fn bytes(&self) -> usize {
        self.run_start.len() * 6 + self.offsets.len() * 4 + self.origins.len() * 12
    }

    /// The stored depth (metres; infinite for [`NOTHING`]) of pixel `p` in cube map `k`.
    pub fn depth(&self, k: u32, p: usize) -> f32 {
        let (a, b) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
        let runs = &self.run_start[a..b];
        let i = runs.partition_point(|&s| s <= k).saturating_sub(1);
        match self.run_depth[a + i] {
            NOTHING => f32::INFINITY,
            c => c as f32 / STEPS * self.far,
        }
    }

    /// Fraction in [0, 1] of cube map `k` that sees point `q` (rest frame), with bilinear
    /// percentage-closer filtering over the four pixels around `q`'s direction (§3.2.2). A point
    /// is seen by a pixel when its distance, less a slack of [`SLACK`] of it, is within the
    /// stored depth (which holds for the pixel's whole filter support: the builder's job).
    pub fn visible(&self, k: u32, q: Vec3) -> f32 {
        let d = q - self.origins[k as usize];
        let dist = d.length();
        let Some(taps) = cube::bilinear(d, self.res) else { return 1.0 };
        let slack = dist * SLACK;
        taps.iter().filter(|(p, w)| *w > 0.0 && dist - slack <= self.depth(k, *p)).map(|(_, w)| w).sum()
    }

    /// Whether the structure is consistent (a file's contents are checked with it).
    pub fn check(&self) -> Result<(), String> {
        let pixels = 6 * (self.res as usize).pow(2);
        if self.res == 0 || self.res > 256 || !(self.far > 0.0 && self.far.is_finite()) {
            return Err(format!("resolution {} or depth range {} out of range", self.res, self.far));
        }
        if self.offsets.len() != pixels + 1 || self.run_start.len() != self.run_depth.len() {
            return Err("run tables of the wrong size".into());
        }
        if self.offsets[0] != 0 || *self.offsets.last().unwrap_or(&0) as usize != self.run_start.len() {
            return Err("run offsets do not cover the runs".into());
        }
        if self.origins.is_empty() {
            // An object without texels (a small movable at a coarse atlas): no runs at all.
            return if self.run_start.is_empty() { Ok(()) } else { Err("runs without cube maps".into()) };
        }
        for p in 0..pixels {
            let (a, b) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
            if a >= b || b > self.run_start.len() || self.run_start[a] != 0 {
                return Err(format!("pixel {p}: no run from the first cube map"));
            }
            if self.run_start[a..b].windows(2).any(|w| w[0] >= w[1])
                || self.run_start[b - 1] as usize >= self.origins.len()
            {
                return Err(format!("pixel {p}: runs out of order or past the last cube map"));
            }
        }
        if self.origins.iter().any(|o| !o.is_finite()) {
            return Err("a cube map origin is not finite".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run stays open while the intervals intersect, and every stored value lies in every
    /// interval of its run (within one code).
    #[test]
    fn runs_hold_a_value_inside_every_interval() {
        let mut b = CssmBuilder::new(1, 10.0);
        let seq = [(1.0, 3.0), (2.0, 4.0), (2.5, f32::INFINITY), (5.0, 6.0), DONT_CARE, (7.0, 9.0)];
        for &(z1, z2) in &seq {
            b.push(Vec3::ZERO, &[(z1, z2); 6]);
        }
        let c = b.finish();
        c.check().unwrap();
        // [1, 3) ∩ [2, 4) ∩ [2.5, 3) (nothing behind: BEHIND), then [5, 6) and don't care, then [7, 9).
        assert_eq!(c.run_start[..3], [0, 3, 5]);
        assert_eq!(c.runs(), 6 * 3);
        for (k, &(z1, z2)) in seq.iter().enumerate() {
            let v = c.depth(k as u32, 0);
            let cap = if z2.is_finite() { z2 } else { z1 * (1.0 + BEHIND) };
            assert!(v >= z1 - 1e-3 && v < cap || z1 < 0.0, "cube map {k}: {v} not in [{z1}, {z2})");
        }
    }

    /// A point seen through an empty cube is visible; one behind a wall is not.
    #[test]
    fn a_wall_hides_what_is_behind_it() {
        let mut b = CssmBuilder::new(4, 10.0);
        let pixels: Vec<(f32, f32)> = (0..96)
            .map(|p| {
                let d = cube::pixel_direction(p, 4);
                if d.x > 0.3 {
                    // A wall x = 1, 10 cm thick.
                    (1.0 / d.x, 1.1 / d.x)
                } else {
                    (f32::INFINITY, f32::INFINITY)
                }
            })
            .collect();
        b.push(Vec3::ZERO, &pixels);
        let c = b.finish();
        assert_eq!(c.visible(0, Vec3::new(1.0, 0.1, 0.0)), 1.0);
        assert_eq!(c.visible(0, Vec3::new(3.0, 0.2, 0.1)), 0.0);
        assert_eq!(c.visible(0, Vec3::new(-3.0, 0.2, 0.1)), 1.0);
    }
}
