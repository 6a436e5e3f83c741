//! Entry cells and their owners (`prm_precompute::cells`): on the bundled levels the cells tile
//! the surface, each entry inside its own cell, every cell facing its entry's way; the owner of
//! a point is the entry whose cell holds it; a triangle without an entry joins a cell of its
//! own surface, never one of a parallel surface beside it.

use std::path::PathBuf;

use glam::Vec3;
use prm::{load_scene, LoadOptions, Scene};
use prm_precompute::cells::{entry_cells, entry_cells_in_rooms, entry_rooms};
use prm_precompute::entries::sample_entries;

mod common;
use common::{quads, unit_box_faces, v};

fn level(name: &str) -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets").join(name);
    load_scene(path, &LoadOptions::default()).unwrap()
}

/// Whether `p` lies in triangle `t` (within `eps` of its plane, barycentrics >= -1e-3).
fn inside(t: &[Vec3; 3], p: Vec3, eps: f32) -> bool {
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let area2 = n.length_squared();
    if !(area2 > 0.0) || n.normalize().dot(p - t[0]).abs() > eps {
        return false;
    }
    let b = |a: Vec3, c: Vec3| (c - a).cross(p - a).dot(n) / area2;
    [b(t[0], t[1]), b(t[1], t[2]), b(t[2], t[0])].iter().all(|&x| x >= -1e-3)
}

#[test]
fn cells_tile_the_levels_and_hold_their_entries() {
    for name in ["cornell.glb", "chamber.glb", "two_rooms.glb"] {
        let scene = level(name);
        let entries = sample_entries(&scene, 2048, 1);
        let total = scene.total_area();
        // All kept, and every fifth dropped as if enclosed: the kept ones share out its surface.
        for keep in [vec![true; entries.len()], (0..entries.len()).map(|j| j % 5 != 0).collect::<Vec<_>>()] {
            let (cells, _, report) = entry_cells(&scene, &entries, &keep);
            let kept: Vec<usize> = (0..entries.len()).filter(|&j| keep[j]).collect();
            assert_eq!(cells.first.len(), kept.len() + 1, "{name}");
            let covered: f64 = (0..kept.len()).map(|k| cells.area(k) as f64).sum();
            // The cells and the triangles no entry took add up to the level (f32 corners: 1e-4).
            let sum = covered + report.area_without_entry;
            assert!(
                (sum / total - 1.0).abs() < 1e-4,
                "{name}: cells {covered} + left {} vs {total}",
                report.area_without_entry
            );
            // Small details no entry of their own surface reaches (a plinth side with none) are
            // left out and reported: 0.2 % of the chamber at 2048 entries.
            assert!(
                report.area_without_entry < 5e-3 * total,
                "{name}: {} of {total} left out",
                report.area_without_entry
            );
            for (k, &j) in kept.iter().enumerate() {
                let (cell, e) = (cells.of(k), &entries[j]);
                assert!(!cell.is_empty(), "{name}: entry {j} has no cell");
                // Counter-clockwise from the front: every piece faces the entry's way.
                for t in cell {
                    let n = (t[1] - t[0]).cross(t[2] - t[0]);
                    assert!(n.dot(e.normal) >= 0.0, "{name}: entry {j}: a cell piece faces away");
                }
                // The entry is the fan's apex: it lies in its cell.
                assert!(cell.iter().any(|t| t[0] == e.position), "{name}: entry {j} is not in its cell");
            }
        }
    }
}

/// The gather credits a walk's hit to `CellOwners::owner`: it must name the entry whose cell
/// holds the point, on every triangle (grid search or not), with entries dropped.
#[test]
fn owners_are_the_cells_holding_the_points() {
    for name in ["cornell.glb", "chamber.glb", "two_rooms.glb"] {
        let scene = level(name);
        let entries = sample_entries(&scene, 2048, 2);
        let keep: Vec<bool> = (0..entries.len()).map(|j| j % 7 != 3).collect();
        let (cells, owners, _) = entry_cells(&scene, &entries, &keep);
        let eps = 1e-5 * scene.diagonal();
        let (mut owned, mut points) = (0, 0);
        for t in 0..scene.triangles.len() {
            let c = scene.corners(t);
            for b in [Vec3::new(0.2, 0.3, 0.5), Vec3::new(0.7, 0.2, 0.1), Vec3::new(0.1, 0.8, 0.1)] {
                let p = c[0] * b.x + c[1] * b.y + c[2] * b.z;
                points += 1;
                if let Some(k) = owners.owner(t, p) {
                    owned += 1;
                    assert!(
                        cells.of(k as usize).iter().any(|piece| inside(piece, p, eps)),
                        "{name}: triangle {t}: {p} is owned by kept entry {k}, whose cell does not hold it"
                    );
                }
            }
        }
        assert!(owned as f64 >= 0.995 * points as f64, "{name}: {owned} of {points} points owned");
    }
}

