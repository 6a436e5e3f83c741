//! Local pane budgets (`cpu::compose_local`): K panes picked at each vertex of the atlas tile
//! grid, the groups standing in for the others, blended over each tile from its corners. A
//! budget as large as the panes around any vertex is the full sum; each vertex keeps the energy
//! of composing everything around it; each vertex's pick is its strongest; the blend leaves no
//! step at tile borders; and at the same K a local budget comes nearer the full sum than a
//! global one.

mod common;
use common::{open_box, point, v};
use std::sync::atomic::AtomicBool;

use glam::Vec3;
use prm::{luminance, Bvh, Scene};
use prm_runtime::cpu::{
    self, compose_local, entry_irradiance, tiles_around, vertex_weights, TileBudget, TileRecord,
};

fn bake(scene: &Scene) -> prm::prm_file::Prm {
    let bvh = Bvh::build(scene);
    let p = prm_precompute::precompute::PrecomputeParams {
        entries: 512,
        paths: 16,
        clusters: 48,
        groups: 8,
        atlas: prm::density::Atlas::single(48),
        tile_size: 8,
        ..Default::default()
    };
    prm_precompute::precompute::precompute(scene, &bvh, &p, &|_, _, _| {}, &AtomicBool::new(false)).unwrap().0
}

/// The open box under a lamp near one corner, and its weights.
fn lit() -> (prm::prm_file::Prm, Vec<Vec3>) {
    let mut scene = open_box();
    scene.lights = vec![point(v(0.15, 0.2, 0.15), 2.0)];
    let prm = bake(&scene);
    let bvh = Bvh::build(&scene);
    let e = entry_irradiance(&prm, &bvh, &scene.lights);
    let w = cpu::cluster_weights(&prm, &e);
    (prm, w)
}

/// The records of the tiles around every vertex of the map's tile grid.
fn vertices(prm: &prm::prm_file::Prm, budget: &TileBudget) -> Vec<Vec<&'static [TileRecord]>> {
    let (tx, ty) = (prm.tiles_x() as usize, prm.tiles_y() as usize);
    let tiles: &'static Vec<Vec<TileRecord>> = Box::leak(Box::new(budget.tiles.clone()));
    (0..(tx + 1) * (ty + 1))
        .map(|v| {
            tiles_around(v % (tx + 1), v / (tx + 1), tx, ty)
                .iter()
                .flatten()
                .map(|&t| &tiles[t][..])
                .collect()
        })
        .collect()
}

#[test]
fn a_budget_as_large_as_the_panes_around_any_vertex_is_the_full_sum() {
    let (prm, w) = lit();
    let layout = prm.layout();
    let budget = TileBudget::new(&prm, &layout);
    let c = w.len() as u32;
    let k = vertices(&prm, &budget)
        .iter()
        .map(|around| {
            let mut panes: Vec<u32> =
                around.iter().flat_map(|l| l.iter().map(|r| r.pane)).filter(|&p| p < c).collect();
            panes.sort();
            panes.dedup();
            panes.len()
        })
        .max()
        .unwrap();
    let full = cpu::compose(&prm, &w);
    let local = compose_local(&prm, &budget, &layout, &w, k, true);
    let peak = full.iter().map(|c| c.max_element()).fold(0.0f32, f32::max);
    for (a, b) in local.lightmap.iter().zip(&full) {
        assert!((*a - *b).abs().max_element() <= 1e-5 * peak, "{a} vs {b}");
    }
    let lit = w.iter().filter(|w| **w != Vec3::ZERO).count();
    assert_eq!(local.kept.iter().filter(|&&c| c).count(), lit, "every lit cluster is kept somewhere");
}

#[test]
fn each_vertex_keeps_the_energy_of_composing_everything_around_it() {
    let (prm, w) = lit();
    let budget = TileBudget::new(&prm, &prm.layout());
    let c = w.len();
    let (mut checked, mut lost) = (0usize, 0.0f32);
    for around in vertices(&prm, &budget) {
        // The energy each pane brings the tiles around, by pane.
        let mut energy: std::collections::BTreeMap<u32, f32> = Default::default();
        for r in around.iter().flat_map(|l| l.iter()) {
            *energy.entry(r.pane).or_default() += r.energy;
        }
        let all: f32 = energy
            .iter()
            .filter(|(&p, _)| (p as usize) < c)
            .map(|(&p, e)| luminance(w[p as usize]) * e)
            .sum();
        if all <= 0.0 {
            continue;
        }
        // A cluster in a tile where its group stores no tile has nowhere to go.
        let homeless = around.iter().any(|l| {
            l.iter().any(|r| {
                (r.pane as usize) < c
                    && !l.iter().any(|q| q.pane == c as u32 + prm.group_of()[r.pane as usize])
            })
        });
        let kept = |residual| -> f32 {
            vertex_weights(&around, &w, prm.group_of(), 2, residual)
                .iter()
                .map(|(p, wt)| luminance(*wt) * energy[p])
                .sum()
        };
        lost = lost.max(1.0 - kept(false) / all);
        if !homeless {
            checked += 1;
            let got = kept(true);
            assert!((got - all).abs() <= 1e-4 * all, "{got} with the groups vs {all} in full");
        }
    }
    assert!(checked > 10, "only {checked} vertices checked");
    assert!(lost > 0.2, "2 panes per vertex leave out at most {lost}: nothing was tested");
}

