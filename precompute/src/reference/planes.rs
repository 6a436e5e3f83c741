//! Plane detection in a VPL set (paper 000 §5.2, after Schnabel et al. 2007): RANSAC with
//! one-point hypotheses (a VPL's position and normal define a plane), inliers within `delta` of
//! the plane and within 10 degrees of its normal, the best of `tries` hypotheses kept while it
//! has at least `min_size` inliers. Inliers are split into connected pieces on a grid in the
//! plane, so two coplanar but separate floors become two segments. What no plane takes is
//! clustered in 3D.

use glam::{Vec2, Vec3};
use rand::Rng;

use prm::sampling::stream;

/// A planar segment: an orthonormal frame and the VPLs on it.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneSegment {
    pub origin: Vec3,
    pub normal: Vec3,
    pub u: Vec3,
    pub v: Vec3,
    pub members: Vec<u32>,
}

impl PlaneSegment {
    /// In-plane coordinates of a point.
    pub fn project(&self, p: Vec3) -> Vec2 {
        let d = p - self.origin;
        Vec2::new(d.dot(self.u), d.dot(self.v))
    }
    /// The point of the plane at in-plane coordinates `q`.
    pub fn lift(&self, q: Vec2) -> Vec3 {
        self.origin + self.u * q.x + self.v * q.y
    }
}

/// Hypotheses per extracted plane.
const TRIES: usize = 48;
/// cos(10 degrees): normal agreement of an inlier.
const MIN_COS: f32 = 0.985;

/// Split `members` (indices into `positions`/`normals`) into planar segments and the rest.
pub fn detect_planes(
    positions: &[Vec3],
    normals: &[Vec3],
    members: &[u32],
    delta: f32,
    min_size: usize,
    seed: u64,
) -> (Vec<PlaneSegment>, Vec<u32>) {
    let mut remaining: Vec<u32> = members.to_vec();
    let mut segments = Vec::new();
    let mut rest = Vec::new();
    let mut rng = stream(seed, 20, members.len() as u64);
    let inliers_of = |rem: &[u32], p: Vec3, n: Vec3| -> Vec<u32> {
        rem.iter()
            .copied()
            .filter(|&i| {
                (positions[i as usize] - p).dot(n).abs() <= delta && normals[i as usize].dot(n) >= MIN_COS
            })
            .collect()
    };
    while remaining.len() >= min_size.max(3) {
        let mut best: Option<(usize, Vec3, Vec3)> = None;
        for _ in 0..TRIES {
            let s = remaining[rng.random_range(0..remaining.len())] as usize;
            let (p, n) = (positions[s], normals[s]);
            let count = remaining
                .iter()
                .filter(|&&i| {
                    (positions[i as usize] - p).dot(n).abs() <= delta && normals[i as usize].dot(n) >= MIN_COS
                })
                .count();
            if best.is_none_or(|b| count > b.0) {
                best = Some((count, p, n));
            }
        }
        let Some((count, p, n)) = best else { break };
        if count < min_size {
            break;
        }
        // Refit: mean normal and position of the inliers.
        let first = inliers_of(&remaining, p, n);
        // Sums in f64: thousands of f32 positions summed in f32 drift by 1e-5 of their size,
        // enough to lift a light off its wall and have the wall hide it.
        let nn = first
            .iter()
            .fold(glam::DVec3::ZERO, |a, &i| a + normals[i as usize].as_dvec3())
            .normalize_or_zero()
            .as_vec3();
        let n = if nn == Vec3::ZERO { n } else { nn };
        let centre = (first.iter().fold(glam::DVec3::ZERO, |a, &i| a + positions[i as usize].as_dvec3())
            / first.len() as f64)
            .as_vec3();
        let inl = inliers_of(&remaining, centre, n);
        let taken: std::collections::HashSet<u32> = inl.iter().copied().collect();
        remaining.retain(|i| !taken.contains(i));
        let (u, v) = n.any_orthonormal_pair();
        let frame = PlaneSegment { origin: centre, normal: n, u, v, members: Vec::new() };
        for piece in connected_pieces(&frame, positions, &inl) {
            if piece.len() >= min_size {
                segments.push(PlaneSegment { members: piece, ..frame.clone() });
            } else {
                rest.extend(piece);
            }
        }
        if inl.is_empty() {
            break;
        }
    }
    rest.extend(remaining);
    rest.sort_unstable();
    (segments, rest)
}

/// Connected pieces of coplanar points on a grid of about 3 point spacings.
fn connected_pieces(frame: &PlaneSegment, positions: &[Vec3], members: &[u32]) -> Vec<Vec<u32>> {
    use std::collections::HashMap;
    if members.is_empty() {
        return Vec::new();
    }
    let q: Vec<Vec2> = members.iter().map(|&i| frame.project(positions[i as usize])).collect();
    let (lo, hi) = q.iter().fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(l, h), p| (l.min(*p), h.max(*p)));
    let extent = (hi - lo).max(Vec2::splat(1e-12));
    let cell = 3.0 * (extent.x * extent.y / members.len() as f32).sqrt().max(1e-9 * extent.max_element());
    let key = |p: Vec2| (((p.x - lo.x) / cell).floor() as i64, ((p.y - lo.y) / cell).floor() as i64);
    let mut cells: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (k, p) in q.iter().enumerate() {
        cells.entry(key(*p)).or_default().push(k);
    }
    let mut keys: Vec<(i64, i64)> = cells.keys().copied().collect();
    keys.sort_unstable();
    let mut label: HashMap<(i64, i64), usize> = HashMap::new();
    let mut pieces: Vec<Vec<u32>> = Vec::new();
    for &start in &keys {
        if label.contains_key(&start) {
            continue;
        }
        let id = pieces.len();
        let mut piece = Vec::new();
        let mut stack = vec![start];
        label.insert(start, id);
        while let Some(c) = stack.pop() {
            piece.extend(cells[&c].iter().map(|&k| members[k]));
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let nb = (c.0 + dx, c.1 + dy);
                    if cells.contains_key(&nb) && !label.contains_key(&nb) {
                        label.insert(nb, id);
                        stack.push(nb);
                    }
                }
            }
        }
        piece.sort_unstable();
        pieces.push(piece);
    }
    pieces
}