/// A floor with a plinth 35 cm high on it, whose 40 x 40 cm top is cut into eight triangles
/// and gets (at 1200 entries over 400 m², 58 cm apart) one entry or none: the top's triangles
/// never join a floor entry's cell, though floor entries stand within a spacing of them (the
/// rule before joined by nearness in space alone, and a lamp lighting the floor lit the top).
#[test]
fn a_plinth_top_joins_no_floor_cell() {
    let (lo, hi, h) = (-0.2f32, 0.2f32, 0.35f32);
    let mut faces = vec![[v(-10., 0., -10.), v(-10., 0., 10.), v(10., 0., 10.), v(10., 0., -10.)]];
    for (x0, x1) in [(lo, 0.0), (0.0, hi)] {
        for (z0, z1) in [(lo, 0.0), (0.0, hi)] {
            faces.push([v(x0, h, z0), v(x0, h, z1), v(x1, h, z1), v(x1, h, z0)]);
        }
    }
    faces.push([v(lo, 0., lo), v(lo, h, lo), v(hi, h, lo), v(hi, 0., lo)]);
    faces.push([v(hi, 0., hi), v(hi, h, hi), v(lo, h, hi), v(lo, 0., hi)]);
    faces.push([v(lo, 0., hi), v(lo, h, hi), v(lo, h, lo), v(lo, 0., lo)]);
    faces.push([v(hi, 0., lo), v(hi, h, lo), v(hi, h, hi), v(hi, 0., hi)]);
    let scene = quads(&faces, 0.7);
    let top_area = (hi - lo) * (hi - lo);
    let mut without = 0;
    for seed in 0..16 {
        let entries = sample_entries(&scene, 1200, seed);
        let (cells, owners, report) = entry_cells(&scene, &entries, &vec![true; entries.len()]);
        let on_top = |p: Vec3| (p.y - h).abs() < 1e-4;
        let top_entries = entries.iter().filter(|e| on_top(e.position)).count();
        for (j, e) in entries.iter().enumerate() {
            for piece in cells.of(j) {
                let top_piece = piece.iter().all(|&q| on_top(q));
                assert!(
                    !top_piece || on_top(e.position),
                    "seed {seed}: entry {j} at {} took top area",
                    e.position
                );
            }
        }
        for t in 0..scene.triangles.len() {
            let c = scene.corners(t);
            if c.iter().all(|&q| on_top(q)) {
                let owner = owners.owner(t, (c[0] + c[1] + c[2]) / 3.0);
                assert!(
                    owner.is_none_or(|k| on_top(entries[k as usize].position)),
                    "seed {seed}: top triangle {t}"
                );
                // With an entry of its own, the whole top is that entry's (joined across edges).
                assert_eq!(owner.is_some(), top_entries > 0, "seed {seed}: top triangle {t}");
            }
        }
        if top_entries == 0 {
            without += 1;
            assert!(
                report.area_without_entry as f32 >= top_area - 1e-4,
                "seed {seed}: {}",
                report.area_without_entry
            );
        }
    }
    // Both cases were tried.
    assert!(without > 0 && without < 16, "{without} of 16 seeds left the top without an entry");
}

