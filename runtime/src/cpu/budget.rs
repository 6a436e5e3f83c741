//! Local pane budgets (the runtime's default selection): every atlas tile composes the K
//! clusters that bring it the most light, `luminance(w_c) x` the energy of pane c's stored tile
//! there, and each group's tile there stands in for that tile's other clusters of the group.
//!
//! A global top-K spends its budget on the clusters that light the level most; a texel far from
//! them gets only the groups' coarse panes. Per tile, every region of the atlas gets the K panes
//! that matter to it, and the compose still reads at most K + G records per texel. The group's
//! weight is local too: `r_g(t) = sum over g's clusters c left out in t of w_c E_c(t) / E_g(t)`
//! (E: the stored tile's luminance energy), so each tile keeps the energy of composing
//! everything, up to the codes' rounding. With K at least the clusters stored in a tile, the
//! tile is exactly the all-panes compose.
//!
//! `shaders/compose.wgsl`'s `gather_main` is the GPU twin, held to [`compose_local`] by the tests.

use glam::Vec3;
use prm::luminance;
use prm::prm_file::{dipole_value, intensity, Prm, TileLayout};

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
    /// Per atlas tile, its records, panes in ascending order.
    pub tiles: Vec<Vec<TileRecord>>,
    /// Per atlas tile, its dipole tiles (index into `Dipoles::tiles`, whose `cluster` is
    /// `3 c + axis`).
    pub dipoles: Vec<Vec<u32>>,
}

impl TileBudget {
    pub fn new(prm: &Prm, layout: &TileLayout) -> TileBudget {
        let n = (prm.tiles_x() * prm.tiles_y()) as usize;
        let mut tiles: Vec<Vec<TileRecord>> = vec![Vec::new(); n];
        for (k, t) in prm.tiles().iter().enumerate() {
            let energy = stored_tile_energy(prm, layout, k);
            tiles[t.index as usize].push(TileRecord { pane: t.cluster, stored: k as u32, energy });
        }
        // Pane order (ties go to the lower cluster); a pane has one tile per atlas tile.
        for list in &mut tiles {
            list.sort_by_key(|r| r.pane);
        }
        let mut dipoles = vec![Vec::new(); n];
        for (k, t) in prm.dipoles().tiles.iter().enumerate() {
            dipoles[t.index as usize].push(k as u32);
        }
        TileBudget { tiles, dipoles }
    }

    /// The most cluster records any atlas tile holds: a K at least this composes everything.
    pub fn most_clusters(&self, clusters: usize) -> usize {
        self.tiles
            .iter()
            .map(|l| l.iter().filter(|r| (r.pane as usize) < clusters).count())
            .max()
            .unwrap_or(0)
    }
}

/// Which of an atlas tile's records are composed, and with what weight: the (at most) `k`
/// cluster records with the largest `luminance(w_c) x energy` (positive only; ties to the
/// lower cluster), then, with `residual`, every group record weighted by its left-out clusters'
/// light there. Returns (record index, weight) pairs, records in order.
pub fn tile_selection(
    records: &[TileRecord],
    weights: &[Vec3],
    group_of: &[u32],
    k: usize,
    residual: bool,
) -> Vec<(usize, Vec3)> {
    let c_count = weights.len();
    let score = |r: &TileRecord| luminance(weights[r.pane as usize]) * r.energy;
    let mut scored: Vec<(f32, usize)> = records
        .iter()
        .enumerate()
        .filter(|(_, r)| (r.pane as usize) < c_count)
        .map(|(i, r)| (score(r), i))
        .filter(|(s, _)| *s > 0.0)
        .collect();
    // Records are in pane order, so the index breaks ties as the cluster would.
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    scored.truncate(k);
    let mut chosen = vec![false; records.len()];
    for &(_, i) in &scored {
        chosen[i] = true;
    }
    let mut out: Vec<(usize, Vec3)> = Vec::new();
    for (i, r) in records.iter().enumerate() {
        let pane = r.pane as usize;
        if pane < c_count {
            if chosen[i] {
                out.push((i, weights[pane]));
            }
        } else if residual && r.energy > 0.0 {
            let g = (pane - c_count) as u32;
            let mut left = Vec3::ZERO;
            for (j, q) in records.iter().enumerate() {
                let c = q.pane as usize;
                if c < c_count && !chosen[j] && group_of.get(c) == Some(&g) {
                    left += weights[c] * q.energy;
                }
            }
            if left != Vec3::ZERO {
                out.push((i, left / r.energy));
            }
        }
    }
    out
}

/// The lightmap under a local budget of `k` panes per atlas tile (weights `weights`, dipole
/// weights `moments`, empty for none; a selected cluster's dipole tiles come with it), plus,
/// with `residual`, the groups standing in for each tile's other clusters. Also returns, per
/// cluster, whether some tile composed it.
pub fn compose_local(
    prm: &Prm,
    budget: &TileBudget,
    layout: &TileLayout,
    weights: &[Vec3],
    moments: &[[Vec3; 3]],
    k: usize,
    residual: bool,
) -> (Vec<Vec3>, Vec<bool>) {
    let mut img = vec![Vec3::ZERO; prm.texel_count()];
    let mut composed_anywhere = vec![false; weights.len()];
    let (d, w) = (prm.dipoles(), prm.atlas().0 as usize);
    let ts = prm.header().tile_size as usize;
    let (block, codes) = (d.block.max(1) as usize, d.tile_codes(prm.header().tile_size));
    let side = ts.div_ceil(block);
    for (t, records) in budget.tiles.iter().enumerate() {
        let texels = &layout.texels[t];
        let selection = tile_selection(records, weights, prm.group_of(), k, residual);
        for &(i, weight) in &selection {
            if let Some(c) = composed_anywhere.get_mut(records[i].pane as usize) {
                *c = true;
            }
            let s = records[i].stored as usize;
            let scale = weight * prm.tiles()[s].scale;
            let data = &prm.data()[layout.offsets[s]..layout.offsets[s] + texels.len()];
            for (&texel, &v) in texels.iter().zip(data) {
                img[texel as usize] += scale * intensity(v);
            }
        }
        for &dt in &budget.dipoles[t] {
            let tile = &d.tiles[dt as usize];
            let (c, axis) = (tile.cluster as usize / 3, tile.cluster as usize % 3);
            let composed = selection.iter().any(|&(i, _)| records[i].pane as usize == c);
            let Some(m) = moments.get(c).map(|m| m[axis]) else { continue };
            if !composed || m == Vec3::ZERO {
                continue;
            }
            let s = m * tile.scale;
            let data = &d.data[dt as usize * codes..(dt as usize + 1) * codes];
            for &texel in texels {
                let (x, y) = (texel as usize % w, texel as usize / w);
                img[texel as usize] += s * dipole_value(data[((y % ts) / block) * side + (x % ts) / block]);
            }
        }
    }
    (img, composed_anywhere)
}
