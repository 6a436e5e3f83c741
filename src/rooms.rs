//! Rooms: the connected parts of a level's free space (issue 13).
//!
//! k-means over entries (position and normal) knows nothing of walls: on 16 closed chambers a
//! metre apart, the floors' and ceilings' edges of two neighbours lie in one plane a metre
//! apart, and 98 of 4,096 clusters took entries from both. Such a cluster's pane is the
//! response to light spread over both rooms, so it lights the dark neighbour through the wall
//! (only the near field's deviation takes it back, and only near the cluster). Rooms let the
//! clustering keep to one side of a wall.
//!
//! The level's surfaces are marked in a voxel grid (every voxel a surface passes through or
//! comes within a quarter voxel of, from points sampled at most half a voxel apart), and the
//! free voxels are labelled by 6-connected flood fill: a room is one component. A door wider
//! than about two voxels joins the rooms on its two sides; a narrower one (or a level whose
//! voxels had to grow past its doors) keeps them apart, and then no light crosses it through
//! the far field, the cells or a cluster. The grid has at most [`MAX_VOXELS`] voxels, cubes of
//! at least [`MIN_METRES`] (glTF units are metres; on a level under 6.4 m across, at least
//! [`MAX_SIDE`] of its diagonal instead: 1.5 cm on the Cornell box) and [`MIN_SIDE`] of the
//! level's diagonal: 0.1 m on the chamber, 0.2 m on
//! 16 chambers, so openings under about 0.4 m may part rooms there; a level of 100 chambers
//! gets about 0.45 m. A point on a surface belongs to the room of the first free voxel along its
//! normal.

use glam::Vec3;

/// Most voxels a grid has (the side grows for a larger level).
pub const MAX_VOXELS: f64 = 4.0e6;

/// Smallest voxel side in metres: finer buys nothing for rooms and costs time on small levels.
pub const MIN_METRES: f32 = 0.1;

/// Smallest voxel side, as a share of the level's diagonal.
pub const MIN_SIDE: f32 = 1.0 / 1024.0;

/// Largest share of the level's diagonal that [`MIN_METRES`] may make a voxel: a small level
/// keeps its gaps open. The Cornell box (0.95 m across) at 0.1 m voxels was two rooms, the
/// 10 cm between its tall block and the walls shut off, and the PRM's cells, far field and
/// clusters kept to them (own lights 5.5 % against 1.9 % before rooms).
pub const MAX_SIDE: f32 = 1.0 / 64.0;

/// Label of a voxel a surface passes through.
const SOLID: u32 = u32::MAX;

/// The rooms of a level: a label per voxel.
pub struct Rooms {
    lo: Vec3,
    side: f32,
    dims: [usize; 3],
    label: Vec<u32>,
    /// The labels again, one byte each (0 solid, else the room + 1), when there are under
    /// 255 rooms: [`Rooms::rooms_on_segment`] looks up three voxels of every walk segment a
    /// precompute records for updates, scattered over the grid, and a quarter of the bytes
    /// stay in cache better (a chamber's `--cache` walks 4.96 -> 4.63 s, medians of 7).
    bytes: Option<Vec<u8>>,
    count: u32,
}

