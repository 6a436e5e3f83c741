//! Spatial zones for generated lightmap UVs (issue 13, spatial locality).
//!
//! uvunwrap packs charts by size, so without help the charts of one room end up scattered
//! over the whole atlas, and a pane (the light one cluster of entries brings, mostly to its own
//! room) touches tiles everywhere. Here the level is cut into zones of at most
//! [`ZONE_AREA`] square metres of surface, and each zone is unwrapped as one mesh packed into
//! its own rectangle of the atlas (uvunwrap's single-instance meshes), so the geometry of a
//! zone stays together in the atlas.
//!
//! Zones are made of patches: triangles joined across shared edges (equal endpoint positions)
//! and lying in one plane, so a flat quad is never cut along its diagonal. Patches are first
//! parted by the room they face into ([`crate::rooms`]: most of the patch's area), so no zone
//! holds both sides of a wall between two rooms, and zones are numbered room after room (in
//! the order of the rooms' first patches). Each room's patches are then split by a k-d tree:
//! along the longest axis of their centroids, at the widest gap between centroids within the
//! middle half of the area, until a zone's area is at most [`ZONE_AREA`] or it is a single
//! patch.

use glam::Vec3;

/// Largest surface area of a zone, in square metres (before a split; a single patch may be
/// larger): about a third of one of the bundled halls, two dozen pane tiles at 0.18 m texels.
pub const ZONE_AREA: f64 = 300.0;

/// Cosine of the largest angle between two triangles' normals for them to join a patch.
const COPLANAR: f32 = 0.9998;

/// One triangle of the level: its corner positions.
pub type Corners = [Vec3; 3];

/// Zone index per triangle (dense, from 0), for triangles given as corner positions.
pub fn zones(triangles: &[Corners], max_area: f64) -> Vec<u32> {
    zones_in_rooms(triangles, max_area).0
}

/// [`zones`], and per zone the room its patches face into (dense, from 0, in the zones'
/// order: the zones of a room are consecutive).
pub fn zones_in_rooms(triangles: &[Corners], max_area: f64) -> (Vec<u32>, Vec<u32>) {
    let patch = patches(triangles);
    let count = patch.iter().map(|&p| p as usize + 1).max().unwrap_or(0);
    let mut area = vec![0.0f64; count];
    let mut centroid = vec![glam::DVec3::ZERO; count];
    for (t, c) in triangles.iter().enumerate() {
        let a = tri_area(c);
        let p = patch[t] as usize;
        area[p] += a;
        centroid[p] += ((c[0] + c[1] + c[2]) / 3.0).as_dvec3() * a;
    }
    let patches: Vec<Patch> = (0..count)
        .map(|p| Patch {
            id: p,
            area: area[p],
            centroid: if area[p] > 0.0 { centroid[p] / area[p] } else { glam::DVec3::ZERO },
        })
        .collect();
    let room_of = patch_rooms(triangles, &patch, &patches);
    let mut slot = std::collections::HashMap::new();
    let mut by_room: Vec<Vec<Patch>> = Vec::new();
    for (p, patch) in patches.into_iter().enumerate() {
        let k = *slot.entry(room_of[p]).or_insert_with(|| {
            by_room.push(Vec::new());
            by_room.len() - 1
        });
        by_room[k].push(patch);
    }
    let mut zone_of_patch = vec![0u32; count];
    let mut next = 0u32;
    let mut room_of_zone = Vec::new();
    for (r, set) in by_room.into_iter().enumerate() {
        split(set, max_area, &mut zone_of_patch, &mut next);
        room_of_zone.resize(next as usize, r as u32);
    }
    (patch.iter().map(|&p| zone_of_patch[p as usize]).collect(), room_of_zone)
}

