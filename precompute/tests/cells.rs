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

/// Stay shares and bounce gains (`cells::reflections`) in a unit box of albedo 0.5, 96 entries.
/// Closed, every cell keeps its light (share 1) and its gain is `1 / (1 - rho)` in each
/// channel (0.5, 0.25 and 0 given as the entries' albedos: 2, 4/3, 1; 0.99, 0.97, 0.95: 100,
/// 33.3, 20; 1: the 1,000 bounces the walks stop at). With its top open, a
/// floor cell loses its form factor to the opening, 0.1998 for parallel unit squares one apart
/// (0.800 stays), and the gains are what a brute-force walk from each cell gives (the light
/// landing over every bounce, Russian roulette on the albedo, 4096 walks a cell), face by face
/// within 2 %. A closed block on the floor of the closed box leaves the floor cells reaching
/// under it at `1 / (1 - rho)` (only their open part counts). A lone floor keeps nothing; a
/// cell of no area stays whole with gain 1.
#[test]
fn a_cell_s_stay_share_and_bounce_gain_are_the_light_that_lands_on_the_level() {
    use prm::prm_file::Cells;
    use prm_precompute::cells::{reflections, Reflections};
    let faces = unit_box_faces();
    let open: Vec<[Vec3; 4]> = faces.iter().enumerate().filter(|&(k, _)| k != 1).map(|(_, q)| *q).collect();
    let bake = |qs: &[[Vec3; 4]], albedo: Option<Vec3>| {
        let scene = quads(qs, 0.5);
        let bvh = prm::Bvh::build(&scene);
        let entries = sample_entries(&scene, 96, 5);
        let (cells, owners, _) = entry_cells(&scene, &entries, &vec![true; entries.len()]);
        let albedo: Vec<Vec3> = entries.iter().map(|e| albedo.unwrap_or(e.albedo)).collect();
        let r = reflections(&scene, &bvh, &cells, &owners, &albedo, 3, 1000);
        (scene, bvh, entries, cells, r)
    };
    let mean = |s: &[f32]| s.iter().sum::<f32>() / s.len() as f32;

    let (_, _, _, _, closed) = bake(&faces, Some(Vec3::new(0.5, 0.25, 0.0)));
    assert!(
        mean(&closed.stays) >= 0.999 && closed.stays.iter().all(|&s| s >= 0.98),
        "closed: {:?}",
        closed.stays
    );
    let want = Vec3::new(2.0, 4.0 / 3.0, 1.0);
    for g in &closed.gains {
        assert!(((*g - want) / want).abs().max_element() <= 0.02, "closed: gain {g}, want {want}");
    }
    // Albedo 0.99: 100, which the iteration's 64 rounds alone leave at 47 (their last step's
    // geometric series adds the rest).
    // Per channel, each with its own rate (0.99, 0.97, 0.95: 100, 33.3, 20); albedo 1 counts
    // the walks' 1,000 bounces.
    let (_, _, _, _, bright) = bake(&faces, Some(Vec3::new(0.99, 0.97, 0.95)));
    let g = bright.gains.iter().fold(Vec3::ZERO, |a, g| a + *g) / bright.gains.len() as f32;
    let want = Vec3::new(100.0, 100.0 / 3.0, 20.0);
    assert!(
        ((g - want) / want).abs().max_element() <= 0.05,
        "albedo 0.99 / 0.97 / 0.95: mean gain {g}, want {want}"
    );
    // Two closed boxes side by side, 0.99 and 0.95: each keeps its own rate (one rate for
    // the whole level gave them 11 % low and high).
    let two: Vec<[Vec3; 4]> = faces
        .iter()
        .chain(&faces)
        .enumerate()
        .map(|(k, q)| {
            let shift = if k < faces.len() { Vec3::ZERO } else { Vec3::new(2.0, 0.0, 0.0) };
            q.map(|p| p + shift)
        })
        .collect();
    let scene = quads(&two, 0.5);
    let bvh = prm::Bvh::build(&scene);
    let entries = sample_entries(&scene, 192, 5);
    let (cells, owners, _) = entry_cells(&scene, &entries, &vec![true; entries.len()]);
    let albedo: Vec<Vec3> =
        entries.iter().map(|e| Vec3::splat(if e.position.x > 1.5 { 0.95 } else { 0.99 })).collect();
    let r = reflections(&scene, &bvh, &cells, &owners, &albedo, 3, 1000);
    for (room, want) in [(false, 100.0), (true, 20.0)] {
        let g: Vec<f32> = (0..entries.len())
            .filter(|&j| (entries[j].position.x > 1.5) == room)
            .map(|j| r.gains[j].x)
            .collect();
        let g = mean(&g);
        assert!((g / want - 1.0).abs() <= 0.05, "two boxes: mean gain {g}, want {want}");
    }
    let (_, _, _, _, white) = bake(&faces, Some(Vec3::ONE));
    let g = white.gains.iter().map(|g| g.x).sum::<f32>() / white.gains.len() as f32;
    assert!((g / 1000.0 - 1.0).abs() <= 0.05, "albedo 1: mean gain {g}, want 1000 (the bounce cap)");

    let (scene, bvh, entries, cells, opened) = bake(&open, None);
    let floor: Vec<usize> = (0..entries.len()).filter(|&j| entries[j].normal.y > 0.9).collect();
    let floor_stays: Vec<f32> = floor.iter().map(|&j| opened.stays[j]).collect();
    assert!(floor.len() >= 8, "{} floor entries", floor.len());
    assert!((mean(&floor_stays) - 0.8002).abs() <= 0.02, "open floor: {floor_stays:?}");
    assert!(floor_stays.iter().all(|&s| (s - 0.8002).abs() <= 0.1), "open floor: {floor_stays:?}");
    // The brute-force twin, face by face (walls, floor): the mean landing over every bounce.
    let walk = |j: usize| {
        use rand::Rng;
        let mut rng = prm::sampling::stream(11, 1, j as u64);
        let (spread, mut sum) = (cells.spread(j), 0.0f64);
        for _ in 0..4096 {
            let (mut p, mut n) = spread.point(rng.random(), rng.random(), rng.random());
            loop {
                let d = prm::sampling::cosine_direction(n, rng.random(), rng.random());
                let Some(hit) = bvh.trace_from_surface(p, n, d) else { break };
                sum += 1.0;
                let tri = hit.triangle as usize;
                if rng.random::<f32>() >= 0.5 {
                    break;
                }
                p = scene.point(tri, hit.bary());
                n = scene.facing_normal(tri, d).unwrap_or(n);
            }
        }
        (sum / 4096.0) as f32
    };
    for (name, face) in [
        ("floor", floor.clone()),
        ("walls", (0..entries.len()).filter(|&j| entries[j].normal.y.abs() < 0.1).collect()),
    ] {
        let got = mean(&face.iter().map(|&j| opened.gains[j].x).collect::<Vec<_>>());
        let want = mean(&face.iter().map(|&j| walk(j)).collect::<Vec<_>>());
        assert!((got - want).abs() <= 0.02 * want, "open box, {name}: gain {got}, the walks {want}");
    }
    // The open box's floor sends on less than a closed one's (2) and more than it keeps.
    assert!(floor.iter().all(|&j| opened.gains[j].x > opened.stays[j] && opened.gains[j].x < 1.9));

    // A closed block standing on the floor: the floor cells reaching under it count only
    // their open part, so every floor cell's gain is still 1 / (1 - rho).
    let block: Vec<[Vec3; 4]> = faces
        .iter()
        .map(|q| q.map(|p| Vec3::new(0.5, 0.15, 0.5) + (p - Vec3::splat(0.5)) * 0.3))
        .map(|[a, b, c, d]| [a, d, c, b])
        .collect();
    let with_block: Vec<[Vec3; 4]> = faces.iter().chain(&block).copied().collect();
    let (_, _, entries, _, blocked) = bake(&with_block, None);
    let under = |p: Vec3| (p.x - 0.5).abs() < 0.15 && (p.z - 0.5).abs() < 0.15 && p.y < 0.01;
    let mut near_block = 0;
    for (j, e) in entries.iter().enumerate() {
        if e.normal.y > 0.9 && e.position.y < 0.01 && !under(e.position) {
            near_block += ((e.position - Vec3::new(0.5, 0.0, 0.5)).length() < 0.35) as usize;
            let g = blocked.gains[j].x;
            assert!((g - 2.0).abs() <= 0.04, "floor entry {j} at {}: gain {g}", e.position);
        }
    }
    assert!(near_block > 0, "no floor cell by the block: this checks nothing");

    let (_, _, _, _, lone) = bake(&faces[..1], None);
    assert!(
        lone.stays.iter().all(|&s| s == 0.0) && lone.gains.iter().all(|&g| g == Vec3::ZERO),
        "a lone floor: {lone:?}"
    );
    // A cell of no area stays whole; the same seed gives the same shares and gains.
    let (scene, bvh, _, _, _) = bake(&faces[..1], None);
    let (_, owners, _) = entry_cells(&scene, &sample_entries(&scene, 4, 5), &[true; 4]);
    let none =
        reflections(&scene, &bvh, &Cells::from_lists(vec![Vec::new()]), &owners, &[Vec3::ONE], 3, 1000);
    assert_eq!(none, Reflections { stays: vec![1.0], gains: vec![Vec3::ONE] });
    assert_eq!(bake(&open, None).4, opened);
}
