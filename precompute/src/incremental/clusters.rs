//! VPL clusters (paper 001 §3.4, §4.1): an octree over the VPLs, cut where a cell holds at most
//! `leaf_vpls` of them, and up to K virtual lights per cell from similarity clustering: planes
//! first (polygon lights), the rest by orientation (disk lights).
//!
//! The cut is a function of the VPL set alone, and a cell's lights a function of its members in
//! a fixed order, so a level reached by edits and the same level baked afresh have the same
//! clusters. Two cuts:
//! - [`cut`]: refine while a cell holds more than `leaf_vpls` VPLs, down to `max_depth`;
//! - [`balanced_cut`]: paper 001's balancing (§4.3, §5) for a budget of N cells: starting from
//!   the root, refine the cell of largest metric B until N cells are selected. That is
//!   Algorithm 1 run from its first state (the root selected). The paper runs it again from
//!   the last state after each edit; where B does not grow from a cell to its parent, that
//!   fixed point depends on the order of past updates. Here the target after an edit is the
//!   greedy cut of the new VPLs, reached by Refine / Merge region updates
//!   ([`super::baker`]), so an edited level and a fresh bake have the same cut.

use glam::{Vec2, Vec3};

use super::level::Aabb;
use crate::reference::form_factor::{clip_above_plane, PolygonLight};
use crate::reference::polygon::light_polygon;

/// Bits per axis of the finest cell coordinates.
pub const MAX_DEPTH: u32 = 10;
/// Orientation tolerance of a plane cluster (paper 001: 1 degree).
pub const SIGMA_N_DEG: f32 = 1.0;
/// Offset tolerance of a plane cluster, as a share of the cell's edge (paper 001: 0.01).
pub const SIGMA_D_REL: f32 = 0.01;
/// Member VPLs kept per virtual light for its soft visibility.
pub const VISIBILITY_MEMBERS: usize = 16;

/// A VPL as the clustering sees it, with the path vertex it comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Member {
    pub code: u32,
    pub light: u32,
    pub path: u32,
    pub vertex: u32,
    pub position: Vec3,
    pub normal: Vec3,
    pub power: Vec3,
    /// Luminance of the power the path carries on to its next vertex (0 where it ended):
    /// summed over a cell, paper 001's visual contribution Φ_Ω (eq. 4).
    pub onward: f32,
    /// Distance to that next vertex (0 where the path ended): where the cell's light lands.
    pub reach: f32,
}

/// Finest-level Morton code of `p` in `root` (points outside are clamped to its border cells).
pub fn morton(root: &Aabb, p: Vec3, depth: u32) -> u32 {
    let n = (1u32 << depth) as f32;
    let rel = (p - root.lo) / (root.hi - root.lo).max(Vec3::splat(f32::MIN_POSITIVE));
    let q = (rel * n).floor().clamp(Vec3::ZERO, Vec3::splat(n - 1.0));
    let (x, y, z) = (q.x as u32, q.y as u32, q.z as u32);
    let mut code = 0u32;
    for b in (0..depth).rev() {
        code = code << 3 | ((x >> b) & 1) << 2 | ((y >> b) & 1) << 1 | ((z >> b) & 1);
    }
    code
}

/// A cell key: depth in the high half, the Morton prefix in the low.
pub fn key(depth: u32, prefix: u32) -> u64 {
    (depth as u64) << 32 | prefix as u64
}

/// The box of cell `k`.
pub fn cell_box(root: &Aabb, k: u64) -> Aabb {
    let depth = (k >> 32) as u32;
    let prefix = k as u32;
    let (mut x, mut y, mut z) = (0u32, 0u32, 0u32);
    for b in (0..depth).rev() {
        let t = prefix >> (3 * b);
        x = x << 1 | (t >> 2) & 1;
        y = y << 1 | (t >> 1) & 1;
        z = z << 1 | t & 1;
    }
    let size = (root.hi - root.lo) / (1u32 << depth) as f32;
    let lo = root.lo + size * Vec3::new(x as f32, y as f32, z as f32);
    Aabb { lo, hi: lo + size }
}