/// Each patch's room (`crate::rooms`): the one most of its area faces into. A patch with no
/// free voxel in front of it (a face of a small solid, wound the other way, or in a gap
/// narrower than a voxel) or facing into a room of under 1 % of the largest's surface (the
/// inside of a hollow object) takes the room of the nearest patch in a larger room: left as
/// they are, such patches from every room would share zones.
fn patch_rooms(triangles: &[Corners], patch: &[u32], patches: &[Patch]) -> Vec<u32> {
    let count = patches.len();
    let rooms = crate::rooms::Rooms::new(triangles);
    let mut facing: Vec<Vec<(u32, f64)>> = vec![Vec::new(); count];
    for (t, c) in triangles.iter().enumerate() {
        let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero();
        if let Some(r) = rooms.room_of((c[0] + c[1] + c[2]) / 3.0, n) {
            let f = &mut facing[patch[t] as usize];
            match f.iter_mut().find(|(q, _)| *q == r) {
                Some(e) => e.1 += tri_area(c),
                None => f.push((r, tri_area(c))),
            }
        }
    }
    let mut room_of: Vec<u32> = facing
        .iter()
        .map(|f| f.iter().fold((u32::MAX, -1.0), |b, &(r, a)| if a > b.1 { (r, a) } else { b }).0)
        .collect();
    let mut room_area: std::collections::HashMap<u32, f64> = std::collections::HashMap::new();
    for (p, &r) in room_of.iter().enumerate() {
        *room_area.entry(r).or_default() += patches[p].area;
    }
    room_area.remove(&u32::MAX);
    let largest = room_area.values().fold(0.0f64, |a, &b| a.max(b));
    let settled = |r: u32| room_area.get(&r).is_some_and(|&a| a >= 0.01 * largest);
    let anchors: Vec<usize> = (0..count).filter(|&p| settled(room_of[p])).collect();
    if !anchors.is_empty() {
        let moved: Vec<(usize, u32)> = (0..count)
            .filter(|&p| !settled(room_of[p]))
            .map(|p| {
                let c = patches[p].centroid;
                let near = anchors.iter().min_by(|&&a, &&b| {
                    c.distance_squared(patches[a].centroid)
                        .total_cmp(&c.distance_squared(patches[b].centroid))
                });
                (p, near.map_or(u32::MAX, |&a| room_of[a]))
            })
            .collect();
        for (p, r) in moved {
            room_of[p] = r;
        }
    }
    room_of
}

struct Patch {
    id: usize,
    area: f64,
    centroid: glam::DVec3,
}

fn tri_area(c: &Corners) -> f64 {
    0.5 * (c[1] - c[0]).cross(c[2] - c[0]).length() as f64
}

/// Give `set` zone numbers from `next` on: one zone if it is small enough, else both halves.
fn split(mut set: Vec<Patch>, max_area: f64, zone_of_patch: &mut [u32], next: &mut u32) {
    let total: f64 = set.iter().map(|p| p.area).sum();
    if set.len() <= 1 || total <= max_area {
        for p in &set {
            zone_of_patch[p.id] = *next;
        }
        *next += 1;
        return;
    }
    let (lo, hi) = set.iter().fold((glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(p.centroid), hi.max(p.centroid))
    });
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    set.sort_by(|a, b| a.centroid[axis].total_cmp(&b.centroid[axis]).then(a.id.cmp(&b.id)));
    // Cut where the centroids leave the widest gap within the middle half of the area (a wall
    // or a corridor between rooms, rather than through one), nearest the median on ties.
    let mut before = 0.0;
    let mut best: Option<(f64, f64, usize)> = None;
    for k in 1..set.len() {
        before += set[k - 1].area;
        if before < 0.25 * total || before > 0.75 * total {
            continue;
        }
        let gap = set[k].centroid[axis] - set[k - 1].centroid[axis];
        let off = (before - 0.5 * total).abs();
        if best.is_none_or(|(g, o, _)| gap > g || (gap == g && off < o)) {
            best = Some((gap, off, k));
        }
    }
    let cut = match best {
        Some((_, _, k)) => k,
        // One patch holds the middle: cut just past it.
        None => {
            let mut acc = 0.0;
            let k = set.iter().position(|p| {
                acc += p.area;
                acc >= 0.5 * total
            });
            (k.unwrap_or(0) + 1).clamp(1, set.len() - 1)
        }
    };
    let upper = set.split_off(cut);
    split(set, max_area, zone_of_patch, next);
    split(upper, max_area, zone_of_patch, next);
}

