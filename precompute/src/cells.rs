//! Entry cells (DESIGN.md §4, `prm::prm_file::Cells`): the surface each entry point stands for.
//!
//! The runtime weights an entry by the power its cell receives over the entry's area, so the
//! cells must tile the lit surfaces: then the weights carry all the power that reaches them,
//! however close a light comes (a point sample misses a hot spot smaller than the entry
//! spacing). A cell is the entry's Voronoi region among the entries of its own triangle,
//! clipped to the triangle and cut into a fan of triangles around the entry. A triangle too
//! small to get an entry joins the cell of the nearest entry facing the same way (normals
//! within ~45°, at most a few entry spacings away); what no entry takes is reported.
//! Entries inside solids are sampled, given their cells, and then dropped with them: that
//! surface is never lit.

use glam::{DVec2, Vec3};
use prm::prm_file::{Cells, Entry};
use prm::Scene;
use rayon::prelude::*;

/// The cells and what they leave out.
#[derive(Clone, Debug, Default)]
pub struct CellReport {
    /// Area of the triangles no entry took (no entry of theirs, none near enough).
    pub area_without_entry: f64,
}

/// Smallest cosine between a triangle without an entry and the entry whose cell it joins.
const MIN_NORMAL_COS: f32 = 0.7;
/// How far (in entry spacings, sqrt(A / N)) such a triangle's centroid may be from that entry.
const MAX_SPACINGS: f32 = 3.0;

/// The cells of `entries` (all sampled entries, in order); those with `keep[j]` false are
/// dropped from the result. The result is in the kept entries' order.
pub fn entry_cells(scene: &Scene, entries: &[Entry], keep: &[bool]) -> (Cells, CellReport) {
    let mut by_triangle: Vec<Vec<usize>> = vec![Vec::new(); scene.triangles.len()];
    for (j, e) in entries.iter().enumerate() {
        by_triangle[e.triangle as usize].push(j);
    }
    let mut lists: Vec<Vec<[Vec3; 3]>> = (0..entries.len())
        .into_par_iter()
        .map(|j| {
            let e = &entries[j];
            let t = e.triangle as usize;
            let others = by_triangle[t].iter().filter(|&&k| k != j).map(|&k| (k, entries[k].position));
            voronoi_fan(scene.corners(t), (j, e.position), others)
        })
        .collect();
    let kept: Vec<usize> = (0..entries.len()).filter(|&j| keep[j]).collect();
    let spacing = entries.first().map_or(0.0, |e| e.area.sqrt());
    let mut report = CellReport::default();
    for (t, members) in by_triangle.iter().enumerate() {
        if !members.is_empty() || scene.area(t) <= 0.0 {
            continue;
        }
        let corners = scene.corners(t);
        let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
        let n = scene.face_normal(t);
        let nearest = kept
            .iter()
            .filter(|&&j| entries[j].normal.dot(n) >= MIN_NORMAL_COS)
            .map(|&j| (j, entries[j].position.distance_squared(centroid)))
            .filter(|&(_, d2)| d2 <= (MAX_SPACINGS * spacing).powi(2))
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        match nearest {
            Some((j, _)) => lists[j].push(corners),
            None => report.area_without_entry += scene.area(t) as f64,
        }
    }
    let kept_lists = lists.drain(..).zip(keep).filter(|(_, &k)| k).map(|(l, _)| l).collect();
    (Cells::from_lists(kept_lists), report)
}

/// Entry `me`'s Voronoi region among `others` (entries on the same triangle), clipped to the
/// triangle `corners` and fanned around the entry: triangles counter-clockwise seen from the
/// triangle's front. Entries at the same point: the lower index takes the region.
fn voronoi_fan(
    corners: [Vec3; 3],
    me: (usize, Vec3),
    others: impl Iterator<Item = (usize, Vec3)>,
) -> Vec<[Vec3; 3]> {
    let [p0, p1, p2] = corners;
    let normal = (p1 - p0).cross(p2 - p0);
    if !(normal.length_squared() > 0.0) {
        return Vec::new();
    }
    // A 2D frame in the triangle's plane, counter-clockwise from the front; f64 so clipped
    // corners shared by neighbouring cells agree closely.
    let u = (p1 - p0).normalize().as_dvec3();
    let v = normal.normalize().as_dvec3().cross(u);
    let origin = p0.as_dvec3();
    let to_2d = |p: Vec3| {
        let d = p.as_dvec3() - origin;
        DVec2::new(d.dot(u), d.dot(v))
    };
    let to_3d = |q: DVec2| (origin + u * q.x + v * q.y).as_vec3();
    let z = to_2d(me.1);
    let mut poly: Vec<DVec2> = corners.iter().map(|&c| to_2d(c)).collect();
    let mut near: Vec<(f64, usize, DVec2)> = others
        .map(|(k, p)| {
            let q = to_2d(p);
            (q.distance_squared(z), k, q)
        })
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    for (d2, k, q) in near {
        // Past twice the farthest corner of the region, no bisector can cut it.
        let reach = poly.iter().map(|p| p.distance_squared(z)).fold(0.0, f64::max);
        if d2 > 4.0 * reach {
            break;
        }
        if d2 == 0.0 {
            if k < me.0 {
                return Vec::new();
            }
            continue;
        }
        // Keep the side nearer to z: (p - midpoint) . (q - z) <= 0.
        poly = clip(&poly, (z + q) * 0.5, q - z);
        if poly.is_empty() {
            return Vec::new();
        }
    }
    let zp = me.1;
    (0..poly.len())
        .filter_map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            // Only pieces with area (the entry on an edge makes slivers of none).
            ((a - z).perp_dot(b - z) > 0.0).then(|| [zp, to_3d(a), to_3d(b)])
        })
        .collect()
}

/// The convex polygon `poly` cut to the half-plane `(p - m) . dir <= 0` (Sutherland-Hodgman).
fn clip(poly: &[DVec2], m: DVec2, dir: DVec2) -> Vec<DVec2> {
    let side = |p: DVec2| (p - m).dot(dir);
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let (sa, sb) = (side(a), side(b));
        if sa <= 0.0 {
            out.push(a);
        }
        if (sa < 0.0 && sb > 0.0) || (sa > 0.0 && sb < 0.0) {
            out.push(a + (b - a) * (sa / (sa - sb)));
        }
    }
    out
}
