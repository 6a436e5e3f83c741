//! Where a texel's walks went: a coarse voxel grid over the level, and the voxels each
//! walk segment passed through.
//!
//! A segment is sampled a little under two voxel sides apart, so every point of it lies within
//! one side of a sample, each coordinate at most a side off, and therefore in a sample's voxel
//! or one of its 26 neighbours. The edit's
//! voxels are grown by one voxel before they are compared ([`VoxelGrid::grow`]), which makes
//! the test conservative: a walk that came within a voxel of an edited triangle counts as
//! touching it. Points outside the grid fall into its border voxels (the grid covers the
//! level as it was baked; geometry an edit moves outside still meets the walks that left
//! through that border).

use glam::Vec3;

/// Voxels of a grid at most (a 32³ grid for a cube-shaped level; flat levels get more in the
/// plan): one bit each per atlas tile, 4 KB a tile.
pub const MAX_VOXELS: usize = 32 * 32 * 32;

/// An axis-aligned grid of cubic voxels.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelGrid {
    pub origin: Vec3,
    /// Side of a voxel, in scene units.
    pub side: f32,
    pub dims: [u32; 3],
}

impl VoxelGrid {
    /// The grid over the box `lo..hi` (widened by 1 % and a millimetre), with at most
    /// [`MAX_VOXELS`] voxels.
    pub fn around(lo: Vec3, hi: Vec3) -> VoxelGrid {
        let pad = (hi - lo).max_element().max(0.0) * 0.01 + 1e-3;
        let (lo, hi) = (lo - Vec3::splat(pad), hi + Vec3::splat(pad));
        let extent = (hi - lo).max(Vec3::splat(1e-3));
        let mut side = (extent.x * extent.y * extent.z / MAX_VOXELS as f32).cbrt();
        let dims = |side: f32| extent.to_array().map(|e| ((e / side).ceil() as u32).max(1));
        // Flat boxes: the ceilings can push the count over; widen until it fits.
        while dims(side).iter().map(|&d| d as usize).product::<usize>() > MAX_VOXELS {
            side *= 1.05;
        }
        VoxelGrid { origin: lo, side, dims: dims(side) }
    }

    pub fn len(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Words of a bitset over the voxels.
    pub fn words(&self) -> usize {
        self.len().div_ceil(64)
    }

    fn cell(&self, p: Vec3) -> [u32; 3] {
        let q = (p - self.origin) / self.side;
        let c = |v: f32, d: u32| if v.is_nan() { 0 } else { (v.max(0.0) as u32).min(d - 1) };
        [c(q.x, self.dims[0]), c(q.y, self.dims[1]), c(q.z, self.dims[2])]
    }

    fn flat(&self, c: [u32; 3]) -> u32 {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    /// The voxel holding `p` (clamped to the grid).
    pub fn voxel(&self, p: Vec3) -> u32 {
        self.flat(self.cell(p))
    }

    /// Calls `mark` with the voxels of samples along `a..b`, at most 1.9 sides apart (module
    /// doc; the 0.1 is room for rounding).
    pub fn segment(&self, a: Vec3, b: Vec3, mut mark: impl FnMut(u32)) {
        let len = (b - a).length();
        if !len.is_finite() {
            mark(self.voxel(a));
            return;
        }
        let n = ((len / (1.9 * self.side)).ceil() as u32).clamp(1, 1 << 16);
        let step = (b - a) / n as f32;
        for i in 0..=n {
            mark(self.voxel(a + step * i as f32));
        }
    }

    /// Where a ray from `o` along unit `d` leaves the grid's box (or `o` if it starts outside).
    pub fn exit(&self, o: Vec3, d: Vec3) -> Vec3 {
        let hi = self.origin + Vec3::from_array(self.dims.map(|n| n as f32)) * self.side;
        let mut t = f32::INFINITY;
        for k in 0..3 {
            if d[k] > 0.0 {
                t = t.min((hi[k] - o[k]) / d[k]);
            } else if d[k] < 0.0 {
                t = t.min((self.origin[k] - o[k]) / d[k]);
            }
        }
        if t.is_finite() && t > 0.0 {
            o + d * t
        } else {
            o
        }
    }

    /// Sets the bits of every voxel the box `lo..hi` overlaps.
    pub fn mark_box(&self, lo: Vec3, hi: Vec3, bits: &mut [u64]) {
        let (a, b) = (self.cell(lo), self.cell(hi));
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    let v = self.flat([x, y, z]) as usize;
                    bits[v / 64] |= 1 << (v % 64);
                }
            }
        }
    }

    /// The set grown by one voxel in every direction (26-neighbourhood).
    pub fn grow(&self, bits: &[u64]) -> Vec<u64> {
        let mut out = vec![0u64; bits.len()];
        let d = self.dims.map(|n| n as i64);
        for v in 0..self.len() {
            if bits[v / 64] >> (v % 64) & 1 == 0 {
                continue;
            }
            let (x, y, z) = (v as i64 % d[0], v as i64 / d[0] % d[1], v as i64 / (d[0] * d[1]));
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (a, b, c) = (x + dx, y + dy, z + dz);
                        if (0..d[0]).contains(&a) && (0..d[1]).contains(&b) && (0..d[2]).contains(&c) {
                            let w = ((c * d[1] + b) * d[0] + a) as usize;
                            out[w / 64] |= 1 << (w % 64);
                        }
                    }
                }
            }
        }
        out
    }
}