#[test]
fn each_vertex_picks_its_strongest_clusters() {
    let (prm, w) = lit();
    let budget = TileBudget::new(&prm, &prm.layout());
    let c = w.len() as u32;
    // Every other cluster dark: never picked, whatever its pane holds.
    let half: Vec<Vec3> =
        w.iter().enumerate().map(|(k, x)| if k % 2 == 0 { Vec3::ZERO } else { *x }).collect();
    for weights in [&w, &half] {
        for around in vertices(&prm, &budget) {
            let picked = vertex_weights(&around, weights, prm.group_of(), 3, false);
            let mut energy: std::collections::BTreeMap<u32, f32> = Default::default();
            for r in around.iter().flat_map(|l| l.iter()) {
                *energy.entry(r.pane).or_default() += r.energy;
            }
            let score = |p: u32| luminance(weights[p as usize]) * energy[&p];
            let lit = energy.keys().filter(|&&p| p < c && score(p) > 0.0).count();
            let kept: Vec<u32> =
                picked.iter().filter(|(p, wt)| *p < c && *wt != Vec3::ZERO).map(|(p, _)| *p).collect();
            assert_eq!(kept.len(), lit.min(3));
            let weakest = kept.iter().map(|&p| score(p)).fold(f32::INFINITY, f32::min);
            for &p in energy.keys().filter(|&&p| p < c && !kept.contains(&p)) {
                assert!(score(p) <= weakest, "a stronger cluster was left out");
            }
            for &p in &kept {
                assert_eq!(picked.iter().find(|q| q.0 == p).unwrap().1, weights[p as usize]);
            }
        }
    }
}

/// Picked per tile, a pane kept on one side of a border and left to its group on the other
/// stepped along it (chamber: 2.6 % of the mean irradiance across borders, 0.4 % between other
/// neighbours). Blended from shared vertices, a pane's weight on the two sides of a border
/// differs by at most 1/ts of its weights at the vertices involved.
#[test]
fn a_panes_weight_does_not_step_at_tile_borders() {
    let (prm, w) = lit();
    let budget = TileBudget::new(&prm, &prm.layout());
    let (tx, ty) = (prm.tiles_x() as usize, prm.tiles_y() as usize);
    let ts = prm.header().tile_size as usize;
    let weights: Vec<Vec<(u32, Vec3)>> = vertices(&prm, &budget)
        .iter()
        .map(|around| vertex_weights(around, &w, prm.group_of(), 3, true))
        .collect();
    let at = |vx: usize, vy: usize, pane: u32| {
        let l = &weights[vy * (tx + 1) + vx];
        l.binary_search_by_key(&pane, |p| p.0).map_or(Vec3::ZERO, |i| l[i].1)
    };
    let corners =
        |x: usize, y: usize, p: u32| [at(x, y, p), at(x + 1, y, p), at(x, y + 1, p), at(x + 1, y + 1, p)];
    let (mut pairs, mut stepped) = (0, 0);
    for y in 0..ty {
        for x in 0..tx - 1 {
            let (left, right) = (&budget.tiles[y * tx + x], &budget.tiles[y * tx + x + 1]);
            for r in left.iter().filter(|r| right.iter().any(|q| q.pane == r.pane)) {
                let (a, b) = (corners(x, y, r.pane), corners(x + 1, y, r.pane));
                let most = a.iter().chain(&b).map(|v| v.max_element()).fold(0.0f32, f32::max);
                for j in 0..ts {
                    let step = (cpu::blend(&a, ts - 1, j, ts) - cpu::blend(&b, 0, j, ts)).abs().max_element();
                    assert!(step <= most / ts as f32 + 1e-6, "pane {} steps {step} of {most}", r.pane);
                    pairs += 1;
                }
                // Tiles that differ at their far corners: a pick per tile would step here.
                stepped += (a[0] != b[1] || a[2] != b[3]) as usize;
            }
        }
    }
    assert!(pairs > 100 && stepped > 10, "{pairs} texel pairs, {stepped} panes picked differently");
}

#[test]
fn a_local_budget_comes_nearer_the_full_sum_than_a_global_one() {
    let (prm, w) = lit();
    let layout = prm.layout();
    let budget = TileBudget::new(&prm, &layout);
    let full = cpu::compose(&prm, &w);
    let energies: Vec<f32> = prm.clusters().iter().map(|c| c.energy).collect();
    let k = 4;
    let top = cpu::select_top_k(&w, &energies, k);
    let chosen: Vec<bool> = (0..w.len()).map(|c| top.contains(&c)).collect();
    for residual in [false, true] {
        let global = cpu::compose_selected(&prm, &w, &chosen, residual, &layout);
        let local = compose_local(&prm, &budget, &layout, &w, k, residual).lightmap;
        let eg = prm::metric::compare(&global, &full, None).error;
        let el = prm::metric::compare(&local, &full, None).error;
        // Measured: 0.21 vs 0.35 without the groups, 0.046 vs 0.16 with them.
        assert!(el < 0.7 * eg, "residual {residual}: {k} per tile {el} vs {k} over the map {eg}");
    }
}
