//! `prm precompute --update` (issue 14, item 3): an update writes, byte for byte, the file a
//! full precompute with the old bake's clusters writes (its twin); it walks only what the
//! edit can reach; a material edit gives exactly a fresh precompute; a moved object gives a
//! map within the distance between two fresh precomputes of different seeds; what it cannot
//! reuse it refuses, and a damaged cache is refused with the reason.

mod common;

use std::sync::atomic::AtomicBool;

use common::{unit_box_faces, v};
use glam::{Vec2, Vec3};
use prm::prm_file::Prm;
use prm::{Bvh, Scene};
use prm_precompute::precompute::{precompute_with, Baked, Held, PrecomputeError, PrecomputeParams, Reuse};
use prm_precompute::transport::Estimator;
use prm_precompute::update::UpdateCache;
use prm_runtime::cpu;

/// Quads on a 5 x 5 grid of UV charts, each a material index (0 grey 0.6, 1 grey 0.6 too,
/// recoloured by a test). At the tests' 160² atlas a chart's cell is two 16-texel tiles wide,
/// so no tile holds two charts.
fn scene(qs: &[([Vec3; 4], u32)]) -> Scene {
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (q, _)) in qs.iter().enumerate() {
        let cell = Vec2::new((k % 5) as f32, (k / 5) as f32);
        let base = pos.len() as u32;
        for (c, p) in q.iter().enumerate() {
            pos.push(*p);
            let corner = [Vec2::ZERO, Vec2::Y, Vec2::ONE, Vec2::X][c];
            uv.push((cell + Vec2::splat(0.08) + corner * 0.84) / 5.0);
        }
        idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    let mut s = Scene::from_mesh(pos, uv, &idx);
    s.materials[0].albedo = Vec3::splat(0.6);
    s.materials.push(s.materials[0].clone());
    for (t, tri) in s.triangles.iter_mut().enumerate() {
        tri.material = qs[t / 2].1;
    }
    s
}

/// Two sealed rooms side by side (unit boxes, the second 2 m along x), a block on the first
/// room's floor at `block` (its lower corner), the second room's floor of material 1.
fn two_sealed_rooms(block: Vec3) -> Scene {
    let mut qs: Vec<([Vec3; 4], u32)> = unit_box_faces().into_iter().map(|q| (q, 0)).collect();
    for (k, q) in unit_box_faces().into_iter().enumerate() {
        qs.push((q.map(|p| p + v(2.0, 0.0, 0.0)), (k == 0) as u32));
    }
    qs.extend(block_faces(block, block + v(0.25, 0.3, 0.25)).map(|q| (q, 0)));
    scene(&qs)
}