/// Patch index per triangle (dense, in order of first triangle): coplanar triangles sharing an
/// edge, by endpoint positions, are one patch.
fn patches(triangles: &[Corners]) -> Vec<u32> {
    let normal: Vec<Vec3> =
        triangles.iter().map(|c| (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero()).collect();
    let key = |v: Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
    crate::uv::edge_components(
        triangles.len(),
        |t| triangles[t].map(key),
        |t, other| normal[t].dot(normal[other]) >= COPLANAR,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A w x d floor of unit quads at height 0, two triangles each.
    fn floor(w: usize, d: usize) -> Vec<Corners> {
        let mut t = Vec::new();
        for j in 0..d {
            for i in 0..w {
                let p = |x: usize, z: usize| Vec3::new(x as f32, 0.0, z as f32);
                t.push([p(i, j), p(i, j + 1), p(i + 1, j + 1)]);
                t.push([p(i, j), p(i + 1, j + 1), p(i + 1, j)]);
            }
        }
        t
    }

    #[test]
    fn a_flat_floor_is_one_patch_and_a_small_level_one_zone() {
        let t = floor(4, 4);
        assert!(patches(&t).iter().all(|&p| p == 0));
        assert!(zones(&t, 100.0).iter().all(|&z| z == 0));
    }

    /// Two closed rooms a metre apart, cut into zones much smaller than a room: no zone holds
    /// faces of both, and the first room's zones come first.
    #[test]
    fn no_zone_holds_both_sides_of_a_wall() {
        use crate::rooms::tests::closed_box;
        let a = closed_box(Vec3::ZERO, Vec3::new(6.0, 3.0, 8.0), 0.0);
        let b = closed_box(Vec3::new(7.0, 0.0, 0.0), Vec3::new(13.0, 3.0, 8.0), 0.0);
        let n = a.len();
        let (z, rooms) = zones_in_rooms(&[a, b].concat(), 20.0);
        let last_a = *z[..n].iter().max().unwrap();
        let first_b = *z[n..].iter().min().unwrap();
        assert!(last_a < first_b, "zones {last_a} and {first_b}");
        assert_eq!(rooms.len(), *z.iter().max().unwrap() as usize + 1);
        assert!(
            rooms[..=last_a as usize].iter().all(|&r| r == 0)
                && rooms[first_b as usize..].iter().all(|&r| r == 1)
        );
        assert!(last_a >= 4, "a room cut into several zones: {}", last_a + 1);
    }

    #[test]
    fn separate_rooms_get_separate_zones_of_bounded_area() {
        // Two 10 x 10 floors of separate quads (a gap between every quad: no shared edges),
        // 50 m apart: zones of at most 30 m^2 never mix the rooms.
        let mut t = Vec::new();
        for room in 0..2 {
            for q in floor(10, 10).chunks(2) {
                for tri in q {
                    let shift = Vec3::new(room as f32 * 50.0, 0.0, 0.0);
                    // Shrink each quad a little about its centre so quads share no edge.
                    let c = (q[0][0] + q[0][2]) * 0.5;
                    t.push(tri.map(|v| c + (v - c) * 0.9 + shift));
                }
            }
        }
        let z = zones(&t, 30.0);
        let count = *z.iter().max().unwrap() as usize + 1;
        let mut area = vec![0.0; count];
        let mut room_of = vec![None; count];
        for (k, c) in t.iter().enumerate() {
            area[z[k] as usize] += tri_area(c);
            let room = (c[0].x > 25.0) as u32;
            let seen = room_of[z[k] as usize].get_or_insert(room);
            assert_eq!(*seen, room, "zone {} mixes rooms", z[k]);
        }
        assert!(area.iter().all(|&a| a <= 30.0 + 1e-3), "{area:?}");
        // Each quad's two triangles stay together.
        for q in z.chunks(2) {
            assert_eq!(q[0], q[1]);
        }
    }
}
