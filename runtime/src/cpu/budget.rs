//! Local pane budgets (the runtime's default selection): the K clusters that matter are
//! picked at each vertex of the atlas tile grid, from the up-to-four tiles around it, and each
//! pane's weight over a tile is the bilinear blend of its weights at the tile's four corners.
//!
//! A global top-K spends its budget on the clusters that light the level most; a texel far from
//! them gets only the groups' coarse panes. Picked locally, every region of the atlas gets the
//! K panes that matter to it. At a vertex, a cluster's claim is `luminance(w_c) x` the energy
//! of its stored tiles around it; the K strongest keep their weight, the others weigh 0 there,
//! and each group stands in for its clusters left out: `r_g(v) = sum of w_c E_c / E_g` over the
//! tiles around v that store the group's pane (E: a stored tile's luminance energy), so the pick
//! keeps the energy of composing everything there, up to the codes' rounding.
//!
//! **Why vertices.** Picked per tile, a cluster kept on one side of a tile border and left to
//! its group on the other made a step along the border (chamber: the difference from all panes
//! changed by 2.6 % of the mean irradiance across borders against 0.4 % between other
//! neighbours, a visible grid). Averaging the tiles' picks at the vertices removed the step but
//! blurred the picks (chamber's own lights 5.6 -> 7.0 %); picking at the vertices removes it
//! (0.38 % against 0.41 %) and keeps most of the gain (6.2 %). A tile sums the panes any of its
//! corners weighs: with K at least the clusters around every vertex, every pane, which is the
//! all-panes compose.
//!
//! `shaders/compose.wgsl` is the GPU twin, held to [`compose_local`] by the tests.

use glam::Vec3;
use prm::luminance;
use prm::prm_file::{intensity, Prm, TileLayout};

/// One stored tile at an atlas tile: its pane (cluster c < C, group C + g) and its place in
/// [`Prm::tiles`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileRecord {
    pub pane: u32,
    pub stored: u32,
    /// Luminance energy per unit weight: `luminance(scale) x sum of its texels' intensities`.
    pub energy: f32,
}

/// Stored tile `k`'s luminance energy per unit weight: `luminance(scale) x` the sum of its
/// texels' intensities (the GPU's records carry the same number, computed here at load).
pub fn stored_tile_energy(prm: &Prm, layout: &TileLayout, k: usize) -> f32 {
    let t = &prm.tiles()[k];
    let start = layout.offsets[k];
    let data = &prm.data()[start..start + layout.texels[t.index as usize].len()];
    luminance(t.scale) * data.iter().map(|&v| intensity(v)).sum::<f32>()
}

/// The map's stored tiles grouped by the atlas tile they cover, built once per map.
pub struct TileBudget {
    /// Per atlas tile, its records in ascending pane order.
    pub tiles: Vec<Vec<TileRecord>>,
    clusters: usize,
}

impl TileBudget {
    pub fn new(prm: &Prm, layout: &TileLayout) -> TileBudget {
        let n = (prm.tiles_x() * prm.tiles_y()) as usize;
        let mut tiles: Vec<Vec<TileRecord>> = vec![Vec::new(); n];
        for (k, t) in prm.tiles().iter().enumerate() {
            let energy = stored_tile_energy(prm, layout, k);
            tiles[t.index as usize].push(TileRecord { pane: t.cluster, stored: k as u32, energy });
        }
        // Pane order (ties go to the lower cluster; lookups by pane); one tile per pane each.
        for list in &mut tiles {
            list.sort_by_key(|r| r.pane);
        }
        TileBudget { tiles, clusters: prm.clusters().len() }
    }
}

/// The atlas tiles around vertex (vx, vy) of the tile grid, in the order (vx-1, vy-1), (vx,
/// vy-1), (vx-1, vy), (vx, vy); those off the grid are None.
pub fn tiles_around(vx: usize, vy: usize, tiles_x: usize, tiles_y: usize) -> [Option<usize>; 4] {
    let at = |x: usize, y: usize| (x < tiles_x && y < tiles_y).then(|| y * tiles_x + x);
    [
        at(vx.wrapping_sub(1), vy.wrapping_sub(1)),
        at(vx, vy.wrapping_sub(1)),
        at(vx.wrapping_sub(1), vy),
        at(vx, vy),
    ]
}