impl Rooms {
    /// The rooms of the level made of `triangles` (corner positions).
    pub fn new(triangles: &[[Vec3; 3]]) -> Rooms {
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for t in triangles {
            for &p in t {
                if p.is_finite() {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
        }
        if !(lo.cmple(hi).all()) {
            return Rooms {
                lo: Vec3::ZERO,
                side: 1.0,
                dims: [1, 1, 1],
                label: vec![0],
                bytes: None,
                count: 1,
            };
        }
        let extent = (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
        let diagonal = extent.length().max(f32::MIN_POSITIVE);
        // Side so that the grid (with a free voxel all round) holds at most MAX_VOXELS.
        let volume = (extent + Vec3::splat(2.0 * MIN_SIDE * diagonal)).as_dvec3();
        let side = ((volume.x * volume.y * volume.z / MAX_VOXELS).cbrt() as f32)
            .max(MIN_SIDE * diagonal)
            .max(MIN_METRES.min(MAX_SIDE * diagonal));
        let lo = lo - Vec3::splat(side);
        let dims = ((extent + Vec3::splat(2.0 * side)) / side).ceil().as_uvec3().max(glam::UVec3::ONE);
        let dims = [dims.x as usize + 1, dims.y as usize + 1, dims.z as usize + 1];
        let label = vec![0; dims[0] * dims[1] * dims[2]];
        let mut rooms = Rooms { lo, side, dims, label, bytes: None, count: 0 };
        for t in triangles {
            rooms.mark(t);
        }
        rooms.flood();
        if rooms.count < u32::from(u8::MAX) {
            rooms.bytes =
                Some(rooms.label.iter().map(|&l| if l == SOLID { 0 } else { l as u8 + 1 }).collect());
        }
        rooms
    }

    /// The rooms of `scene`'s triangles.
    pub fn of_scene(scene: &crate::scene::Scene) -> Rooms {
        let corners: Vec<[Vec3; 3]> = (0..scene.triangles.len()).map(|t| scene.corners(t)).collect();
        Rooms::new(&corners)
    }

    /// The voxels' side (scene units).
    pub fn voxel_side(&self) -> f32 {
        self.side
    }

    /// How many rooms (free components, the outside included).
    pub fn count(&self) -> u32 {
        self.count
    }

    /// The room of a point on a surface with normal `n`: the first free voxel along `n` within
    /// four voxels (None: none there, or a point outside the grid).
    pub fn room_of(&self, p: Vec3, n: Vec3) -> Option<u32> {
        let n = n.normalize_or_zero();
        (1..=8).find_map(|k| self.free_at(p + n * (k as f32 * 0.5 * self.side)))
    }

    /// The room in front of a triangle (`corners`), seen along `n`: its centroid's, else one
    /// near a corner (a strip along a wall has its centroid in the wall's voxels and its far
    /// corners in the room); None if every one lies in surfaces' voxels.
    pub fn room_of_triangle(&self, corners: [Vec3; 3], n: Vec3) -> Option<u32> {
        let centroid = corners.iter().sum::<Vec3>() / 3.0;
        let points = std::iter::once(centroid).chain(corners.map(|c| c.lerp(centroid, 0.1)));
        points.filter_map(|p| self.room_of(p, n)).next()
    }

    /// Calls `found` with the room of each free voxel among a few points of the segment
    /// `a..b` (half a voxel in from each end, and its middle). A segment of a ray between two
    /// surfaces lies in free space, and a free voxel has no surface within a quarter voxel, so
    /// the room of such a point is the room of the whole segment: unlike a point on a surface
    /// seen along its normal ([`Rooms::room_of`]), nothing can lie between them.
    pub fn rooms_on_segment(&self, a: Vec3, b: Vec3, mut found: impl FnMut(u32)) {
        self.segment_voxels(a, b, |v| {
            if let Some(r) = self.room_of_voxel(v) {
                found(r);
            }
        });
    }

    /// The voxels of the points [`Rooms::rooms_on_segment`] looks at on `a..b` (those inside
    /// the grid), each fetched towards the cache as it is named. A caller that looks them up
    /// later ([`Rooms::room_of_voxel`]), after other work, does not wait for memory: the
    /// lookup of a point scattered over a grid of a few MB missed the cache nearly every time
    /// (three quarters of `rooms_on_segment`'s time in a chamber's `--cache` walks).
    pub fn segment_voxels(&self, a: Vec3, b: Vec3, mut voxel: impl FnMut(u32)) {
        let len = a.distance(b);
        if !len.is_finite() {
            return;
        }
        let f = (0.5 * self.side / len.max(f32::MIN_POSITIVE)).min(0.5);
        // A segment under a voxel long has its three points at its middle.
        let points: &[f32] = if f < 0.5 { &[f, 0.5, 1.0 - f] } else { &[0.5] };
        for &t in points {
            if let Some(v) = self.voxel(a.lerp(b, t)) {
                match &self.bytes {
                    Some(bytes) => crate::prefetch::prefetch(bytes, v),
                    None => crate::prefetch::prefetch(&self.label, v),
                }
                voxel(v as u32);
            }
        }
    }

    /// The room of voxel `v` (as [`Rooms::segment_voxels`] names it); None where it is solid
    /// or outside the grid.
    pub fn room_of_voxel(&self, v: u32) -> Option<u32> {
        let v = v as usize;
        match &self.bytes {
            Some(bytes) => bytes.get(v)?.checked_sub(1).map(u32::from),
            None => self.label.get(v).copied().filter(|&l| l != SOLID),
        }
    }

    /// The rooms whose free voxels overlap the box `lo..hi` grown by `grow` voxels on every
    /// side (clamped to the grid; a box outside it meets the border voxels), sorted. What an
    /// update asks of an edited region: which rooms' walks can have passed through it.
    pub fn rooms_in_box(&self, lo: Vec3, hi: Vec3, grow: usize) -> Vec<u32> {
        if !(lo.is_finite() && hi.is_finite()) {
            return (0..self.count).collect();
        }
        let cell = |p: Vec3, k: usize| {
            let q = ((p[k] - self.lo[k]) / self.side).floor();
            (q.max(0.0) as usize).min(self.dims[k] - 1)
        };
        let a: [usize; 3] = std::array::from_fn(|k| cell(lo, k).saturating_sub(grow));
        let b: [usize; 3] = std::array::from_fn(|k| (cell(hi, k) + grow).min(self.dims[k] - 1));
        let mut found = std::collections::BTreeSet::new();
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                let row = (z * self.dims[1] + y) * self.dims[0];
                for &l in &self.label[row + a[0]..=row + b[0]] {
                    if l != SOLID {
                        found.insert(l);
                    }
                }
            }
        }
        found.into_iter().collect()
    }

    /// Per room, the box its free voxels fill (scene space), grown by two voxels on every
    /// side: the surfaces that bound a room lie within about a voxel and a quarter of its free
    /// voxels. The outside (a room touching the grid's border) spans the whole grid.
    pub fn boxes(&self) -> Vec<(Vec3, Vec3)> {
        let grow = 2.0;
        let mut lo = vec![[usize::MAX; 3]; self.count as usize];
        let mut hi = vec![[0usize; 3]; self.count as usize];
        let [nx, ny, _] = self.dims;
        for (v, &l) in self.label.iter().enumerate() {
            if l == SOLID {
                continue;
            }
            let c = [v % nx, (v / nx) % ny, v / (nx * ny)];
            let (a, b) = (&mut lo[l as usize], &mut hi[l as usize]);
            for k in 0..3 {
                a[k] = a[k].min(c[k]);
                b[k] = b[k].max(c[k]);
            }
        }
        let corner = |c: [usize; 3], plus: f32| {
            self.lo + (Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) + Vec3::splat(plus)) * self.side
        };
        lo.iter().zip(&hi).map(|(&a, &b)| (corner(a, -grow), corner(b, 1.0 + grow))).collect()
    }