/// Whether cell `a` contains cell `b` (or is it).
pub fn contains(a: u64, b: u64) -> bool {
    let (da, db) = ((a >> 32) as u32, (b >> 32) as u32);
    da <= db && (b as u32) >> (3 * (db - da)) == a as u32
}

/// The cut: for `members` sorted by code, the cells (key, member range).
pub fn cut(members: &[Member], leaf_vpls: usize, max_depth: u32) -> Vec<(u64, std::ops::Range<usize>)> {
    let mut out = Vec::new();
    split(members, 0, 0..members.len(), 0, leaf_vpls.max(1), max_depth.min(MAX_DEPTH), &mut out);
    out
}

fn split(
    m: &[Member],
    depth: u32,
    r: std::ops::Range<usize>,
    prefix: u32,
    leaf: usize,
    max_depth: u32,
    out: &mut Vec<(u64, std::ops::Range<usize>)>,
) {
    if r.is_empty() {
        return;
    }
    if r.len() <= leaf || depth == max_depth {
        out.push((key(depth, prefix), r));
        return;
    }
    let shift = 3 * (MAX_DEPTH - depth - 1);
    let mut start = r.start;
    for child in 0..8u32 {
        let end = start + m[start..r.end].partition_point(|x| (x.code >> shift) & 7 <= child);
        split(m, depth + 1, start..end, prefix << 3 | child, leaf, max_depth, out);
        start = end;
    }
}

/// Paper 001's balancing metric B of a VPL cluster (§5): visual contribution Φ_Ω times the
/// visibility error E_v = r² / (d_avg + r)², π and the directionality D (I_max / Φ = 1/π for
/// a Lambertian cluster, the same for every cell) dropped as constant factors, and the
/// clustering term 1.
///
/// Φ_Ω is eq. (4): the flux the cluster's particles deposit, times the albedo where they land,
/// over the particles scattered. With Russian roulette by albedo (our paths), a vertex's next
/// vertex carries in expectation exactly that, so Φ_Ω is the sum of `onward`. (Eq. (3)'s
/// leading 1/(2π) does not belong there: with the importance-sampled I the sum is already the
/// flux, as eq. (4) says; a constant factor, so it does not change the balance.) r is the
/// half-diagonal of the members' box, d_avg the mean `reach`, weighted by `onward`.
pub fn balance_metric(members: &[Member]) -> f32 {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let (mut phi, mut dsum) = (0.0f64, 0.0f64);
    for m in members {
        lo = lo.min(m.position);
        hi = hi.max(m.position);
        if m.onward > 0.0 && m.reach.is_finite() {
            phi += m.onward as f64;
            dsum += m.onward as f64 * m.reach as f64;
        }
    }
    if !(phi > 0.0) || members.len() < 2 {
        return 0.0;
    }
    let r = 0.5 * (hi - lo).length() as f64;
    let d = dsum / phi;
    let ev = r * r / ((d + r) * (d + r)).max(f64::MIN_POSITIVE);
    (phi * ev) as f32
}

