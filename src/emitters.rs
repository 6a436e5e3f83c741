//! Emissive surfaces as polygon area lights for the bakers (paper 001 §3.2).
//!
//! A glTF emissive surface is a mesh: a ceiling panel is two triangles, a light strip or a
//! window tens. One light a triangle would multiply the bakers' shadow rays and entries by the
//! triangle count for the same light, so triangles that share an edge, a node, a material and
//! a plane are merged into convex polygons first. A flat piece whose corners' convex hull has
//! its triangles' area (a quad, a grid, a disc, a strip) is that hull; any other piece (an L,
//! a ring) is cut into convex parts greedily: in triangle order, a triangle joins a polygon
//! across a shared edge while the union stays flat and convex (at most [`MAX_CORNERS`]
//! corners). Every light passes the bakers' own check of a polygon light
//! ([`crate::light::Light::check`]); a merged polygon that would not (a piece bent by more
//! than its tolerance) is given back as its triangles, and a triangle that would not (a sliver
//! without area) gives no light. The union of the triangles is the same surface, so the
//! lights' unshadowed irradiance is the same to round-off (Lambert's contour integral is
//! additive), and each light is then split back into parts for its shadow rays
//! ([`crate::light::aperture_parts`]) by its own extent, not by how it was modelled.
//!
//! Edges are matched by their corners' exact positions (vertex bits), so a mesh whose faces
//! repeat their vertices (flat-shaded exports) merges as one with shared vertices would. A
//! light's corners are always corners of its triangles, which is how an edited level finds
//! the lights of a node that moved.

use std::collections::HashMap;

use glam::Vec3;

use crate::light::Light;
use crate::scene::Scene;

/// Corners a merged polygon keeps at most (the bakers' polygon lights take up to 64).
pub const MAX_CORNERS: usize = 32;

/// One emissive polygon light and the triangles it was merged from.
#[derive(Clone, Debug)]
pub struct Emitter {
    /// A convex polygon light of the material's radiance.
    pub light: Light,
    /// Its triangles, ascending; the light is named after the first.
    pub triangles: Vec<u32>,
}

/// The emissive triangles `keep` picks, merged into polygon lights of the material's radiance,
/// named `emissive <first triangle>` (and a `... back` light wound the other way for a
/// double-sided material). Triangles without area (by [`Light::check`]'s measure) give none.
/// Deterministic: the same scene gives the same lights in the same order.
pub fn emitters(scene: &Scene, keep: impl Fn(usize) -> bool) -> Vec<Emitter> {
    let glowing = |t: usize| {
        keep(t)
            && scene.material(t).emissive != Vec3::ZERO
            && crate::light::check_polygon(&scene.corners(t)).is_ok()
    };
    let key = |p: Vec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    // Each glowing triangle's directed edges (counter-clockwise from its front).
    let mut edges: HashMap<([u32; 3], [u32; 3]), usize> = HashMap::new();
    for t in (0..scene.triangles.len()).filter(|&t| glowing(t)) {
        let c = scene.corners(t);
        for k in 0..3 {
            edges.entry((key(c[k]), key(c[(k + 1) % 3]))).or_insert(t);
        }
    }
    // The neighbour across a triangle's edge a -> b runs it b -> a, on the same node and
    // material, facing the same way (so in the same plane: the edge lies in both).
    let neighbour = |t: usize, a: Vec3, b: Vec3| -> Option<usize> {
        let &u = edges.get(&(key(b), key(a)))?;
        let (x, y) = (&scene.triangles[t], &scene.triangles[u]);
        (x.node == y.node
            && x.material == y.material
            && scene.face_normal(u).dot(scene.face_normal(t)) >= 1.0 - 1e-6)
            .then_some(u)
    };
    let mut used = vec![false; scene.triangles.len()];
    let mut out = Vec::new();
    for t in 0..scene.triangles.len() {
        if used[t] || !glowing(t) {
            continue;
        }
        // The flat piece of surface around t: its triangles joined edge to edge.
        let mut piece = vec![t];
        used[t] = true;
        let mut k = 0;
        while k < piece.len() {
            let c = scene.corners(piece[k]);
            for e in 0..3 {
                if let Some(u) = neighbour(piece[k], c[e], c[(e + 1) % 3]) {
                    if !used[u] {
                        used[u] = true;
                        piece.push(u);
                    }
                }
            }
            k += 1;
        }
        piece.sort_unstable();
        let normal = scene.face_normal(t);
        let m = scene.material(t);
        // A convex piece is its vertices' hull (the hull's area is the triangles'); else
        // convex parts of it, grown greedily.
        let polygons = match convex_outline(scene, &piece, normal) {
            Some(hull) => vec![(hull, piece.iter().map(|&t| t as u32).collect::<Vec<u32>>())],
            None => grow(scene, &piece, normal, &neighbour),
        };
        // A polygon the bakers would refuse goes back to its triangles (each passed the check).
        let polygons = polygons.into_iter().flat_map(|(poly, members)| {
            if crate::light::check_polygon(&poly).is_ok() {
                vec![(poly, members)]
            } else {
                members.iter().map(|&t| (scene.corners(t as usize).to_vec(), vec![t])).collect()
            }
        });
        for (poly, members) in polygons {
            let first = members[0];
            out.push(Emitter {
                light: Light::polygon(&format!("emissive {first}"), &poly, m.emissive),
                triangles: members.clone(),
            });
            if m.double_sided {
                let back: Vec<Vec3> = poly.iter().rev().copied().collect();
                out.push(Emitter {
                    light: Light::polygon(&format!("emissive {first} back"), &back, m.emissive),
                    triangles: members,
                });
            }
        }
    }
    out
}