/// The weights of the panes at one vertex of the tile grid under a budget of `k`, from the
/// records of the (up to four) tiles around it (`around`, each in pane order): every pane
/// stored there, once, in pane order, with its energy summed over them. The (at most) `k`
/// clusters with the largest `luminance(w_c) x energy` (positive only; ties to the lower
/// cluster) keep their weight; with `residual`, each group gets the light of its clusters left
/// out in the tiles that store the group's pane, over the group's energy there. Everything
/// else weighs 0.
pub fn vertex_weights(
    around: &[&[TileRecord]],
    weights: &[Vec3],
    group_of: &[u32],
    k: usize,
    residual: bool,
) -> Vec<(u32, Vec3)> {
    let c_count = weights.len();
    let mut panes: Vec<(u32, f32)> = Vec::new();
    for list in around {
        for r in *list {
            panes.push((r.pane, r.energy));
        }
    }
    panes.sort_by_key(|p| p.0);
    let mut merged: Vec<(u32, f32)> = Vec::with_capacity(panes.len());
    for (pane, e) in panes {
        match merged.last_mut() {
            Some(last) if last.0 == pane => last.1 += e,
            _ => merged.push((pane, e)),
        }
    }
    let mut scored: Vec<(f32, usize)> = merged
        .iter()
        .enumerate()
        .filter(|(_, p)| (p.0 as usize) < c_count)
        .map(|(i, p)| (luminance(weights[p.0 as usize]).abs() * p.1, i))
        .filter(|(s, _)| *s > 0.0)
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    scored.truncate(k);
    let mut chosen = vec![false; merged.len()];
    for &(_, i) in &scored {
        chosen[i] = true;
    }
    // Kept clusters, in pane order.
    let kept_panes: Vec<u32> = merged.iter().zip(&chosen).filter(|(_, &k)| k).map(|(p, _)| p.0).collect();
    let kept = |c: usize| kept_panes.binary_search(&(c as u32)).is_ok();
    merged
        .iter()
        .enumerate()
        .map(|(i, &(pane, energy))| {
            let p = pane as usize;
            let w = if p < c_count {
                if chosen[i] {
                    weights[p]
                } else {
                    Vec3::ZERO
                }
            } else {
                // The light of the group's clusters left out, in the tiles around that store
                // the group's pane (tile by tile, panes in order), over its energy there.
                let g = (p - c_count) as u32;
                let mut left = Vec3::ZERO;
                if residual && energy > 0.0 {
                    let stores = |l: &&&[TileRecord]| l.binary_search_by_key(&pane, |r| r.pane).is_ok();
                    for list in around.iter().filter(stores) {
                        for q in list.iter() {
                            let c = q.pane as usize;
                            if c < c_count && group_of.get(c) == Some(&g) && !kept(c) {
                                left += weights[c] * q.energy;
                            }
                        }
                    }
                    left /= energy;
                }
                left
            };
            (pane, w)
        })
        .collect()
}

/// The blend of a pane's four vertex weights (`[(0,0), (1,0), (0,1), (1,1)]` corners of the
/// tile) at texel offset `(x, y)` within a tile of side `ts`: bilinear in the texel's centre.
pub fn blend(corners: &[Vec3; 4], x: usize, y: usize, ts: usize) -> Vec3 {
    // Equal corners: that weight, exactly (the GPU reads just the first).
    if corners[1..].iter().all(|c| *c == corners[0]) {
        return corners[0];
    }
    let (fx, fy) = ((x as f32 + 0.5) / ts as f32, (y as f32 + 0.5) / ts as f32);
    (corners[0] * (1.0 - fx) + corners[1] * fx) * (1.0 - fy)
        + (corners[2] * (1.0 - fx) + corners[3] * fx) * fy
}

/// What [`compose_local`] did besides the lightmap.
pub struct LocalCompose {
    pub lightmap: Vec<Vec3>,
    /// Per cluster: some vertex kept it.
    pub kept: Vec<bool>,
    /// Per atlas tile: the stored tiles summed there (panes any of its vertices weighs).
    pub summed: Vec<u32>,
}

/// The lightmap under a local budget of `k` panes picked per vertex of the tile grid (weights
/// `weights`), with, under `residual`, the groups standing in for the
/// clusters each vertex leaves out; each pane's weight blended from its tile's corners.
pub fn compose_local(
    prm: &Prm,
    budget: &TileBudget,
    layout: &TileLayout,
    weights: &[Vec3],
    k: usize,
    residual: bool,
) -> LocalCompose {
    assert_eq!(weights.len(), budget.clusters, "one weight per cluster");
    let (tx, ty) = (prm.tiles_x() as usize, prm.tiles_y() as usize);
    let vertices: Vec<Vec<(u32, Vec3)>> = (0..(tx + 1) * (ty + 1))
        .map(|v| {
            let around: Vec<&[TileRecord]> = tiles_around(v % (tx + 1), v / (tx + 1), tx, ty)
                .iter()
                .flatten()
                .map(|&t| &budget.tiles[t][..])
                .collect();
            vertex_weights(&around, weights, prm.group_of(), k, residual)
        })
        .collect();
    let mut kept = vec![false; weights.len()];
    for list in &vertices {
        for &(pane, w) in list {
            if (pane as usize) < weights.len() && w != Vec3::ZERO {
                kept[pane as usize] = true;
            }
        }
    }
    let (w, ts) = (prm.atlas().0, prm.header().tile_size as usize);
    // Pane `pane`'s weight at vertex (vx, vy) (every pane of a tile is listed at its corners).
    let vertex = |vx: usize, vy: usize, pane: u32| -> Vec3 {
        let list = &vertices[vy * (tx + 1) + vx];
        list.binary_search_by_key(&pane, |p| p.0).map_or(Vec3::ZERO, |i| list[i].1)
    };
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    let mut summed = vec![0u32; budget.tiles.len()];
    for (t, records) in budget.tiles.iter().enumerate() {
        let (x0, y0) = (t % tx, t / tx);
        let texels = &layout.texels[t];
        for r in records {
            let c = [
                vertex(x0, y0, r.pane),
                vertex(x0 + 1, y0, r.pane),
                vertex(x0, y0 + 1, r.pane),
                vertex(x0 + 1, y0 + 1, r.pane),
            ];
            if c.iter().all(|v| *v == Vec3::ZERO) {
                continue;
            }
            summed[t] += 1;
            let s = r.stored as usize;
            let scale = prm.tiles()[s].scale;
            let data = &prm.data()[layout.offsets[s]..layout.offsets[s] + texels.len()];
            for (&texel, &v) in texels.iter().zip(data) {
                let (x, y) = (texel as usize % w as usize, texel as usize / w as usize);
                img[texel as usize] += blend(&c, x % ts, y % ts, ts) * scale * intensity(v);
            }
        }
    }
    LocalCompose { lightmap: img, kept, summed }
}
