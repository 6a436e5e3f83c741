//! The slow, obvious compose (DESIGN.md §5 steps 2-4 after the entry irradiance): cluster
//! weights, top-K selection, residual group weights and the weighted sum of panes, on the CPU.
//! The GPU passes (`weights.wgsl`, `compose.wgsl`) are held to these functions by the tests.

use glam::Vec3;
use prm::luminance;
use prm::prm_file::{Prm, TileLayout};

/// Cluster weights from per-entry irradiance: the mean over each cluster's members.
pub fn cluster_weights(prm: &Prm, entry_irradiance: &[Vec3]) -> Vec<Vec3> {
    prm.clusters()
        .iter()
        .map(|c| {
            if c.members.is_empty() {
                return Vec3::ZERO;
            }
            c.members.iter().map(|&m| entry_irradiance[m as usize]).fold(Vec3::ZERO, |a, b| a + b)
                / c.members.len() as f32
        })
        .collect()
}

/// Indices of the (at most) `k` clusters with the largest `luminance(weight) x energy`,
/// strongest first; zero-weight clusters are left out. Ties go to the lower index.
pub fn select_top_k(weights: &[Vec3], energies: &[f32], k: usize) -> Vec<usize> {
    let mut scored: Vec<(f32, usize)> = weights
        .iter()
        .zip(energies)
        .enumerate()
        .map(|(c, (w, e))| (luminance(*w) * e, c))
        .filter(|(s, _)| *s > 0.0)
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    scored.truncate(k);
    scored.into_iter().map(|(_, c)| c).collect()
}

/// The weight of each group's pane when only the clusters in `selected` are composed:
/// `r_g = sum over left-out clusters c of g of w_c x energy_c / energy_g`, which gives the
/// group's pane the (luminance) energy of the light those clusters would have added.
pub fn residual_weights(prm: &Prm, weights: &[Vec3], selected: &[bool]) -> Vec<Vec3> {
    let mut r = vec![Vec3::ZERO; prm.groups().len()];
    for (c, &g) in prm.group_of().iter().enumerate() {
        if !selected[c] {
            r[g as usize] += weights[c] * prm.clusters()[c].energy;
        }
    }
    for (v, g) in r.iter_mut().zip(prm.groups()) {
        *v = if g.energy > 0.0 { *v / g.energy } else { Vec3::ZERO };
    }
    r
}

/// Add `weight x` pane `pane` (cluster c < C, group C + g) into a full-atlas image.
pub fn add_pane(prm: &Prm, pane: usize, weight: Vec3, img: &mut [Vec3], layout: &TileLayout) {
    for t in prm.pane_tiles(pane, layout) {
        let s = weight * t.tile.scale;
        for (&texel, v) in t.texels.iter().zip(t.data) {
            img[texel as usize] += s * v.to_f32();
        }
    }
}

/// The lightmap from the clusters in `selected` (weights `weights`), plus, with `residual`,
/// the groups standing in for the rest.
pub fn compose_selected(
    prm: &Prm,
    weights: &[Vec3],
    selected: &[bool],
    residual: bool,
    layout: &TileLayout,
) -> Vec<Vec3> {
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    for c in 0..prm.clusters().len() {
        if selected[c] && weights[c] != Vec3::ZERO {
            add_pane(prm, c, weights[c], &mut img, layout);
        }
    }
    if residual {
        let first_group = prm.clusters().len();
        for (g, w) in residual_weights(prm, weights, selected).into_iter().enumerate() {
            if w != Vec3::ZERO {
                add_pane(prm, first_group + g, w, &mut img, layout);
            }
        }
    }
    img
}

/// The indirect lightmap for per-cluster weights (W/m² of entry irradiance): every pane times
/// its weight, no selection.
pub fn compose(prm: &Prm, weights: &[Vec3]) -> Vec<Vec3> {
    assert_eq!(weights.len(), prm.clusters().len(), "one weight per cluster");
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    let layout = prm.layout();
    for (c, w) in weights.iter().enumerate() {
        if *w != Vec3::ZERO {
            add_pane(prm, c, *w, &mut img, &layout);
        }
    }
    img
}