/// A block's top and four sides, outward, from its lower corner `lo` to its upper `hi`.
fn block_faces(lo: Vec3, hi: Vec3) -> [[Vec3; 4]; 5] {
    [
        [v(lo.x, hi.y, lo.z), v(lo.x, hi.y, hi.z), v(hi.x, hi.y, hi.z), v(hi.x, hi.y, lo.z)],
        [v(lo.x, lo.y, lo.z), v(lo.x, hi.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, lo.y, lo.z)],
        [v(hi.x, lo.y, hi.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z), v(lo.x, lo.y, hi.z)],
        [v(lo.x, lo.y, hi.z), v(lo.x, hi.y, hi.z), v(lo.x, hi.y, lo.z), v(lo.x, lo.y, lo.z)],
        [v(hi.x, lo.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(hi.x, lo.y, hi.z)],
    ]
}

/// Two sealed 10 m rooms `gap` apart along x, a 2.5 x 3 x 2.5 m block on the first room's
/// floor at `block` (its lower corner).
fn two_large_rooms(gap: f32, block: Vec3) -> Scene {
    let mut qs: Vec<([Vec3; 4], u32)> = Vec::new();
    for (room, dx) in [(0, 0.0), (1, 10.0 + gap)] {
        qs.extend(unit_box_faces().into_iter().map(|q| (q.map(|p| p * 10.0 + v(dx, 0.0, 0.0)), room)));
    }
    qs.extend(block_faces(block, block + v(2.5, 3.0, 2.5)).map(|q| (q, 0)));
    scene(&qs)
}

fn params() -> PrecomputeParams {
    PrecomputeParams {
        entries: 1024,
        paths: 16,
        clusters: 64,
        groups: 4,
        atlas: prm::density::Atlas::single(160),
        ..PrecomputeParams::production()
    }
}

fn run(scene: &Scene, p: &PrecomputeParams, reuse: Reuse, keep: bool) -> Result<Baked, PrecomputeError> {
    let bvh = Bvh::build(scene);
    precompute_with(scene, &bvh, p, reuse, keep, &|_, _, _| {}, &AtomicBool::new(false))
}

fn baked(scene: &Scene, p: &PrecomputeParams, reuse: Reuse, keep: bool) -> (Prm, UpdateCache, Vec<u8>) {
    let b = run(scene, p, reuse, keep).unwrap();
    let bytes = b.prm.to_bytes();
    (b.prm, b.cache.expect("a cache was asked for"), bytes)
}

/// Relative RMS distance between two maps' indirect light for one cluster weight pattern
/// (every cluster at 1 W/m²), over the covered texels.
fn distance(a: &Prm, b: &Prm, mask: &[bool]) -> f64 {
    let img = |p: &Prm| cpu::compose(p, &vec![Vec3::ONE; p.clusters().len()]);
    let (x, y) = (img(a), img(b));
    let (mut d, mut s) = (0.0f64, 0.0f64);
    for k in (0..x.len()).filter(|&k| mask[k]) {
        d += (x[k] - y[k]).length_squared() as f64;
        s += y[k].length_squared() as f64;
    }
    (d / s.max(1e-30)).sqrt()
}

/// Two sealed rooms baked whole: the entries lie in two rooms, no cluster takes entries from
/// both, and the far field has no pair across them, while within a room it has many.
#[test]
fn a_precompute_keeps_clusters_and_the_far_field_to_their_rooms() {
    let b = run(&two_sealed_rooms(v(0.3, 0.0, 0.3)), &params(), Reuse::Nothing, false).unwrap();
    assert_eq!(b.report.rooms, 2);
    assert!(b.report.room_voxel > 0.0 && b.report.room_voxel <= 0.1 + 1e-6, "{}", b.report.room_voxel);
    let (map, second) = (&b.prm, |e: &prm::prm_file::Entry| e.position.x > 1.5);
    let entries = map.entries();
    for (c, cluster) in map.clusters().iter().enumerate() {
        let first = second(&entries[cluster.members[0] as usize]);
        assert!(
            cluster.members.iter().all(|&e| second(&entries[e as usize]) == first),
            "cluster {c} takes entries from both rooms"
        );
    }
    let (mut within, mut across) = (0, 0);
    for i in 0..entries.len() {
        for j in 0..entries.len() {
            if map.far().sees(i, j) {
                if second(&entries[i]) == second(&entries[j]) {
                    within += 1;
                } else {
                    across += 1;
                }
            }
        }
    }
    assert!(within > 1000 && across == 0, "far pairs within {within}, across {across}");
}

#[test]
fn an_update_is_its_twin_to_the_byte_and_walks_only_what_the_edit_reaches() {
    let p = params();
    let before = two_sealed_rooms(v(0.3, 0.0, 0.3));
    let (old, cache, old_bytes) = baked(&before, &p, Reuse::Nothing, true);
    // Keeping the cache does not change the map.
    let plain = run(&before, &p, Reuse::Nothing, false).unwrap();
    assert!(plain.cache.is_none());
    assert_eq!(plain.prm.to_bytes(), old_bytes, "the cache's tracing changed the map");

    // The block moves 20 cm in the first room: the second room's walks never meet it.
    let after = two_sealed_rooms(v(0.5, 0.0, 0.4));
    let up =
        run(&after, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) }, true).unwrap();
    let (twin, twin_cache, twin_bytes) = baked(&after, &p, Reuse::Clusters(&cache), true);
    // Given rather than lent (as the CLI gives them, to let each go once done with it): the
    // same map and cache.
    let given = run(&after, &p, Reuse::Update { cache: cache.clone().into(), old: old.clone().into() }, true)
        .unwrap();
    assert_eq!(given.prm.to_bytes(), twin_bytes, "the update given OLD differs from its twin");
    assert_eq!(given.cache, up.cache);
    // To the byte here (the block's triangles' rounded areas did not cross a rounding step,
    // `prm_precompute::entries::sample_entries`); in general to float noise (module doc of
    // `update`), which the distance holds.
    let covered = prm::TexelSet::build(&after, 160, 160).mask();
    let d = distance(&up.prm, &twin, &covered);
    assert!(d < 1e-4, "the update is {d:.2e} from a full walk with the old clusters");
    assert_eq!(up.prm.to_bytes(), twin_bytes, "the update differs from a full walk with the old clusters");
    let r = &up.report;
    let tiles = cache.tiles.len();
    assert!(r.update_tiles_hit > 0, "the edit reached no tile");
    assert!(
        r.update_tiles_encoded < tiles && r.update_texels_walked < r.texels,
        "the second room was walked again: {} of {tiles} tiles, {} of {} texels",
        r.update_tiles_encoded,
        r.update_texels_walked,
        r.texels
    );
    assert!(r.update_texels_walked > 0);
    // The second room's entries are settled: their far-field pairs and texels' near links
    // come from the old bake (and the bytes above say they are what a full walk makes).
    assert!(
        r.update_entries_settled > r.entries as usize / 4 && r.update_entries_settled < r.entries as usize,
        "{} of {} entries settled",
        r.update_entries_settled,
        r.entries
    );
    // In the first room, whose entries are not settled, the pairs of blocks whose entries'
    // box misses the block where it was and where it is come from the old bake too (by
    // geometry, `prm_precompute::far::FarReuse`); the bytes above say they are what a full
    // walk makes.
    assert!(r.update_far_pairs_kept > 0, "no pair of the first room was kept by geometry");
    // So are the near links of its texels away from the block (`prm_precompute::near::NearReuse`).
    assert!(r.update_near_texels_kept > 0, "no texel of the first room kept its links by geometry");
    // Only the first room's next-bounce rows are made again (the second's inputs are as they
    // were, and its walks are not taken again), and the cache's row digests are the twin's.
    assert!(
        r.update_rows_made > 0 && r.update_rows_made < r.entries as usize * 3 / 4,
        "{} of {} rows made",
        r.update_rows_made,
        r.entries
    );
    let up_rows = up.cache.as_ref().map(|c| (c.rows.clone(), c.row_inputs.clone()));
    assert_eq!(up_rows, Some((twin_cache.rows.clone(), twin_cache.row_inputs.clone())));
    eprintln!(
        "moved block: {} of {tiles} tiles hit, {} encoded, {} of {} texels walked, {} of {} rows made, {} far pairs and {} texels' near links kept by geometry",
        r.update_tiles_hit,
        r.update_tiles_encoded,
        r.update_texels_walked,
        r.texels,
        r.update_rows_made,
        r.entries,
        r.update_far_pairs_kept,
        r.update_near_texels_kept
    );
    // And it is a different map from the old one (the block moved).
    assert_ne!(twin_bytes, old_bytes);
    assert!(distance(&twin, &old, &covered) > 1e-3, "the block's move changed nothing");
    drop(twin_cache);

    // A chain: moving the block back reaches the same tiles (a walk meets the edit's voxels
    // before the edit as after it: it is the same walk until it first does), so the update of
    // the update is the original again.
    let up_cache = up.cache.expect("an update keeps a cache");
    let back =
        run(&before, &p, Reuse::Update { cache: Held::Lent(&up_cache), old: Held::Lent(&up.prm) }, true)
            .unwrap();
    let d = distance(&back.prm, &old, &covered);
    assert!(d < 1e-4, "moving the block back is {d:.2e} from the original");
    assert_eq!(back.prm.to_bytes(), old_bytes, "moving the block back is not the original");
}

