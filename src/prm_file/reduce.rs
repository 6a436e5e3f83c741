//! A map for fewer receivers: the same map with some atlas tiles left out, for a runtime whose
//! GPU memory budget cannot hold the whole map (`prm_runtime::budget`).
//!
//! Leaving out an atlas tile removes everything the map stores *at* its texels: the panes',
//! and groups' tiles there, the texels' mask bits, their near-field links and points
//! (with the echo links that touch them) and their far-field texels. Nothing that *sends* light
//! is removed: every entry, cell, cluster and the far field's entry visibility stay, so the
//! light that reaches a kept texel from anywhere in the level still arrives. The left-out texels
//! get no indirect light at all.
//!
//! Every pane keeps its energy, the whole pane's: the runtime ranks panes and balances each
//! cluster's weight against its near field with it, and the pick and the weights should stay
//! the whole map's. (Scaling each energy by the share of its light that stays was tried: the
//! kept texels then moved by 21 % RMS on two halls with one left out, against 0.9 % without.)
//! The same holds for the energy the near links deliver (`Prm::link_energy`), which the
//! balance counts beside the far field's: the energy of the links cut is added to each entry's
//! `Far::energy`, so the cluster weights are the whole map's. (Without it, on two halls with one
//! left out, the kept texels inside moved by 2.5 % RMS.) What still moves kept texels: a tile
//! grid vertex next to a left-out tile picks its K panes without that tile's records; the
//! near field's echo loses the links that were cut; and the lift reads the near field's mean
//! over a cell's kept texels. The tests measure them. When every far-field texel goes, the far
//! field goes whole, with its entries' energies, and the balance then counts the kept near
//! links alone (the format has no far field without texels); so does a map baked without a
//! far field.

use super::{intensity, Echo, EchoLink, Far, InvalidPrm, Prm, PrmParts, Tile};
use crate::luminance;

/// What [`Prm::without_atlas_tiles`] left out.
#[derive(Clone, Debug, PartialEq)]
pub struct Reduced {
    pub prm: Prm,
    /// Atlas tiles that held stored texels and were left out.
    pub atlas_tiles: usize,
    /// Stored texels left out.
    pub texels: usize,
    /// Stored pane tiles (panes' and groups') left out.
    pub pane_tiles: usize,
    /// The share of the clusters' pane energy in the tiles left out (0 ..= 1).
    pub energy_share: f64,
}