/// The balanced cut for `members` sorted by code: from the root, the cell of largest
/// [`balance_metric`] is refined into its non-empty children until at least `cells` cells are
/// selected (a refinement adds up to 7, so at most `cells` + 6), or none can be refined (at
/// `max_depth`, one member, B = 0 or not a number). Ties go to the lower key.
pub fn balanced_cut(members: &[Member], cells: usize, max_depth: u32) -> Vec<(u64, std::ops::Range<usize>)> {
    use std::collections::BinaryHeap;
    #[derive(PartialEq)]
    struct Node {
        b: f32,
        depth: u32,
        prefix: u32,
        range: std::ops::Range<usize>,
    }
    impl Eq for Node {}
    impl Ord for Node {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            self.b.total_cmp(&o.b).then(key(o.depth, o.prefix).cmp(&key(self.depth, self.prefix)))
        }
    }
    impl PartialOrd for Node {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    let max_depth = max_depth.min(MAX_DEPTH);
    let mut out = Vec::new();
    if members.is_empty() {
        return out;
    }
    let node = |depth: u32, prefix: u32, range: std::ops::Range<usize>| Node {
        b: if depth < max_depth { balance_metric(&members[range.clone()]) } else { 0.0 },
        depth,
        prefix,
        range,
    };
    let mut heap = BinaryHeap::from([node(0, 0, 0..members.len())]);
    let mut count = 1usize;
    while count < cells.max(1) {
        let Some(top) = heap.pop() else { break };
        if !(top.b > 0.0) {
            heap.push(top);
            break;
        }
        let shift = 3 * (MAX_DEPTH - top.depth - 1);
        let mut start = top.range.start;
        let mut children = 0;
        for child in 0..8u32 {
            let end =
                start + members[start..top.range.end].partition_point(|x| (x.code >> shift) & 7 <= child);
            if end > start {
                heap.push(node(top.depth + 1, top.prefix << 3 | child, start..end));
                children += 1;
            }
            start = end;
        }
        count += children - 1;
    }
    out.extend(heap.into_iter().map(|n| (key(n.depth, n.prefix), n.range)));
    out.sort_unstable_by_key(|(_, r)| r.start);
    out
}

/// A virtual light: a Lambertian polygon (a disk is a regular octagon of its area) and the
/// member VPLs its visibility is sampled at.
#[derive(Clone, Debug, PartialEq)]
pub struct VirtualLight {
    pub polygon: PolygonLight,
    pub samples: Vec<(Vec3, Vec3)>,
}

fn luminance(c: Vec3) -> f32 {
    super::paths::luminance(c)
}

fn frame(n: Vec3) -> (Vec3, Vec3) {
    let u = n.any_orthonormal_vector();
    (u, n.cross(u))
}

fn samples_of(members: &[&Member]) -> Vec<(Vec3, Vec3)> {
    let stride = members.len().div_ceil(VISIBILITY_MEMBERS).max(1);
    members.iter().step_by(stride).map(|m| (m.position, m.normal)).collect()
}

/// The virtual lights of one cell: at most `k` of them, polygons for plane clusters of at least
/// `p_min` VPLs (the `k - 1` largest when there are more than `k` planes), disks for the rest.
/// Their power sums to the members' power exactly.
pub fn cell_lights(members: &[Member], cell: &Aabb, k: usize, p_min: usize) -> Vec<VirtualLight> {
    if members.is_empty() {
        return Vec::new();
    }
    let k = k.max(1);
    let edge = (cell.hi - cell.lo).max_element().max(f32::MIN_POSITIVE);
    let centre = 0.5 * (cell.lo + cell.hi);
    let sin_n = SIGMA_N_DEG.to_radians().sin();
    let scale = sin_n / (SIGMA_D_REL * edge);
    // 4-D plane vectors (paper 001 §4.1): normal and offset about the cell's centre, the
    // offset scaled so that sigma_d of it weighs as much as sigma_n of angle.
    let plane = |m: &Member| -> [f32; 4] {
        let n = m.normal;
        [n.x, n.y, n.z, n.dot(m.position - centre) * scale]
    };
    let d2 = |a: &[f32; 4], b: &[f32; 4]| (0..4).map(|i| (a[i] - b[i]) * (a[i] - b[i])).sum::<f32>();
    let mut order: Vec<usize> = (0..members.len()).collect();
    order.sort_by(|&a, &b| {
        luminance(members[b].power).total_cmp(&luminance(members[a].power)).then(a.cmp(&b))
    });
    let feats: Vec<[f32; 4]> = members.iter().map(plane).collect();
    let mut assigned = vec![usize::MAX; members.len()];
    let mut planes: Vec<Vec<usize>> = Vec::new();
    for &seed in &order {
        if assigned[seed] != usize::MAX {
            continue;
        }
        let c = planes.len();
        assigned[seed] = c;
        let mut group = vec![seed];
        let mut mean = feats[seed];
        for _ in 0..8 {
            let mut added = false;
            for &j in &order {
                if assigned[j] == usize::MAX && d2(&feats[j], &mean) <= sin_n * sin_n {
                    assigned[j] = c;
                    group.push(j);
                    added = true;
                }
            }
            if !added {
                break;
            }
            let mut s = [0.0f32; 4];
            for &j in &group {
                for (a, b) in s.iter_mut().zip(&feats[j]) {
                    *a += b;
                }
            }
            let nl = Vec3::new(s[0], s[1], s[2]).length().max(f32::MIN_POSITIVE);
            mean = [s[0] / nl, s[1] / nl, s[2] / nl, s[3] / group.len() as f32];
        }
        planes.push(group);
    }
    let power = |g: &[usize]| g.iter().fold(Vec3::ZERO, |a, &i| a + members[i].power);
    planes.sort_by(|a, b| luminance(power(b)).total_cmp(&luminance(power(a))).then(a[0].cmp(&b[0])));
    let polygon_slots = if planes.len() > k { k - 1 } else { k };
    let mut out = Vec::new();
    let mut rest: Vec<usize> = Vec::new();
    for (i, g) in planes.iter().enumerate() {
        let light =
            if i < polygon_slots && g.len() >= p_min { plane_polygon(members, g, cell) } else { None };
        match light {
            Some(l) => out.push(l),
            None => rest.extend(g),
        }
    }
    if !rest.is_empty() {
        rest.sort_unstable();
        let slots = k.saturating_sub(out.len()).max(1);
        out.extend(disks(members, &rest, slots, edge));
    }
    out
}