    /// Per room of this level, the rooms of `other` (the same level after an edit) in which
    /// its free voxels' centres lie, sorted; empty where none does. Room labels are given in
    /// voxel order, so an edit can renumber rooms it did not touch: this maps the labels of
    /// one to the other's.
    pub fn rooms_in(&self, other: &Rooms) -> Vec<Vec<u32>> {
        let mut sets = vec![std::collections::BTreeSet::new(); self.count as usize];
        let [nx, ny, _] = self.dims;
        let mut last = (SOLID, SOLID);
        for (v, &l) in self.label.iter().enumerate() {
            if l == SOLID {
                continue;
            }
            let c = Vec3::new((v % nx) as f32, ((v / nx) % ny) as f32, (v / (nx * ny)) as f32);
            if let Some(m) = other.free_at(self.lo + (c + 0.5) * self.side) {
                // Neighbouring voxels mostly repeat the last pair.
                if (l, m) != last {
                    sets[l as usize].insert(m);
                    last = (l, m);
                }
            }
        }
        sets.into_iter().map(|s| s.into_iter().collect()).collect()
    }

    fn free_at(&self, p: Vec3) -> Option<u32> {
        let v = self.voxel(p)?;
        let l = self.label[v];
        (l != SOLID).then_some(l)
    }