impl Prm {
    /// This map without the atlas tiles where `drop[index]` is true (row-major over the tile
    /// grid; missing entries are kept). See the module docs for what goes and what stays.
    pub fn without_atlas_tiles(&self, drop: &[bool]) -> Result<Reduced, InvalidPrm> {
        let h = &self.parts.header;
        let dropped = |index: u32| drop.get(index as usize).copied().unwrap_or(false);
        let texel_dropped = |k: u32| dropped(self.atlas_tile_of(k) as u32);
        let layout = self.layout();
        let p = &self.parts;

        // Panes: keep the tiles outside the cut, in order, and measure the share of each
        // pane's stored light that goes (for the report; the energies stay, see the docs).
        let codes = |k: usize, tile: &Tile| {
            let start = layout.offsets[k];
            &p.data[start..start + layout.texels[tile.index as usize].len()]
        };
        let mut tiles = Vec::with_capacity(p.tiles.len());
        let mut data = Vec::with_capacity(p.data.len());
        let mut kept_mass = vec![0.0f64; self.pane_count()];
        let mut all_mass = vec![0.0f64; self.pane_count()];
        for (k, tile) in p.tiles.iter().enumerate() {
            let m = codes(k, tile).iter().map(|&c| intensity(c) as f64).sum::<f64>()
                * luminance(tile.scale) as f64;
            all_mass[tile.cluster as usize] += m;
            if !dropped(tile.index) {
                kept_mass[tile.cluster as usize] += m;
                data.extend_from_slice(codes(k, tile));
                tiles.push(*tile);
            }
        }
        // The new ranges: the kept tiles before each old first tile.
        let kept_before = prefix_counts(p.tiles.iter().map(|t| !dropped(t.index)));
        let range = |first: u32, count: u32| {
            let start = kept_before[first as usize];
            (start, kept_before[(first + count) as usize] - start)
        };
        let mut clusters = p.clusters.clone();
        let (mut energy, mut energy_cut) = (0.0f64, 0.0f64);
        for (c, cl) in clusters.iter_mut().enumerate() {
            (cl.first_tile, cl.tile_count) = range(cl.first_tile, cl.tile_count);
            energy += cl.energy as f64;
            if all_mass[c] > 0.0 {
                energy_cut += cl.energy as f64 * (1.0 - kept_mass[c] / all_mass[c]);
            }
        }
        let mut groups = p.groups.clone();
        for gr in &mut groups {
            (gr.first_tile, gr.tile_count) = range(gr.first_tile, gr.tile_count);
        }

        let (near, near_points, echo) =
            without_near_texels(p, &texel_dropped, h.atlas_width * h.atlas_height);
        let mut far = without_far_texels(&p.far, &texel_dropped);
        // The links cut go on counting in the balance, as the far field's energy: the weights
        // stay the whole map's (see the module docs).
        let kept_energy = super::link_energy(&p.entries, &near, &echo, near_points.len());
        for ((f, whole), kept) in far.energy.iter_mut().zip(self.link_energy()).zip(kept_energy) {
            *f += whole - kept;
        }

        let mut mask = p.mask.clone();
        let mut texels = 0;
        let mut atlas_tiles = 0;
        for (index, list) in layout.texels.iter().enumerate() {
            if list.is_empty() || !dropped(index as u32) {
                continue;
            }
            atlas_tiles += 1;
            texels += list.len();
            for &k in list {
                mask[k as usize / 8] &= !(1 << (k % 8));
            }
        }
        let pane_tiles = p.tiles.len() - tiles.len();
        let mut header = h.clone();
        header.tiles = tiles.len() as u32;
        let parts = PrmParts {
            header,
            entries: p.entries.clone(),
            stays: p.stays.clone(),
            gains: p.gains.clone(),
            cells: p.cells.clone(),
            near,
            near_points,
            echo,
            clusters,
            groups,
            group_of: p.group_of.clone(),
            tiles,
            mask,
            data,
            far,
        };
        let energy_share = if energy > 0.0 { energy_cut / energy } else { 0.0 };
        Ok(Reduced {
            prm: Prm::new(parts)?,
            atlas_tiles,
            texels,
            pane_tiles,
            energy_share: energy_share.clamp(0.0, 1.0),
        })
    }
}

impl Prm {
    /// This map with its echo reading every source at its texel's point, as before v16: no
    /// crease points ([`Echo::creases`]), each echo link that read one reading its texel again.
    /// For a side-by-side measure of what they bring.
    pub fn without_creases(&self) -> Result<Prm, InvalidPrm> {
        let mut parts = self.parts.clone();
        let points = parts.near_points.len();
        let first = parts.echo.first_crease(points);
        let echo = &mut parts.echo;
        for k in 0..echo.links.len() {
            echo.links[k].source = echo.echo_of(echo.links[k].source as usize, points) as u32;
        }
        echo.links.sort_by_key(|l| (l.receiver, l.source));
        echo.albedo.truncate(first);
        echo.creases.clear();
        let texels = self.texel_count() as u32;
        parts.near.retain(|l| l.texel < texels);
        parts.near_points.truncate(first);
        Prm::new(parts)
    }
}

/// `out[k]` = how many of the first k flags are set (k = 0 ..= len).
fn prefix_counts(flags: impl Iterator<Item = bool>) -> Vec<u32> {
    let mut out = vec![0u32];
    for f in flags {
        out.push(out.last().copied().unwrap_or(0) + f as u32);
    }
    out
}