/// A polygon light over a plane cluster, clipped to the cell; `None` when clipping leaves
/// nothing.
fn plane_polygon(members: &[Member], g: &[usize], cell: &Aabb) -> Option<VirtualLight> {
    let n = g.iter().fold(Vec3::ZERO, |a, &i| a + members[i].normal).normalize_or_zero();
    if n == Vec3::ZERO {
        return None;
    }
    let origin = g.iter().fold(Vec3::ZERO, |a, &i| a + members[i].position) / g.len() as f32;
    let (u, v) = frame(n);
    let pts: Vec<Vec2> = g
        .iter()
        .map(|&i| Vec2::new((members[i].position - origin).dot(u), (members[i].position - origin).dot(v)))
        .collect();
    // The cell's projection's bounding rectangle: a loose 2-D clip; the 3-D clip is exact.
    let corners = (0..8).map(|c| {
        Vec3::new(
            if c & 1 == 0 { cell.lo.x } else { cell.hi.x },
            if c & 2 == 0 { cell.lo.y } else { cell.hi.y },
            if c & 4 == 0 { cell.lo.z } else { cell.hi.z },
        )
    });
    let (lo, hi) = corners.fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(l, h), c| {
        let q = Vec2::new((c - origin).dot(u), (c - origin).dot(v));
        (l.min(q), h.max(q))
    });
    let poly2 = light_polygon(&pts, lo, hi);
    let mut poly: Vec<Vec3> = poly2.iter().map(|q| origin + u * q.x + v * q.y).collect();
    // The cell's faces pushed out by a hair: a plane cluster lying on a face (a floor at a
    // cell boundary, paper 001's border case) keeps its polygon instead of losing it whole.
    let hair = Vec3::splat(1e-4 * (cell.hi - cell.lo).max_element());
    for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
        poly = clip_above_plane(&poly, cell.lo - hair, axis);
        poly = clip_above_plane(&poly, cell.hi + hair, -axis);
        if poly.len() < 3 {
            return None;
        }
    }
    let light = PolygonLight::new(poly, n, g.iter().fold(Vec3::ZERO, |a, &i| a + members[i].power));
    if !(light.area() > 0.0) {
        return None;
    }
    let ms: Vec<&Member> = g.iter().map(|&i| &members[i]).collect();
    Some(VirtualLight { polygon: light, samples: samples_of(&ms) })
}

