//! Tile dropping (`panes`, header `dropped_energy` and `drop_threshold`): the same bake with no
//! dropping and with a 10 % threshold. Per pane, the kept tiles are the same bytes, the dropped
//! ones hold at most the threshold's share of the pane's energy, they are the pane's weakest
//! tiles, and the greedy rule stops at the first tile that would cross the threshold.

use prm_runtime::cpu;
use std::sync::atomic::AtomicBool;

use glam::Vec3;
use prm::prm_file::{Prm, TileLayout};
use prm_precompute::precompute::{precompute, PrecomputeParams};

const THRESHOLD: f64 = 0.1;
/// Tile energies are read back from the file: 8-bit logarithmic intensities (within half a
/// step, 1.9 %, of the exact value; `prm::prm_file::intensity`) times an f32 scale. A tile's
/// energy is a sum of same-signed such terms, so it carries at most ~1.9 % relative error;
/// comparisons between tiles and against the threshold allow 2e-2.
const REL: f64 = 2e-2;

fn bake(threshold: f64) -> Prm {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = prm::gltf_load::load_scene(root.join("assets/cornell.glb"), &Default::default()).unwrap();
    let bvh = prm::Bvh::build(&scene);
    let p = PrecomputeParams {
        entries: 256,
        paths: 8,
        clusters: 16,
        groups: 4,
        atlas: prm::density::Atlas::single(32),
        tile_size: 4,
        drop_threshold: threshold,
        // The panes as walked: matched to their power, the kept tiles would also carry the
        // dropped ones' share (`precompute::match_power`), and this compares them byte for byte.
        match_power: false,
        ..Default::default()
    };
    precompute(&scene, &bvh, &p, &|_, _, _| {}, &AtomicBool::new(false)).unwrap().0
}

/// One pane (cluster c < C, group C + g) as a full-atlas image, decoded from the file's tiles
/// (texel = tile scale x half-float intensity); for a cluster, also held to the runtime's CPU
/// compose of a one-hot weight.
fn pane(prm: &Prm, layout: &TileLayout, k: usize) -> Vec<Vec3> {
    let mut img = vec![Vec3::ZERO; (prm.header().atlas_width * prm.header().atlas_height) as usize];
    for t in prm.pane_tiles(k, layout) {
        for (&texel, v) in t.texels.iter().zip(t.data) {
            img[texel as usize] = t.tile.scale * prm::prm_file::intensity(*v);
        }
    }
    let c = prm.clusters().len();
    if k < c {
        let mut w = vec![Vec3::ZERO; c];
        w[k] = Vec3::ONE;
        assert_eq!(cpu::compose(prm, &w), img, "compose of a one-hot weight is not the pane");
    }
    img
}

/// The stored tiles of pane k: (atlas tile index, energy = summed luminance of its texels).
fn tile_energies(prm: &Prm, img: &[Vec3], k: usize) -> Vec<(u32, f64)> {
    let (first, count) = if k < prm.clusters().len() {
        (prm.clusters()[k].first_tile, prm.clusters()[k].tile_count)
    } else {
        let g = &prm.groups()[k - prm.clusters().len()];
        (g.first_tile, g.tile_count)
    };
    let (w, ts, tx) =
        (prm.header().atlas_width as usize, prm.header().tile_size as usize, prm.tiles_x() as usize);
    let h = prm.header().atlas_height as usize;
    (first..first + count)
        .map(|t| {
            let index = prm.tiles()[t as usize].index;
            assert_eq!(prm.tiles()[t as usize].cluster as usize, k);
            let (ti, tj) = (index as usize % tx, index as usize / tx);
            let mut e = 0.0f64;
            for y in tj * ts..((tj + 1) * ts).min(h) {
                for x in ti * ts..((ti + 1) * ts).min(w) {
                    e += prm::luminance(img[y * w + x]) as f64;
                }
            }
            (index, e)
        })
        .collect()
}