    fn voxel(&self, p: Vec3) -> Option<usize> {
        let q = (p - self.lo) / self.side;
        if !q.is_finite() || q.min_element() < 0.0 {
            return None;
        }
        let [x, y, z] = [q.x as usize, q.y as usize, q.z as usize];
        (x < self.dims[0] && y < self.dims[1] && z < self.dims[2])
            .then(|| (z * self.dims[1] + y) * self.dims[0] + x)
    }

    /// Mark the voxels the triangle passes through or comes within a quarter voxel of.
    fn mark(&mut self, t: &[Vec3; 3]) {
        if !t.iter().all(|p| p.is_finite()) {
            return;
        }
        let longest = (t[1] - t[0]).length().max((t[2] - t[1]).length()).max((t[0] - t[2]).length());
        let steps = ((2.0 * longest / self.side).ceil() as usize).clamp(1, 1 << 14);
        let reach = 0.25 * self.side;
        for i in 0..=steps {
            for j in 0..=steps - i {
                let (a, b) = (i as f32 / steps as f32, j as f32 / steps as f32);
                let p = t[0] + (t[1] - t[0]) * a + (t[2] - t[0]) * b;
                for corner in 0..8 {
                    let d = Vec3::new(
                        if corner & 1 == 0 { -reach } else { reach },
                        if corner & 2 == 0 { -reach } else { reach },
                        if corner & 4 == 0 { -reach } else { reach },
                    );
                    if let Some(v) = self.voxel(p + d) {
                        self.label[v] = SOLID;
                    }
                }
            }
        }
    }