/// Disk lights over `rest`: k-means on the normals (angular distance), then one disk per
/// group at the member nearest the group's mean, facing its mean normal, of the radius whose
/// uniform disk has the members' in-plane spread (and at least half the spacing of `n` VPLs
/// over a cell face, so a lone VPL is not a point).
fn disks(members: &[Member], rest: &[usize], k: usize, edge: f32) -> Vec<VirtualLight> {
    let k = k.min(rest.len()).max(1);
    let first = *rest
        .iter()
        .max_by(|&&a, &&b| {
            luminance(members[a].power).total_cmp(&luminance(members[b].power)).then(b.cmp(&a))
        })
        .unwrap_or(&rest[0]);
    let mut centres = vec![members[first].normal];
    while centres.len() < k {
        // The member least like every centre so far.
        let far = rest
            .iter()
            .map(|&i| (centres.iter().map(|c| c.dot(members[i].normal)).fold(f32::MIN, f32::max), i))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
            .map(|x| x.1)
            .unwrap_or(first);
        centres.push(members[far].normal);
    }
    let assign = |centres: &[Vec3]| -> Vec<usize> {
        rest.iter()
            .map(|&i| {
                (0..centres.len())
                    .max_by(|&a, &b| {
                        centres[a]
                            .dot(members[i].normal)
                            .total_cmp(&centres[b].dot(members[i].normal))
                            .then(b.cmp(&a))
                    })
                    .unwrap_or(0)
            })
            .collect()
    };
    let mut groups = assign(&centres);
    for _ in 0..8 {
        for (c, centre) in centres.iter_mut().enumerate() {
            let s = rest.iter().zip(&groups).filter(|(_, &g)| g == c).fold(Vec3::ZERO, |a, (&i, _)| {
                a + members[i].normal * luminance(members[i].power).max(1e-30)
            });
            if let Some(n) = s.try_normalize() {
                *centre = n;
            }
        }
        let next = assign(&centres);
        if next == groups {
            break;
        }
        groups = next;
    }
    let mut out = Vec::new();
    for c in 0..centres.len() {
        let ms: Vec<&Member> =
            rest.iter().zip(&groups).filter(|(_, &g)| g == c).map(|(&i, _)| &members[i]).collect();
        if ms.is_empty() {
            continue;
        }
        let power = ms.iter().fold(Vec3::ZERO, |a, m| a + m.power);
        let n = ms
            .iter()
            .fold(Vec3::ZERO, |a, m| a + m.normal * luminance(m.power).max(1e-30))
            .try_normalize()
            .unwrap_or(ms[0].normal);
        let mean = ms.iter().fold(Vec3::ZERO, |a, m| a + m.position) / ms.len() as f32;
        let centre = ms
            .iter()
            .map(|m| m.position)
            .min_by(|a, b| (*a - mean).length_squared().total_cmp(&(*b - mean).length_squared()))
            .unwrap_or(mean);
        let spread = ms
            .iter()
            .map(|m| {
                let d = m.position - centre;
                (d - n * d.dot(n)).length_squared()
            })
            .sum::<f32>()
            / ms.len() as f32;
        let r = (2.0 * spread).sqrt().max(0.5 * edge / (ms.len() as f32).sqrt());
        // A regular octagon of the disk's area: circumradius r sqrt(pi / (2 sqrt 2)).
        let big = r * (std::f32::consts::PI / (2.0 * std::f32::consts::SQRT_2)).sqrt();
        let (u, v) = frame(n);
        let vertices = (0..8)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / 8.0;
                centre + (u * a.cos() + v * a.sin()) * big
            })
            .collect();
        out.push(VirtualLight { polygon: PolygonLight::new(vertices, n, power), samples: samples_of(&ms) });
    }
    out
}

/// A sphere around a light's polygon and visibility samples: where its light leaves from.
pub fn bound(lights: &[VirtualLight]) -> (Vec3, f32) {
    let pts: Vec<Vec3> = lights
        .iter()
        .flat_map(|l| l.polygon.vertices.iter().copied().chain(l.samples.iter().map(|s| s.0)))
        .collect();
    if pts.is_empty() {
        return (Vec3::ZERO, 0.0);
    }
    let c = pts.iter().fold(Vec3::ZERO, |a, p| a + *p) / pts.len() as f32;
    (c, pts.iter().map(|p| (*p - c).length()).fold(0.0, f32::max))
}