#[test]
fn dropped_tiles_are_the_weakest_and_stay_within_the_threshold() {
    let (all, some) = (bake(0.0), bake(THRESHOLD));
    // Dropping changes only which tiles are stored.
    assert_eq!(
        (&all.entries(), &all.mask(), &all.group_of()),
        (&some.entries(), &some.mask(), &some.group_of())
    );
    assert_eq!(all.clusters().len(), some.clusters().len());
    assert_eq!(all.groups().len(), some.groups().len());
    assert!(!all.groups().is_empty(), "fixture: the bake should have groups");
    for (a, b) in all.clusters().iter().zip(some.clusters()) {
        assert_eq!((&a.members, a.centroid, a.energy), (&b.members, b.centroid, b.energy));
    }
    assert_eq!((all.header().drop_threshold, some.header().drop_threshold), (0.0, THRESHOLD));
    assert_eq!(all.header().dropped_energy, 0.0, "threshold 0 drops only empty tiles");

    let (la, lb) = (all.layout(), some.layout());
    let c = all.clusters().len();
    let (mut dropped_clusters, mut dropped_groups) = (0u32, 0u32);
    let (mut dropped_e, mut total_e) = (0.0f64, 0.0f64);
    for k in 0..c + all.groups().len() {
        let (img_a, img_b) = (pane(&all, &la, k), pane(&some, &lb, k));
        let (ta, tb) = (tile_energies(&all, &img_a, k), tile_energies(&some, &img_b, k));
        let total: f64 = ta.iter().map(|t| t.1).sum();
        let kept: Vec<(u32, f64)> = ta.iter().copied().filter(|t| tb.iter().any(|u| u.0 == t.0)).collect();
        let dropped: Vec<(u32, f64)> =
            ta.iter().copied().filter(|t| !tb.iter().any(|u| u.0 == t.0)).collect();
        assert_eq!(kept.len(), tb.len(), "pane {k}: a tile appeared that threshold 0 did not store");
        // Kept tiles are the same texels, bit for bit (same scale, same codes); dropped
        // ones are absent.
        let tx = all.tiles_x() as usize;
        let ts = all.header().tile_size as usize;
        let w = all.header().atlas_width as usize;
        for (k_idx, px) in img_a.iter().enumerate() {
            let index = ((k_idx / w) / ts * tx + (k_idx % w) / ts) as u32;
            let want = if kept.iter().any(|t| t.0 == index) { *px } else { Vec3::ZERO };
            assert_eq!(img_b[k_idx], want, "pane {k}, texel {k_idx} (tile {index})");
        }
        let e_drop: f64 = dropped.iter().map(|t| t.1).sum();
        // The bound: dropped energy within the threshold's share of the pane.
        assert!(e_drop <= THRESHOLD * total * (1.0 + REL), "pane {k}: dropped {e_drop} of {total}");
        // Greedy: every dropped tile is weaker than every kept one...
        let max_dropped = dropped.iter().map(|t| t.1).fold(0.0, f64::max);
        let min_kept = kept.iter().map(|t| t.1).fold(f64::INFINITY, f64::min);
        assert!(max_dropped <= min_kept * (1.0 + REL), "pane {k}: dropped {max_dropped} > kept {min_kept}");
        // ...and it stops only when the next (weakest kept) tile would cross the threshold.
        if !kept.is_empty() {
            assert!(
                e_drop + min_kept >= THRESHOLD * total * (1.0 - REL),
                "pane {k}: tile of energy {min_kept} could also have been dropped ({e_drop} of {total})"
            );
        }
        if k < c {
            dropped_clusters += dropped.len() as u32;
            dropped_e += e_drop;
            total_e += total;
        } else {
            dropped_groups += dropped.len() as u32;
        }
    }
    assert!(dropped_clusters > 0 && dropped_groups > 0, "fixture: tiles must really be dropped");
    // The header's figures are the clusters' (the groups' panes are dropped by the same rule but
    // not counted there).
    assert_eq!(some.header().tiles_dropped, dropped_clusters);
    assert_eq!(some.tiles().len() + (dropped_clusters + dropped_groups) as usize, all.tiles().len());
    let frac = some.header().dropped_energy;
    assert!(frac > 0.0 && frac <= THRESHOLD, "header dropped_energy {frac}");
    assert!(
        (frac - dropped_e / total_e).abs() <= REL * frac,
        "header dropped_energy {frac} vs {} from the panes",
        dropped_e / total_e
    );
}