/// The near field without the links, points and echo of dropped texels (echo links re-indexed
/// to the points that stay). A crease point goes with its texel's point, and those that stay
/// take the texel numbers past the atlas's (`texels`) again, in order.
fn without_near_texels(
    p: &PrmParts,
    dropped: &dyn Fn(u32) -> bool,
    texels: u32,
) -> (Vec<super::NearLink>, Vec<super::NearPoint>, Echo) {
    let first_crease = p.echo.first_crease(p.near_points.len());
    let keep: Vec<bool> = p
        .near_points
        .iter()
        .enumerate()
        .map(|(k, pt)| {
            let own = p.echo.echo_of(k, p.near_points.len());
            match p.near_points.get(own) {
                Some(parent) if k >= first_crease => !dropped(parent.texel),
                _ => !dropped(pt.texel),
            }
        })
        .collect();
    let index = prefix_counts(keep.iter().copied());
    let kept = |i: u32| keep.get(i as usize).copied().unwrap_or(false);
    // A crease point's texel number after the cut: the atlas's count plus the creases kept
    // before it.
    let kept_before = index[first_crease];
    let renumber = |texel: u32| match (texel as u64).checked_sub(texels as u64) {
        Some(k) => texels + index[first_crease + k as usize] - kept_before,
        None => texel,
    };
    let point_of_texel = |texel: u32| match (texel as u64).checked_sub(texels as u64) {
        Some(k) => kept(first_crease as u32 + k as u32),
        None => !dropped(texel),
    };
    let near = p
        .near
        .iter()
        .filter(|l| point_of_texel(l.texel))
        .map(|l| super::NearLink { texel: renumber(l.texel), ..*l })
        .collect();
    let near_points = p
        .near_points
        .iter()
        .zip(&keep)
        .filter(|(_, &k)| k)
        .map(|(pt, _)| super::NearPoint { texel: renumber(pt.texel), ..*pt })
        .collect();
    let creases = p
        .echo
        .creases
        .iter()
        .enumerate()
        .filter(|&(k, _)| kept((first_crease + k) as u32))
        .map(|(_, &parent)| index[parent as usize])
        .collect();
    let echo = Echo {
        albedo: p.echo.albedo.iter().zip(&keep).filter(|(_, &k)| k).map(|(a, _)| *a).collect(),
        links: p
            .echo
            .links
            .iter()
            .filter(|l| kept(l.receiver) && kept(l.source))
            .map(|l| EchoLink {
                receiver: index[l.receiver as usize],
                source: index[l.source as usize],
                ..*l
            })
            .collect(),
        creases,
    };
    (near, near_points, echo)
}

/// The far field without dropped texels; none at all when no texel stays (its entry energies
/// then reach no receiver).
fn without_far_texels(f: &Far, dropped: &dyn Fn(u32) -> bool) -> Far {
    let kept: Vec<usize> = (0..f.texels.len()).filter(|&k| !dropped(f.texels[k].texel)).collect();
    if kept.is_empty() {
        return Far::default();
    }
    let texels = kept.iter().map(|&k| f.texels[k]).collect();
    let areas = if f.areas.is_empty() { Vec::new() } else { kept.iter().map(|&k| f.areas[k]).collect() };
    Far { texels, areas, ..f.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prm_file::FarTexel;

    /// A far texel left out takes its area with it; the others keep theirs, in order.
    #[test]
    fn the_far_texels_left_out_take_their_areas() {
        let texel = |t: u32| FarTexel { texel: t, ..Default::default() };
        let far =
            Far { texels: vec![texel(2), texel(5), texel(9)], areas: vec![0.1, 0.2, 0.3], ..Far::default() };
        let kept = without_far_texels(&far, &|t| t == 5);
        assert_eq!(kept.texels.iter().map(|t| t.texel).collect::<Vec<_>>(), vec![2, 9]);
        assert_eq!(kept.areas, vec![0.1, 0.3]);
        // A map before v17 has none to keep.
        let old = Far { areas: Vec::new(), ..far };
        assert!(without_far_texels(&old, &|t| t == 5).areas.is_empty());
    }
}