/// A block moved along the wall two large rooms share. The walks' footprint grid (0.4 m
/// voxels here, grown by one) cannot tell the far side of a 30 cm gap from the near one, so
/// by the footprint alone the second room's walks met the edit; by the rooms their points lay
/// in, they did not, and the update walks none of them and is still its twin to the byte.
#[test]
fn rooms_keep_an_edit_by_a_shared_wall_out_of_the_next_room() {
    let p = params();
    let gap = 0.3;
    let before = two_large_rooms(gap, v(7.4, 0.0, 2.0));
    let after = two_large_rooms(gap, v(7.4, 0.0, 3.0));
    let (old, cache, _) = baked(&before, &p, Reuse::Nothing, true);
    assert!(cache.grid.side > 0.3, "the footprint grid is finer than this test needs: {:?}", cache.grid);
    let up =
        run(&after, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) }, true).unwrap();
    let (_, _, twin_bytes) = baked(&after, &p, Reuse::Clusters(&cache), true);
    assert_eq!(up.prm.to_bytes(), twin_bytes, "the update differs from a full walk with the old clusters");

    // Tiles hold one chart each (two tiles a side); charts 0-5 are the first room's walls,
    // 6-11 the second's. The second room's walked tiles lay in one room, the same for all.
    // The first room's never lay in it; some of them are anywhere (ANY_ROOM): the wall texels
    // behind the block, whose walks stay in the 10 cm slot between the two, in voxels the
    // surfaces mark, so none of them could be placed.
    let chart_of = |k: usize| (k / 10 / 2) * 5 + (k % 10) / 2;
    let walked = |k: usize| !cache.tiles[k].rooms.is_empty();
    let second: Vec<usize> =
        (0..cache.tiles.len()).filter(|&k| (6..12).contains(&chart_of(k)) && walked(k)).collect();
    assert!(!second.is_empty());
    let room = cache.tiles[second[0]].rooms.clone();
    assert!(room.len() == 1 && room[0] != prm_precompute::transport::ANY_ROOM, "{room:?}");
    for &k in &second {
        assert_eq!(cache.tiles[k].rooms, room, "tile {k} of the second room");
    }
    let first: Vec<usize> = (0..cache.tiles.len()).filter(|&k| chart_of(k) < 6 && walked(k)).collect();
    assert!(first.iter().all(|&k| !cache.tiles[k].rooms.contains(&room[0])));
    let anywhere =
        first.iter().filter(|&&k| cache.tiles[k].rooms.contains(&prm_precompute::transport::ANY_ROOM));
    assert!(anywhere.count() < first.len() / 4, "most of the first room's walks were placed nowhere");
    // The block's old and new boxes, grown by one voxel as the update grows them, meet the
    // footprint of some tile of the second room's wall facing the block.
    let mut bits = vec![0u64; cache.grid.words()];
    for z in [2.0, 3.0] {
        cache.grid.mark_box(v(7.4, 0.0, z), v(9.9, 3.0, z + 2.5), &mut bits);
    }
    let grown = cache.grid.grow(&bits);
    let reached = (0..cache.tiles.len())
        .filter(|&k| (6..12).contains(&chart_of(k)))
        .filter(|&k| cache.tiles[k].footprint.iter().zip(&grown).any(|(a, b)| a & b != 0))
        .count();
    assert!(reached > 0, "no tile of the second room came within a voxel of the block");
    // ... but none of the second room's texels was walked again.
    let set = prm::TexelSet::build(&after, 160, 160);
    let in_first = set.texels.iter().filter(|t| t.position.x < 10.0 + 0.5 * gap).count();
    let r = &up.report;
    assert!(
        r.update_texels_walked > 0 && r.update_texels_walked <= in_first,
        "{} of {in_first}",
        r.update_texels_walked
    );
    eprintln!(
        "block by the shared wall: {} of {} tiles hit, {} of {} texels walked, {reached} second-room tiles \
         within the footprint",
        r.update_tiles_hit,
        cache.tiles.len(),
        r.update_texels_walked,
        r.texels
    );

    // The block is a closed room of its own, labelled in voxel order: pushed against the
    // first room's end wall its inside comes before the second room and renumbers it. An
    // update from the last update's cache (whose tiles taken over name the rooms in its
    // labels) is still its twin, and the second room is still not walked.
    let label = |level: &Scene| {
        let corners: Vec<[Vec3; 3]> = (0..level.triangles.len()).map(|t| level.corners(t)).collect();
        prm::rooms::Rooms::new(&corners).room_of(v(15.0, 0.0, 5.0), Vec3::Y)
    };
    let corner = two_large_rooms(gap, v(7.4, 0.0, 0.02));
    assert_ne!(label(&after), label(&corner), "the second room kept its label");
    let (up_cache, up_prm) = (up.cache.expect("an update keeps a cache"), up.prm);
    let next =
        run(&corner, &p, Reuse::Update { cache: Held::Lent(&up_cache), old: Held::Lent(&up_prm) }, true)
            .unwrap();
    let (_, _, twin_bytes) = baked(&corner, &p, Reuse::Clusters(&up_cache), true);
    assert_eq!(next.prm.to_bytes(), twin_bytes, "the second update differs from its full walk");
    assert!(next.report.update_texels_walked <= in_first);
    // A third from that one's cache: the second room's tiles were taken over, their rooms
    // mapped to the new labels (under the old label they would name the block's inside, which
    // this move touches, and be walked again).
    let (next_cache, next_prm) = (next.cache.expect("an update keeps a cache"), next.prm);
    let third =
        run(&after, &p, Reuse::Update { cache: Held::Lent(&next_cache), old: Held::Lent(&next_prm) }, true)
            .unwrap();
    let (_, _, twin_bytes) = baked(&after, &p, Reuse::Clusters(&next_cache), true);
    assert_eq!(third.prm.to_bytes(), twin_bytes, "the third update differs from its full walk");
    assert!(third.report.update_texels_walked <= in_first, "{}", third.report.update_texels_walked);
}