/// Two sealed 2 m rooms 30 cm apart. In the second, a 5 cm floor strip 30 cm from its wall
/// shares no edge with the rest of that floor and has no entry; the first room's floor entry
/// is the nearest in its plane (0.76-0.77 m, within three spacings), the second's 0.95 m away.
#[test]
fn a_triangle_without_an_entry_joins_only_a_cell_of_its_own_room() {
    let box_at = |x: f32| unit_box_faces().into_iter().map(move |q| q.map(|p| p * 2.0 + v(x, 0.0, 0.0)));
    let floor =
        |x0: f32, x1: f32, z0: f32, z1: f32| [v(x0, 0., z0), v(x0, 0., z1), v(x1, 0., z1), v(x1, 0., z0)];
    let strip = floor(2.6, 2.65, 0.5, 1.5);
    let mut qs: Vec<[Vec3; 4]> = box_at(0.0).collect();
    qs.extend(box_at(2.3).skip(1));
    qs.extend([
        floor(2.3, 2.6, 0.0, 2.0),
        strip,
        floor(2.6, 2.65, 0.0, 0.5),
        floor(2.6, 2.65, 1.5, 2.0),
        floor(2.65, 4.3, 0.0, 2.0),
    ]);
    let scene = quads(&qs, 0.5);
    let on =
        |p: Vec3| (0..scene.triangles.len()).find(|&t| inside(&scene.corners(t), p, 1e-4)).unwrap() as u32;
    let entry = |p: Vec3| prm::prm_file::Entry {
        position: p,
        normal: Vec3::Y,
        albedo: Vec3::splat(0.5),
        area: 0.07,
        triangle: on(p),
    };
    let entries = [entry(v(1.88, 0.0, 1.0)), entry(v(3.6, 0.0, 1.0))];
    let strip_triangles: Vec<usize> =
        (0..scene.triangles.len()).filter(|&t| scene.corners(t).iter().all(|c| strip.contains(c))).collect();
    assert_eq!(strip_triangles.len(), 2);
    let centroid = |t: usize| scene.corners(t).iter().sum::<Vec3>() / 3.0;
    // Without rooms the strip joins the first room's entry, through two walls.
    let (_, owners, _) = entry_cells(&scene, &entries, &[true; 2]);
    for &t in &strip_triangles {
        assert_eq!(owners.owner(t, centroid(t)), Some(0), "triangle {t}");
    }
    // With them it joins none (the second room's entry is too far): its area is left out.
    let corners: Vec<[Vec3; 3]> = (0..scene.triangles.len()).map(|t| scene.corners(t)).collect();
    let rooms = prm::rooms::Rooms::new(&corners);
    let room = entry_rooms(&rooms, &entries);
    let (_, owners, _) = entry_cells_in_rooms(&scene, &entries, &[true; 2], Some((&rooms, &room)));
    for &t in &strip_triangles {
        assert_eq!(owners.owner(t, centroid(t)), None, "triangle {t}");
    }
    // And the first room's own floor still belongs to its entry.
    assert_eq!(owners.owner(0, centroid(0)), Some(0));
}

/// Stay shares (`cells::stay_shares`): a closed box keeps a floor cell's light; with its top
/// open, the floor loses its form factor to the opening, 0.1998 for parallel unit squares one
/// apart (0.800 stays); a lone floor keeps none. 32 copies of the floor's cell, each with its
/// own rays.
#[test]
fn a_cell_s_stay_share_is_the_light_that_lands_on_the_level() {
    use prm::prm_file::Cells;
    use prm_precompute::cells::stay_shares;
    let faces = unit_box_faces();
    let f = faces[0];
    let cells = Cells::from_lists(vec![vec![[f[0], f[1], f[2]], [f[0], f[2], f[3]]]; 32]);
    let shares = |qs: &[[Vec3; 4]]| stay_shares(&prm::Bvh::build(&quads(qs, 0.5)), &cells, 3);
    let mean = |s: &[f32]| s.iter().sum::<f32>() / s.len() as f32;

    let closed = shares(&faces);
    assert!(mean(&closed) >= 0.999 && closed.iter().all(|&s| s >= 0.98), "closed: {closed:?}");
    let open: Vec<[Vec3; 4]> = faces.iter().enumerate().filter(|&(k, _)| k != 1).map(|(_, q)| *q).collect();
    let open = shares(&open);
    assert!((mean(&open) - 0.8002).abs() <= 0.02, "open: mean {} of {open:?}", mean(&open));
    assert!(open.iter().all(|&s| (s - 0.8002).abs() <= 0.15), "open: {open:?}");
    let lone = shares(&faces[..1]);
    assert!(lone.iter().all(|&s| s == 0.0), "a lone floor: {lone:?}");
    // A cell of no area stays whole; the same seed gives the same shares.
    let none = Cells::from_lists(vec![Vec::new()]);
    assert_eq!(stay_shares(&prm::Bvh::build(&quads(&faces[..1], 0.5)), &none, 3), vec![1.0]);
    assert_eq!(shares(&faces[..1]), lone);
}