/// One texel's voxels as they are marked: a bitset and the list of voxels set, so taking them
/// costs what was marked, not the grid.
pub struct Recorder {
    bits: Vec<u64>,
    set: Vec<u32>,
}

impl Recorder {
    pub fn new(grid: &VoxelGrid) -> Recorder {
        Recorder { bits: vec![0; grid.words()], set: Vec::new() }
    }

    pub fn mark(&mut self, v: u32) {
        let (w, b) = (v as usize / 64, v % 64);
        if self.bits[w] >> b & 1 == 0 {
            self.bits[w] |= 1 << b;
            self.set.push(v);
        }
    }

    /// The voxels marked since the last take, in the order first marked; the recorder is
    /// left empty.
    pub fn take(&mut self) -> Vec<u32> {
        for &v in &self.set {
            self.bits[v as usize / 64] = 0;
        }
        std::mem::take(&mut self.set)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: every point of a segment, finely sampled, lies in a voxel the coarse
    /// samples marked once the marks are grown by one voxel.
    #[test]
    fn grown_segment_marks_cover_the_segment() {
        let grid = VoxelGrid::around(Vec3::ZERO, Vec3::new(4.0, 3.0, 2.5));
        assert!(grid.len() <= MAX_VOXELS && grid.len() > MAX_VOXELS / 2, "{grid:?}");
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..200 {
            let a = Vec3::new(next() * 4.0, next() * 3.0, next() * 2.5);
            let b = Vec3::new(next() * 4.0, next() * 3.0, next() * 2.5);
            let mut bits = vec![0u64; grid.words()];
            grid.segment(a, b, |v| bits[v as usize / 64] |= 1 << (v % 64));
            let grown = grid.grow(&bits);
            for i in 0..=1000 {
                let v = grid.voxel(a.lerp(b, i as f32 / 1000.0)) as usize;
                assert!(grown[v / 64] >> (v % 64) & 1 == 1, "{a} {b} at {i}");
            }
        }
    }

    #[test]
    fn exit_leaves_the_box_and_recorder_lists_each_voxel_once() {
        let grid = VoxelGrid::around(Vec3::ZERO, Vec3::ONE);
        let p = grid.exit(Vec3::splat(0.5), Vec3::X);
        let hi = grid.origin.x + grid.dims[0] as f32 * grid.side;
        assert!((p.x - hi).abs() < 1e-4 && (p.y - 0.5).abs() < 1e-6, "{p}");
        let mut r = Recorder::new(&grid);
        for v in [5, 3, 5, 9, 3] {
            r.mark(v);
        }
        assert_eq!(r.take(), vec![5, 3, 9]);
        assert!(r.take().is_empty());
    }
}