/// The map is made of the level's triangles alone (never its lights): with every triangle as
/// it was, the update hands back the old file and cache without a plan or a walk, and that is
/// what walking everything again with the old clusters gives (its twin), for no edit and for a
/// light moved and recoloured.
#[test]
fn an_update_with_no_edit_writes_the_same_file_and_cache() {
    let p = params();
    let mut level = two_sealed_rooms(v(0.3, 0.0, 0.3));
    level.lights = vec![prm::Light::point("lamp", v(0.5, 0.8, 0.5), Vec3::ONE)];
    let (old, cache, bytes) = baked(&level, &p, Reuse::Nothing, true);
    let (_, twin_cache, twin_bytes) = baked(&level, &p, Reuse::Clusters(&cache), true);
    assert_eq!(twin_bytes, bytes);
    assert_eq!(twin_cache, cache);
    let up =
        run(&level, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) }, true).unwrap();
    assert_eq!(up.report.update_tiles_hit, 0);
    assert_eq!(up.report.update_texels_walked, 0);
    assert_eq!(up.prm.to_bytes(), bytes);
    assert_eq!(up.cache.as_ref(), Some(&cache));
    // Given, the old map and cache are handed back themselves.
    let given = run(&level, &p, Reuse::Update { cache: cache.clone().into(), old: old.clone().into() }, true)
        .unwrap();
    assert_eq!((given.prm.to_bytes(), given.cache.as_ref()), (bytes.clone(), Some(&cache)));
    level.lights[0].position = v(2.5, 0.2, 0.5);
    level.lights[0].intensity = v(1.0, 0.5, 0.2);
    let moved =
        run(&level, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) }, true).unwrap();
    assert_eq!(moved.report.update_texels_walked, 0);
    // Its report is the old bake's, from the map's header (what `--json` prints).
    let first = run(&level, &p, Reuse::Nothing, false).unwrap().report;
    let r = &moved.report;
    assert!(r.texels > 0);
    assert_eq!(
        (r.texels, r.entries, r.clusters, r.tiles_kept, r.tiles_dropped, r.near_links, r.far_pairs),
        (
            first.texels,
            first.entries,
            first.clusters,
            first.tiles_kept,
            first.tiles_dropped,
            first.near_links,
            first.far_pairs
        )
    );
    assert_eq!(r.pane_bytes, first.pane_bytes);
    // The panes' power scales too, which the header states.
    assert_eq!(r.power_scale, first.power_scale);
    assert_ne!(r.power_scale, [1.0, 1.0], "the panes were scaled: this checks nothing");
    assert_eq!(moved.prm.to_bytes(), bytes);
    assert_eq!(moved.cache.as_ref(), Some(&cache));
    let fresh = run(&level, &p, Reuse::Nothing, false).unwrap();
    assert_eq!(fresh.prm.to_bytes(), bytes, "a fresh precompute read the lights");
}