    /// Label the free voxels by 6-connected component, in voxel order.
    fn flood(&mut self) {
        const UNSEEN: u32 = 0;
        // Labels start at 1 while flooding (0 is unseen), then shift down.
        let [nx, ny, nz] = self.dims;
        let mut next = 1u32;
        let mut stack = Vec::new();
        for start in 0..self.label.len() {
            if self.label[start] != UNSEEN {
                continue;
            }
            self.label[start] = next;
            stack.push(start);
            while let Some(v) = stack.pop() {
                let (x, y, z) = (v % nx, (v / nx) % ny, v / (nx * ny));
                let mut visit = |w: usize, label: &mut Vec<u32>| {
                    if label[w] == UNSEEN {
                        label[w] = next;
                        stack.push(w);
                    }
                };
                if x > 0 {
                    visit(v - 1, &mut self.label);
                }
                if x + 1 < nx {
                    visit(v + 1, &mut self.label);
                }
                if y > 0 {
                    visit(v - nx, &mut self.label);
                }
                if y + 1 < ny {
                    visit(v + nx, &mut self.label);
                }
                if z > 0 {
                    visit(v - nx * ny, &mut self.label);
                }
                if z + 1 < nz {
                    visit(v + nx * ny, &mut self.label);
                }
            }
            next += 1;
        }
        for l in &mut self.label {
            if *l != SOLID {
                *l -= 1;
            }
        }
        self.count = next - 1;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The six faces of a box as triangles fronting its inside, with a square hole of side
    /// `door` (0: none) in the middle of its +x wall.
    pub(crate) fn closed_box(lo: Vec3, hi: Vec3, door: f32) -> Vec<[Vec3; 3]> {
        let mut out = Vec::new();
        // The corners below go round each face counter-clockwise seen from outside: wound the
        // other way, so that every face fronts the inside.
        let mut quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| {
            out.push([a, c, b]);
            out.push([a, d, c]);
        };
        let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let (l, h) = (lo, hi);
        quad(v(l.x, l.y, l.z), v(h.x, l.y, l.z), v(h.x, l.y, h.z), v(l.x, l.y, h.z));
        quad(v(l.x, h.y, l.z), v(l.x, h.y, h.z), v(h.x, h.y, h.z), v(h.x, h.y, l.z));
        quad(v(l.x, l.y, l.z), v(l.x, l.y, h.z), v(l.x, h.y, h.z), v(l.x, h.y, l.z));
        quad(v(l.x, l.y, l.z), v(l.x, h.y, l.z), v(h.x, h.y, l.z), v(h.x, l.y, l.z));
        quad(v(l.x, l.y, h.z), v(h.x, l.y, h.z), v(h.x, h.y, h.z), v(l.x, h.y, h.z));
        // The +x wall, around a door (a hole from the floor up).
        let (zm, d) = (0.5 * (l.z + h.z), 0.5 * door);
        let top = l.y + door.min(h.y - l.y);
        if door > 0.0 {
            quad(v(h.x, l.y, l.z), v(h.x, h.y, l.z), v(h.x, h.y, zm - d), v(h.x, l.y, zm - d));
            quad(v(h.x, l.y, zm + d), v(h.x, h.y, zm + d), v(h.x, h.y, h.z), v(h.x, l.y, h.z));
            quad(v(h.x, top, zm - d), v(h.x, h.y, zm - d), v(h.x, h.y, zm + d), v(h.x, top, zm + d));
        } else {
            quad(v(h.x, l.y, l.z), v(h.x, h.y, l.z), v(h.x, h.y, h.z), v(h.x, l.y, h.z));
        }
        out
    }

    /// A 15 cm strip of floor along a wall has its centroid in the wall's voxels (no room), and
    /// its corner away from the wall in the room.
    #[test]
    fn a_strip_along_a_wall_finds_its_room_by_a_corner() {
        let a = closed_box(Vec3::ZERO, Vec3::new(6.0, 3.0, 8.0), 0.0);
        let rooms = Rooms::new(&a);
        let inside = rooms.room_of(Vec3::new(3.0, 0.0, 4.0), Vec3::Y);
        assert!(inside.is_some());
        let strip = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, 7.0), Vec3::new(0.15, 0.0, 7.0)];
        let centroid = strip.iter().sum::<Vec3>() / 3.0;
        assert_eq!(rooms.room_of(centroid, Vec3::Y), None, "the centroid's column is the wall's");
        assert_eq!(rooms.room_of_triangle(strip, Vec3::Y), inside);
    }

    /// Two closed boxes a metre apart are two rooms (and the outside a third); the same boxes
    /// joined by a 1.5 m door through a corridor are one. A point on a floor is in its box's
    /// room; on the outside of a wall, in the outside's.
    #[test]
    fn walls_part_rooms_and_doors_join_them() {
        let a = closed_box(Vec3::ZERO, Vec3::new(6.0, 3.0, 8.0), 0.0);
        let b = closed_box(Vec3::new(7.0, 0.0, 0.0), Vec3::new(13.0, 3.0, 8.0), 0.0);
        let rooms = Rooms::new(&[a.clone(), b.clone()].concat());
        let up = Vec3::Y;
        let (ra, rb) =
            (rooms.room_of(Vec3::new(5.5, 0.0, 4.0), up), rooms.room_of(Vec3::new(7.5, 0.0, 4.0), up));
        let outside = rooms.room_of(Vec3::new(6.0, 1.5, 4.0), Vec3::X);
        assert!(ra.is_some() && rb.is_some() && outside.is_some());
        assert!(ra != rb && ra != outside && rb != outside, "{ra:?} {rb:?} {outside:?}");
        assert_eq!(rooms.room_of(Vec3::new(1.0, 3.0, 1.0), -up), ra, "the ceiling faces into its room");

        // A 1.5 m door in each box's facing wall (the second box is the first's mirror image)
        // and a corridor between them without end walls: one room.
        let a = closed_box(Vec3::ZERO, Vec3::new(6.0, 3.0, 8.0), 1.5);
        let b: Vec<[Vec3; 3]> = closed_box(Vec3::new(7.0, 0.0, 0.0), Vec3::new(13.0, 3.0, 8.0), 1.5)
            .into_iter()
            .map(|t| t.map(|p| Vec3::new(20.0 - p.x, p.y, p.z)))
            .collect();
        let corridor: Vec<[Vec3; 3]> = closed_box(Vec3::new(6.0, 0.0, 3.25), Vec3::new(7.0, 1.5, 4.75), 0.0)
            .into_iter()
            .filter(|t| !(t.iter().all(|p| p.x == 6.0) || t.iter().all(|p| p.x == 7.0)))
            .collect();
        let shut = Rooms::new(&[a.clone(), b.clone()].concat());
        let (ra, rb) =
            (shut.room_of(Vec3::new(1.0, 0.0, 4.0), up), shut.room_of(Vec3::new(12.0, 0.0, 4.0), up));
        assert_eq!(ra, rb, "doors into the open gap: both boxes open onto the outside");
        let rooms = Rooms::new(&[a, b, corridor].concat());
        let (ra, rb) =
            (rooms.room_of(Vec3::new(1.0, 0.0, 4.0), up), rooms.room_of(Vec3::new(12.0, 0.0, 4.0), up));
        assert!(ra.is_some());
        assert_eq!(ra, rb, "the door joins the two rooms");
        assert_ne!(
            ra,
            rooms.room_of(Vec3::new(6.5, 3.0, 1.0), up),
            "the corridor keeps them from the outside"
        );
    }

    /// A box the size of the Cornell box with a block 10 cm from its walls: one room inside
    /// (the gap and the space over the block alike), the block's hollow and the outside. At the 0.1 m floor
    /// alone the gap's voxels were all marked and it was a room of its own.
    #[test]
    fn a_small_level_keeps_its_gaps_open() {
        let walls = closed_box(Vec3::ZERO, Vec3::new(0.55, 0.55, 0.55), 0.0);
        let block = closed_box(Vec3::new(0.1, 0.0, 0.1), Vec3::new(0.45, 0.33, 0.45), 0.0);
        let rooms = Rooms::new(&[walls, block].concat());
        assert!(rooms.voxel_side() < 0.1 * 0.25, "voxels of {} m", rooms.voxel_side());
        let up = Vec3::Y;
        let in_gap = rooms.room_of(Vec3::new(0.5, 0.0, 0.3), up);
        let over_block = rooms.room_of(Vec3::new(0.3, 0.33, 0.3), up);
        let behind = rooms.room_of(Vec3::new(0.3, 0.2, 0.55), Vec3::NEG_Z);
        assert!(in_gap.is_some());
        assert_eq!(in_gap, over_block);
        assert_eq!(in_gap, behind);
        assert_eq!(rooms.count(), 3, "the inside, the block's hollow and the outside");
    }

    /// A box in one of two closed rooms meets that room only; grown past the wall it meets the
    /// outside too; and after room a is filled with small closed boxes (its labels go to
    /// their insides, the others' shift), room b maps to the new label of its own space and a
    /// never to that.
    #[test]
    fn rooms_in_a_box_and_the_labels_after_an_edit() {
        let a = closed_box(Vec3::ZERO, Vec3::new(6.0, 3.0, 8.0), 0.0);
        let b = closed_box(Vec3::new(7.0, 0.0, 0.0), Vec3::new(13.0, 3.0, 8.0), 0.0);
        let both = Rooms::new(&[a.clone(), b.clone()].concat());
        let up = Vec3::Y;
        let ra = both.room_of(Vec3::new(3.0, 0.0, 4.0), up).unwrap();
        let rb = both.room_of(Vec3::new(10.0, 0.0, 4.0), up).unwrap();
        let out = both.room_of(Vec3::new(6.0, 1.5, 4.0), Vec3::X).unwrap();
        let crate_lo = Vec3::new(2.0, 0.0, 3.0);
        let crate_hi = Vec3::new(3.0, 1.0, 4.0);
        assert_eq!(both.rooms_in_box(crate_lo, crate_hi, 2), vec![ra]);
        assert_eq!(both.rooms_in_box(Vec3::new(10.0, 0.0, 3.0), Vec3::new(11.0, 1.0, 4.0), 2), vec![rb]);
        let wide = both.rooms_in_box(Vec3::new(5.0, 1.0, 3.0), Vec3::new(5.9, 1.0, 4.0), 2);
        assert_eq!(wide, {
            let mut w = vec![ra, out];
            w.sort();
            w
        });
        assert_eq!(both.rooms_in_box(Vec3::NAN, Vec3::ONE, 0).len(), both.count() as usize);

        // Room a filled solid by a block of small boxes: its space is gone, b keeps its space
        // under whatever label it now has.
        let mut fill = Vec::new();
        for i in 0..12 {
            for k in 0..16 {
                let lo = Vec3::new(0.5 * i as f32, 0.0, 0.5 * k as f32);
                fill.extend(closed_box(lo, lo + Vec3::new(0.5, 3.0, 0.5), 0.0));
            }
        }
        let filled = Rooms::new(&[a, b, fill].concat());
        let map = both.rooms_in(&filled);
        assert_eq!(map.len(), both.count() as usize);
        assert_eq!(map[rb as usize], vec![filled.room_of(Vec3::new(10.0, 0.0, 4.0), up).unwrap()]);
        assert!(map[ra as usize].iter().all(|&m| m != map[rb as usize][0]), "{map:?}");
        let same = both.rooms_in(&both);
        assert!((0..both.count()).all(|r| same[r as usize] == vec![r]), "{same:?}");
    }

    /// Non-finite corners and an empty level give one room, never a panic.
    #[test]
    fn degenerate_levels_are_one_room() {
        assert_eq!(Rooms::new(&[]).count(), 1);
        let nan = [[Vec3::NAN, Vec3::ZERO, Vec3::X]];
        assert!(Rooms::new(&nan).count() >= 1);
    }

    /// The rooms a segment's three points fall in, from the full labels (the byte table's twin).
    fn rooms_by_labels(rooms: &Rooms, a: Vec3, b: Vec3) -> Vec<u32> {
        let f = (0.5 * rooms.side / a.distance(b).max(f32::MIN_POSITIVE)).min(0.5);
        let mut out: Vec<u32> =
            [f, 0.5, 1.0 - f].iter().filter_map(|&t| rooms.free_at(a.lerp(b, t))).collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// Segments' rooms from the one-byte labels are those of the full labels, with under 255
    /// rooms (the byte table) and with more (the full labels alone), segments through walls,
    /// within a voxel and outside the grid included; and so are those of the segments' voxels
    /// looked up after they were named (`segment_voxels`, `room_of_voxel`).
    #[test]
    fn segments_find_the_same_rooms_with_byte_labels_as_with_full_ones() {
        use rand::{Rng, SeedableRng};
        // Two rooms, and 300 closed cells (301 rooms with the outside).
        let mut two = closed_box(Vec3::ZERO, Vec3::new(4.0, 3.0, 4.0), 0.0);
        two.extend(closed_box(Vec3::new(4.5, 0.0, 0.0), Vec3::new(8.5, 3.0, 4.0), 0.0));
        let mut many = Vec::new();
        for k in 0..300 {
            let lo = Vec3::new((k % 20) as f32 * 0.8, 0.0, (k / 20) as f32 * 0.8);
            many.extend(closed_box(lo, lo + Vec3::splat(0.6), 0.0));
        }
        for (level, small) in [(two, true), (many, false)] {
            let rooms = Rooms::new(&level);
            assert_eq!(rooms.bytes.is_some(), small, "{} rooms", rooms.count());
            let (lo, hi) = (rooms.lo, rooms.lo + Vec3::from_array(rooms.dims.map(|d| d as f32)) * rooms.side);
            let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
            let mut point = || lo - 1.0 + (hi - lo + 2.0) * Vec3::from(rng.random::<[f32; 3]>());
            let mut seen = 0;
            for k in 0..4000 {
                let a = point();
                let b = if k % 4 == 0 { a + 0.3 * rooms.side * Vec3::ONE } else { point() };
                let mut found = Vec::new();
                rooms.rooms_on_segment(a, b, |r| found.push(r));
                found.sort_unstable();
                found.dedup();
                assert_eq!(found, rooms_by_labels(&rooms, a, b), "segment {a} .. {b}");
                // The same points named first and looked up later, as a recording walk does.
                let mut voxels = Vec::new();
                rooms.segment_voxels(a, b, |v| voxels.push(v));
                let mut later: Vec<u32> = voxels.iter().filter_map(|&v| rooms.room_of_voxel(v)).collect();
                later.sort_unstable();
                later.dedup();
                assert_eq!(later, found, "segment {a} .. {b}, looked up later");
                seen += found.len();
            }
            assert!(seen > 500, "the segments found {seen} rooms");
        }
    }
}
