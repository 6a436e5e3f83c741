//! Virtual polygon lights from planar VPL clusters (paper 000 §5.2, Fig. 6): the 2D convex hull
//! of the cluster's VPLs, simplified to at most 8 vertices, grown by a border of
//! `1.5 sqrt(A_hull / n)` and clipped to the kd cell. Simplification only ever removes area
//! from the outside's complement (it replaces an edge by extending its neighbours until they
//! meet), so the simplified hull still contains every VPL.

use glam::Vec2;

/// Twice the signed area.
fn area2(p: &[Vec2]) -> f32 {
    let mut s = 0.0;
    for k in 0..p.len() {
        s += p[k].perp_dot(p[(k + 1) % p.len()]);
    }
    s
}

/// Area of a simple polygon.
pub fn area(p: &[Vec2]) -> f32 {
    0.5 * area2(p).abs()
}

/// Convex hull, counter-clockwise, no collinear points (Andrew's monotone chain).
pub fn convex_hull(points: &[Vec2]) -> Vec<Vec2> {
    let mut pts: Vec<Vec2> = points.to_vec();
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: Vec2, a: Vec2, b: Vec2| (a - o).perp_dot(b - o);
    let mut lower: Vec<Vec2> = Vec::new();
    for &p in &pts {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], p) <= 0.0 {
            lower.pop();
        }
        lower.push(p);
    }
    let mut upper: Vec<Vec2> = Vec::new();
    for &p in pts.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], p) <= 0.0 {
            upper.pop();
        }
        upper.push(p);
    }
    lower.pop();
    upper.pop();
    lower.extend(upper);
    lower
}

/// Intersection of lines (a0 + t da) and (b0 + s db).
fn line_intersection(a0: Vec2, da: Vec2, b0: Vec2, db: Vec2) -> Option<Vec2> {
    let den = da.perp_dot(db);
    if den.abs() < 1e-20 {
        return None;
    }
    let t = (b0 - a0).perp_dot(db) / den;
    Some(a0 + da * t)
}

/// Reduce a convex counter-clockwise polygon to at most `max` vertices, each step removing the
/// edge whose removal adds the least area (its neighbours extended to meet). The result
/// contains the input.
pub fn simplify_outer(poly: &[Vec2], max: usize) -> Vec<Vec2> {
    let mut p = poly.to_vec();
    while p.len() > max.max(3) {
        let n = p.len();
        let mut best: Option<(f32, usize, Vec2)> = None;
        for i in 0..n {
            // Remove edge (p[i], p[i+1]): extend edges (p[i-1] -> p[i]) and (p[i+2] -> p[i+1]).
            let (a, b, c, d) = (p[(i + n - 1) % n], p[i], p[(i + 1) % n], p[(i + 2) % n]);
            let (da, dd) = (b - a, c - d);
            let Some(q) = line_intersection(b, da, c, dd) else { continue };
            // The extensions must meet beyond the edge (outside the polygon).
            if (q - b).dot(da) < 0.0 || (q - c).dot(dd) < 0.0 {
                continue;
            }
            let added = 0.5 * (c - b).perp_dot(q - b).abs();
            if best.is_none_or(|bst| added < bst.0) {
                best = Some((added, i, q));
            }
        }
        let Some((_, i, q)) = best else { break };
        let j = (i + 1) % p.len();
        p[i] = q;
        p.remove(j);
    }
    p
}

/// Grow a convex counter-clockwise polygon by moving every edge outward by `b`.
pub fn grow(poly: &[Vec2], b: f32) -> Vec<Vec2> {
    let n = poly.len();
    if n < 3 {
        return poly.to_vec();
    }
    let offset_line = |i: usize| {
        let (a, c) = (poly[i], poly[(i + 1) % n]);
        let d = c - a;
        let out = Vec2::new(d.y, -d.x).normalize_or_zero(); // right of the edge = outside (CCW)
        (a + out * b, d)
    };
    (0..n)
        .map(|i| {
            let (p0, d0) = offset_line((i + n - 1) % n);
            let (p1, d1) = offset_line(i);
            line_intersection(p0, d0, p1, d1).unwrap_or(poly[i])
        })
        .collect()
}

/// Clip a polygon to the rectangle [lo, hi] (Sutherland-Hodgman).
pub fn clip_to_rect(poly: &[Vec2], lo: Vec2, hi: Vec2) -> Vec<Vec2> {
    let mut p = poly.to_vec();
    let planes = [(Vec2::X, lo.x), (-Vec2::X, -hi.x), (Vec2::Y, lo.y), (-Vec2::Y, -hi.y)];
    for (n, d) in planes {
        if p.is_empty() {
            break;
        }
        let mut out = Vec::with_capacity(p.len() + 2);
        for k in 0..p.len() {
            let (a, b) = (p[k], p[(k + 1) % p.len()]);
            let (da, db) = (a.dot(n) - d, b.dot(n) - d);
            if da >= 0.0 {
                out.push(a);
            }
            if (da >= 0.0) != (db >= 0.0) {
                out.push(a + (b - a) * (da / (da - db)));
            }
        }
        p = out;
    }
    p
}

/// True when `q` is inside (or on) the convex counter-clockwise polygon, with slack `tol`.
pub fn contains(poly: &[Vec2], q: Vec2, tol: f32) -> bool {
    (0..poly.len()).all(|k| {
        let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
        let e = b - a;
        e.perp_dot(q - a) >= -tol * e.length()
    })
}

/// True when the polygon is convex and counter-clockwise.
pub fn is_convex_ccw(poly: &[Vec2]) -> bool {
    let n = poly.len();
    n >= 3
        && (0..n).all(|k| {
            (poly[(k + 1) % n] - poly[k]).perp_dot(poly[(k + 2) % n] - poly[(k + 1) % n])
                >= -1e-6 * (poly[(k + 1) % n] - poly[k]).length_squared().max(1e-30)
        })
}

/// The light polygon of a planar cluster: hull, simplified to <= 8 vertices, grown by
/// `1.5 sqrt(A_hull / n)`, clipped to the cell. A hull of fewer than 3 points (one VPL, or all
/// on a line) becomes a square of the cell's share per VPL around them.
pub fn light_polygon(points: &[Vec2], cell_lo: Vec2, cell_hi: Vec2) -> Vec<Vec2> {
    let n = points.len().max(1) as f32;
    let hull = convex_hull(points);
    let hull_area = if hull.len() >= 3 { area(&hull) } else { 0.0 };
    let grown = if hull.len() >= 3 && hull_area > 0.0 {
        grow(&simplify_outer(&hull, 8), 1.5 * (hull_area / n).sqrt())
    } else {
        let cell = (cell_hi - cell_lo).max(Vec2::ZERO);
        let b = 0.5 * (cell.x * cell.y / n).sqrt().max(1e-6);
        let (lo, hi) =
            points.iter().fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(l, h), p| (l.min(*p), h.max(*p)));
        let (lo, hi) = (lo - Vec2::splat(b), hi + Vec2::splat(b));
        vec![lo, Vec2::new(hi.x, lo.y), hi, Vec2::new(lo.x, hi.y)]
    };
    clip_to_rect(&grown, cell_lo, cell_hi)
}