#[test]
fn a_material_edit_updates_to_exactly_a_fresh_precompute() {
    let p = params();
    let level = two_sealed_rooms(v(0.3, 0.0, 0.3));
    let (old, cache, _) = baked(&level, &p, Reuse::Nothing, true);
    let mut recoloured = level.clone();
    recoloured.materials[1].albedo = Vec3::new(0.8, 0.2, 0.1);
    let up = run(&recoloured, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) }, true)
        .unwrap();
    let (_, fresh_cache, fresh) = baked(&recoloured, &p, Reuse::Nothing, true);
    assert_eq!(up.prm.to_bytes(), fresh, "a recolour's update is not the fresh precompute");
    assert_eq!(up.cache.as_ref(), Some(&fresh_cache));
    // Only the second room's walks met the recoloured floor.
    assert!(up.report.update_texels_walked < up.report.texels);
}

#[test]
fn a_moved_block_updates_to_within_seed_noise_of_a_fresh_precompute() {
    let p = params();
    let before = two_sealed_rooms(v(0.3, 0.0, 0.3));
    let after = two_sealed_rooms(v(0.55, 0.0, 0.5));
    let (old, cache, _) = baked(&before, &p, Reuse::Nothing, true);
    let up =
        run(&after, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) }, false).unwrap();
    let fresh = run(&after, &p, Reuse::Nothing, false).unwrap().prm;
    let other = run(&after, &PrecomputeParams { seed: 7, ..params() }, Reuse::Nothing, false).unwrap().prm;
    let set = prm::TexelSet::build(&after, 160, 160);
    let mask = set.mask();
    let (d_update, d_seeds) = (distance(&up.prm, &fresh, &mask), distance(&other, &fresh, &mask));
    // The old clusters are not the fresh ones (k-means moved with the block): the update may
    // be as far from the fresh map as another seed is, with 25 % to spare for the noise of
    // one pair of seeds.
    assert!(d_update <= 1.25 * d_seeds, "update {d_update:.4} vs two seeds {d_seeds:.4}");
    assert!(d_seeds > 0.0);
}