/// The convex hull of the piece's corners (counter-clockwise about `normal`, without straight
/// corners) when it is the piece itself: its area that of the triangles, to 1e-5, and at most
/// [`MAX_CORNERS`] corners.
fn convex_outline(scene: &Scene, piece: &[usize], normal: Vec3) -> Option<Vec<Vec3>> {
    let (t_axis, b_axis) = normal.any_orthonormal_pair();
    let mut pts: Vec<Vec3> = piece.iter().flat_map(|&t| scene.corners(t)).collect();
    let flat = |p: Vec3| (p.dot(t_axis), p.dot(b_axis));
    pts.sort_by(|a, b| flat(*a).partial_cmp(&flat(*b)).unwrap_or(std::cmp::Ordering::Equal));
    pts.dedup_by(|a, b| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits));
    let s2 = size2(&pts);
    // Andrew's monotone chain; a turn not clearly to the left is dropped (straight corners).
    let left = |o: Vec3, a: Vec3, b: Vec3| (a - o).cross(b - a).dot(normal) > 1e-7 * s2;
    let mut hull: Vec<Vec3> = Vec::with_capacity(pts.len() + 1);
    for pass in 0..2 {
        let start = hull.len();
        let order: Box<dyn Iterator<Item = &Vec3>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in order {
            while hull.len() >= start + 2 && !left(hull[hull.len() - 2], hull[hull.len() - 1], p) {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    if crate::light::polygon_twice_area(&hull).dot(normal) < 0.0 {
        hull.reverse();
    }
    let area: f64 = piece.iter().map(|&t| scene.area(t) as f64).sum();
    let hull_area = 0.5 * crate::light::polygon_twice_area(&hull).length() as f64;
    (hull.len() >= 3 && hull.len() <= MAX_CORNERS && (hull_area - area).abs() <= 1e-5 * area).then_some(hull)
}

/// A piece that is not convex as convex polygons: in triangle order, a triangle grows across
/// its polygon's edges while the union stays flat and convex.
fn grow(
    scene: &Scene,
    piece: &[usize],
    normal: Vec3,
    neighbour: &impl Fn(usize, Vec3, Vec3) -> Option<usize>,
) -> Vec<(Vec<Vec3>, Vec<u32>)> {
    let key = |p: Vec3| p.to_array().map(f32::to_bits);
    let mut used: std::collections::HashSet<usize> = std::collections::HashSet::new();
    let mut out = Vec::new();
    for &t in piece {
        if !used.insert(t) {
            continue;
        }
        let mut poly: Vec<Vec3> = scene.corners(t).to_vec();
        let mut members = vec![t as u32];
        let mut grown = true;
        while grown {
            grown = false;
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                // The neighbour of any member across this edge of the polygon.
                let Some(u) = members.iter().find_map(|&m| neighbour(m as usize, a, b)) else { continue };
                // Of this piece only (a mesh that repeats a directed edge could offer another's).
                if used.contains(&u) || piece.binary_search(&u).is_err() {
                    continue;
                }
                let c = scene.corners(u);
                let Some(far) = c.into_iter().find(|q| key(*q) != key(a) && key(*q) != key(b)) else {
                    continue;
                };
                let mut wider = poly.clone();
                wider.insert(i + 1, far);
                if wider.len() <= MAX_CORNERS && flat_and_convex(&wider, normal) {
                    poly = wider;
                    used.insert(u);
                    members.push(u as u32);
                    grown = true;
                    break;
                }
            }
        }
        members.sort_unstable();
        out.push((without_straight_corners(&poly, normal), members));
    }
    out
}

/// The polygon's size squared: the scale of its tolerances.
fn size2(poly: &[Vec3]) -> f32 {
    poly.iter().map(|c| (*c - poly[0]).length_squared()).fold(0.0, f32::max)
}

/// Whether `poly` (counter-clockwise about `normal`) lies in one plane and turns left or goes
/// straight at every corner, with tolerances well inside the bakers' own check of a polygon
/// light.
fn flat_and_convex(poly: &[Vec3], normal: Vec3) -> bool {
    let s2 = size2(poly);
    let n = poly.len();
    (0..n).all(|k| {
        let (a, b, c) = (poly[k], poly[(k + 1) % n], poly[(k + 2) % n]);
        (b - poly[0]).dot(normal).abs() <= 1e-5 * s2.sqrt() && (b - a).cross(c - b).dot(normal) >= -1e-7 * s2
    })
}

/// `poly` without the corners where it goes straight on (a merged grid's edge midpoints).
fn without_straight_corners(poly: &[Vec3], normal: Vec3) -> Vec<Vec3> {
    let s2 = size2(poly);
    let n = poly.len();
    (0..n)
        .filter(|&k| {
            let (a, b, c) = (poly[(k + n - 1) % n], poly[k], poly[(k + 1) % n]);
            (b - a).cross(c - b).dot(normal) > 1e-7 * s2
        })
        .map(|k| poly[k])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light::{polygon_twice_area, Aperture};
    use crate::scene::Material;
    use glam::Vec2;

    /// A scene of quads in the y = 0 plane facing up, each two triangles; `shared`: quads that
    /// meet share their vertices, else every triangle has its own (a flat-shaded export).
    /// All glow (radiance 2) with material 1; `cells` are (x, z) unit squares.
    fn tiles(cells: &[(i32, i32)], shared: bool) -> Scene {
        let mut positions: Vec<Vec3> = Vec::new();
        let mut indices = Vec::new();
        let mut at = HashMap::new();
        let mut vertex = |p: Vec3, positions: &mut Vec<Vec3>| -> u32 {
            if !shared {
                positions.push(p);
                return positions.len() as u32 - 1;
            }
            *at.entry(p.to_array().map(f32::to_bits)).or_insert_with(|| {
                positions.push(p);
                positions.len() as u32 - 1
            })
        };
        for &(x, z) in cells {
            let c = |dx: i32, dz: i32| Vec3::new((x + dx) as f32 * 0.5, 0.0, (z + dz) as f32 * 0.5);
            // Counter-clockwise seen from above (+Y): (0,0) -> (0,1) -> (1,1) in (x, z).
            for tri in [[c(0, 0), c(0, 1), c(1, 1)], [c(0, 0), c(1, 1), c(1, 0)]] {
                for p in tri {
                    let i = vertex(p, &mut positions);
                    indices.push(i);
                }
            }
        }
        let n = positions.len();
        let mut s = Scene::from_mesh(positions, vec![Vec2::ZERO; n], &indices);
        s.materials.push(Material { emissive: Vec3::splat(2.0), ..Default::default() });
        for t in &mut s.triangles {
            t.material = 1;
        }
        s
    }

    fn corners(l: &Light) -> &[Vec3] {
        match &l.aperture {
            Aperture::Polygon { corners } => corners,
            _ => panic!("not a polygon"),
        }
    }

    /// Power over all lights (pi L A per light): merging keeps the surface, so the same.
    fn power(ls: &[Emitter]) -> f32 {
        ls.iter().map(|e| e.light.flux().x).sum()
    }

    #[test]
    fn a_grid_of_glowing_quads_is_one_light() {
        let grid: Vec<(i32, i32)> = (0..3).flat_map(|x| (0..4).map(move |z| (x, z))).collect();
        for shared in [true, false] {
            let s = tiles(&grid, shared);
            let es = emitters(&s, |_| true);
            assert_eq!(es.len(), 1, "24 triangles, one rectangle (shared vertices: {shared})");
            let l = &es[0].light;
            l.check().unwrap();
            assert_eq!(corners(l).len(), 4, "edge midpoints dropped: {:?}", corners(l));
            assert!((l.direction - Vec3::Y).length() < 1e-6);
            assert_eq!(es[0].triangles, (0..24).collect::<Vec<u32>>());
            let want = std::f32::consts::PI * 2.0 * (1.5 * 2.0);
            assert!((power(&es) - want).abs() < 1e-5 * want, "{} vs {want}", power(&es));
            assert_eq!(l.name, "emissive 0");
        }
    }

    /// The greedy cut of the L below (a square and a trapezoid).
    const L_PIECES: usize = 2;

    #[test]
    fn an_l_shape_stays_convex_pieces_covering_it() {
        // Three cells in an L: no convex polygon holds all six triangles.
        let s = tiles(&[(0, 0), (1, 0), (0, 1)], true);
        let es = emitters(&s, |_| true);
        assert_eq!(es.len(), L_PIECES, "{es:?}");
        let mut all: Vec<u32> = es.iter().flat_map(|e| e.triangles.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..6).collect::<Vec<u32>>(), "every triangle in exactly one light");
        for e in &es {
            e.light.check().unwrap();
            let area: f32 = e.triangles.iter().map(|&t| s.area(t as usize)).sum();
            let got = 0.5 * polygon_twice_area(corners(&e.light)).length();
            assert!((got - area).abs() < 1e-6, "a light is its triangles' surface: {got} vs {area}");
        }
        assert!((power(&es) - std::f32::consts::PI * 2.0 * 0.75).abs() < 1e-5);
    }

    #[test]
    fn lights_split_by_node_material_plane_and_side() {
        let grid = [(0, 0), (1, 0)];
        // Another node.
        let mut s = tiles(&grid, true);
        s.triangles[2].node = 1;
        s.triangles[3].node = 1;
        assert_eq!(emitters(&s, |_| true).len(), 2);
        assert_eq!(emitters(&s, |t| s.triangles[t].node == 1)[0].triangles, vec![2, 3], "the node's own");
        // Another material of the same radiance.
        let mut s = tiles(&grid, true);
        s.materials.push(s.materials[1].clone());
        s.triangles[3].material = 2;
        assert_eq!(emitters(&s, |_| true).len(), 2);
        // Folded: the second cell tilted up about the shared edge.
        let mut s = tiles(&grid, true);
        for p in &mut s.positions {
            if p.x > 0.75 {
                p.y = 0.1;
            }
        }
        let es = emitters(&s, |_| true);
        assert_eq!(es.len(), 2, "not one plane");
        es.iter().for_each(|e| e.light.check().unwrap());
        // Double-sided: a back light wound the other way, same triangles.
        let mut s = tiles(&grid, true);
        s.materials[1].double_sided = true;
        let es = emitters(&s, |_| true);
        assert_eq!(es.len(), 2);
        assert_eq!(es[1].light.name, "emissive 0 back");
        assert!((es[1].light.direction + Vec3::Y).length() < 1e-6);
        assert_eq!(es[0].triangles, es[1].triangles);
        // Dark or without area: none.
        let mut s = tiles(&grid, true);
        s.materials[1].emissive = Vec3::ZERO;
        assert!(emitters(&s, |_| true).is_empty());
    }

    /// A disc of 40 fan triangles has a hull of 40 corners, over [`MAX_CORNERS`]: it is cut
    /// into convex polygons of at most that many, covering every triangle once.
    #[test]
    fn a_disc_over_the_corner_limit_is_cut_into_convex_parts() {
        let k = 40;
        let mut positions = vec![Vec3::ZERO];
        positions.extend((0..k).map(|i| {
            let a = std::f32::consts::TAU * i as f32 / k as f32;
            Vec3::new(a.cos(), 0.0, -a.sin())
        }));
        // Counter-clockwise seen from above: centre, then i, then i + 1 going round.
        let indices: Vec<u32> = (0..k).flat_map(|i| [0, 1 + i, 1 + (i + 1) % k]).collect();
        let n = positions.len();
        let mut s = Scene::from_mesh(positions, vec![Vec2::ZERO; n], &indices);
        assert!(s.face_normal(0).y > 0.99);
        s.materials.push(Material { emissive: Vec3::ONE, ..Default::default() });
        s.triangles.iter_mut().for_each(|t| t.material = 1);
        let es = emitters(&s, |_| true);
        assert!(es.len() >= 2 && es.len() < k as usize, "{} lights", es.len());
        let mut all: Vec<u32> = es.iter().flat_map(|e| e.triangles.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..k).collect::<Vec<u32>>());
        for e in &es {
            e.light.check().unwrap();
            assert!(corners(&e.light).len() <= MAX_CORNERS);
        }
        let area: f32 = (0..k as usize).map(|t| s.area(t)).sum();
        assert!((power(&es) - std::f32::consts::PI * area).abs() < 1e-5 * area);
    }

    /// A piece bent by more than a polygon light may be (within the neighbour test's 1e-6 of
    /// the normals' dot, beyond `Light::check`'s 1e-4 of its size off the plane) goes back to
    /// its triangles; a sliver without area gives no light; every light passes the check.
    #[test]
    fn what_the_bakers_would_refuse_is_not_merged() {
        // Two cells; one far corner lifted so the second cell's triangles tilt by about 1e-3.
        let mut s = tiles(&[(0, 0), (1, 0)], true);
        for p in &mut s.positions {
            if p.x == 1.0 && p.z == 0.5 {
                p.y = 7e-4;
            }
        }
        let es = emitters(&s, |_| true);
        for e in &es {
            e.light.check().unwrap();
        }
        let mut all: Vec<u32> = es.iter().flat_map(|e| e.triangles.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, vec![0, 1, 2, 3], "{es:?}");
        // The flat cell and the tilted triangle next to it pass the neighbour test, but their
        // hull is off its plane by more than the check allows: four triangles, four lights.
        assert_eq!(es.len(), 4, "{es:?}");
        // A sliver: its third corner 1e-12 off the line of the other two (a face normal, no
        // area by the check's 1e-10 of its size squared).
        let positions = vec![Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.5, 0.0, 1e-12)];
        let mut s = Scene::from_mesh(positions, vec![Vec2::ZERO; 3], &[0, 1, 2]);
        s.materials.push(Material { emissive: Vec3::ONE, ..Default::default() });
        s.triangles[0].material = 1;
        assert_ne!(s.face_normal(0), Vec3::ZERO);
        assert!(emitters(&s, |_| true).is_empty());
    }
}