#[test]
fn updates_it_cannot_do_are_refused_with_the_reason() {
    let p = params();
    let level = two_sealed_rooms(v(0.3, 0.0, 0.3));
    let (old, cache, _) = baked(&level, &p, Reuse::Nothing, true);
    let refused = |scene: &Scene, p: &PrecomputeParams| match run(
        scene,
        p,
        Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old) },
        true,
    ) {
        Err(PrecomputeError::Refused(r)) => r.0,
        Err(e) => panic!("not a refusal: {e}"),
        Ok(_) => panic!("updated"),
    };
    let more_paths = PrecomputeParams { paths: 32, ..params() };
    assert!(refused(&level, &more_paths).contains("parameters differ"));
    // A triangle more.
    let mut grown = level.clone();
    let extra = grown.triangles[0];
    grown.triangles.push(extra);
    assert!(refused(&grown, &p).contains("triangles"));
    // The second room pushed half a metre further out: the level's bounds move, and every
    // ray's offsets with them.
    let mut wider = level.clone();
    for q in wider.positions.iter_mut().filter(|q| q.x > 1.5) {
        q.x += 0.5;
    }
    assert!(refused(&wider, &p).contains("bounds"));
    // A cache of another map.
    let other = run(&level, &PrecomputeParams { seed: 3, ..params() }, Reuse::Nothing, false).unwrap().prm;
    let r = run(&level, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&other) }, true);
    assert!(matches!(r, Err(PrecomputeError::Refused(ref r)) if r.0.contains("another .prm")));
    // The same map as an older build wrote it (format version 14: no `SEEN` section, every
    // texel seeing its links' whole cells, no crease points, v16's `CRSE`, and no far texel
    // areas, v17's `TXAR`) is refused as
    // such, not as another map's (it reads in this version's form, whose checksum differs).
    let without = |bytes: &[u8], tag: &[u8; 4]| -> Vec<u8> {
        let Some(at) = (16..bytes.len()).find(|&k| &bytes[k..k + 4] == tag) else {
            panic!("no {} section", String::from_utf8_lossy(tag));
        };
        let len = u64::from_le_bytes(bytes[at + 4..at + 12].try_into().unwrap()) as usize;
        [&bytes[..at], &bytes[at + 12 + len..]].concat()
    };
    let bytes =
        without(&without(&without(&old.without_creases().unwrap().to_bytes(), b"SEEN"), b"CRSE"), b"TXAR");
    let mut v14 = bytes[..bytes.len() - 8].to_vec();
    v14[8..12].copy_from_slice(&14u32.to_le_bytes());
    let sum = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &v14);
    v14.extend_from_slice(&sum.to_le_bytes());
    let old14 = Prm::from_bytes(std::path::Path::new("old.prm"), &v14).unwrap();
    assert_eq!(old14.read_version(), 14);
    let r = run(&level, &p, Reuse::Update { cache: Held::Lent(&cache), old: Held::Lent(&old14) }, true);
    let Err(PrecomputeError::Refused(r)) = r else { panic!("a version 14 map updated or failed otherwise") };
    assert!(r.0.contains("format version 14") && r.0.contains("older build"), "{}", r.0);
    // A cache is kept for the gather estimator only.
    let mis = PrecomputeParams { estimator: Estimator::Mis, ..params() };
    assert!(matches!(run(&level, &mis, Reuse::Nothing, true), Err(PrecomputeError::Refused(_))));
}

#[test]
fn a_damaged_cache_is_refused_with_what_is_wrong() {
    let p = PrecomputeParams { atlas: prm::density::Atlas::single(64), ..params() };
    let level = two_sealed_rooms(v(0.3, 0.0, 0.3));
    let (map, cache, _) = baked(&level, &p, Reuse::Nothing, true);
    let bytes = cache.to_bytes(&map);
    assert_eq!(UpdateCache::from_bytes(&bytes, &map).as_ref(), Ok(&cache));
    // The tiles the map keeps are not written twice: beside a map that keeps none of them
    // (another level's) every tile is written whole, and the difference is exactly the kept
    // tiles' codes and counts (each tile's scale is written either way).
    let (other, _, _) = baked(&two_sealed_rooms(v(0.6, 0.0, 0.3)), &p, Reuse::Nothing, true);
    let whole = cache.to_bytes(&other);
    let layout = map.layout();
    let kept: usize = (0..map.clusters().len() + map.groups().len())
        .flat_map(|c| map.pane_tiles(c, &layout).map(|t| t.data.len() + 4).collect::<Vec<_>>())
        .sum();
    assert!(kept > 0);
    assert_eq!(
        whole.len() - bytes.len(),
        kept,
        "{} bytes beside its map, {} whole",
        bytes.len(),
        whole.len()
    );
    // Beside another map the codes it leaves out are not there, or they are that map's: then
    // the cache's tie to its own map (its checksum) refuses the update, which bakes whole.
    match UpdateCache::from_bytes(&bytes, &other) {
        Err(e) => assert!(e.contains("not in the map"), "{e}"),
        Ok(misread) => {
            assert_ne!(misread.prm_checksum, other.checksum());
            let update = Reuse::Update { cache: Held::Lent(&misread), old: Held::Lent(&other) };
            assert!(matches!(run(&level, &p, update, true), Err(PrecomputeError::Refused(_))));
        }
    }
    let err = |b: &[u8]| UpdateCache::from_bytes(b, &map).expect_err("a damaged cache parsed");
    assert!(err(&bytes[..bytes.len() / 2]).contains("checksum"));
    assert!(err(b"not a cache at all").contains("magic"));
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 3] ^= 0x40;
    assert!(err(&flipped).contains("checksum"));
    // Every cut with the checksum fixed up is refused by a section check, never a panic.
    for cut in (12..bytes.len() - 8).step_by(bytes.len() / 97 + 1) {
        let mut b = bytes[..cut].to_vec();
        let sum = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &b);
        b.extend_from_slice(&sum.to_le_bytes());
        assert!(UpdateCache::from_bytes(&b, &map).is_err(), "a cache cut at {cut} parsed");
    }
    // A cache of an older build is not called damaged: the reader says which version it is.
    let mut older = bytes[..bytes.len() - 8].to_vec();
    older[8..12].copy_from_slice(&3u32.to_le_bytes());
    let sum = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &older);
    older.extend_from_slice(&sum.to_le_bytes());
    let dir = std::env::temp_dir().join(format!("prm-cache-version-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("old.prm.cache");
    std::fs::write(&path, &older).unwrap();
    let said = UpdateCache::read(&path, &map).expect_err("an older cache was read").to_string();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(
        said.contains("version 3") && said.contains("again with --cache") && !said.contains("damaged"),
        "{said}"
    );
}
