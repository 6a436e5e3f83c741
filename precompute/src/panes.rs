//! Pane atlases: per-texel contributions become per-cluster panes, dilated, tiled and stored as
//! 8-bit logarithmic intensities with an RGB scale per tile (format in `prm::prm_file`).
//!
//! **Dropping tiles.** A cluster's light reaches mostly nearby surfaces; far tiles hold little.
//! For each pane, tiles are sorted by energy (sum of texel luminance) and the smallest are left
//! out while their total stays within `drop_threshold` of the pane's energy (default 1e-3: at
//! most 0.1 % of every pane's light is lost). The rule is relative to the pane, so the light a
//! cluster sends into a dim room is a small share of its total and goes first: at 1e-2 the
//! second room of two_rooms lost 12 % of its indirect light, at 1e-3 none measurable. The file
//! records the fraction dropped overall.
//!
//! Panes are dilated before tiling (the dilation of [`prm::TexelSet`] is linear, so a sum of
//! dilated panes is the dilated sum): the runtime's bilinear lookups need no extra pass.

use glam::Vec3;
use prm::prm_file::{dipole_code, intensity_code, Cluster, Dipole, Dipoles, Tile};
use prm::{luminance, Smoothing, TexelSet};
use rayon::prelude::*;

use crate::transport::{TexelDipoles, TexelPanes};

/// Tiles and their data for all clusters, plus drop statistics.
pub struct Tiled {
    pub clusters: Vec<Cluster>,
    /// Stored-texel mask (covered or dilated), packed.
    pub mask: Vec<u8>,
    pub tiles: Vec<Tile>,
    pub data: Vec<u8>,
    pub tiles_dropped: u32,
    pub dropped_energy: f64,
}

/// Build the pane atlases. `members` are the clusters' entries; `centroids` their means.
#[allow(clippy::too_many_arguments)]
pub fn tile_panes(
    set: &TexelSet,
    smoothing: Option<&Smoothing>,
    texel_panes: &[TexelPanes],
    exact: &[TexelPanes],
    members: &[Vec<u32>],
    centroids: &[Vec3],
    tile_size: u32,
    drop_threshold: f64,
) -> Tiled {
    let grid = Grid::new(set, tile_size);
    let stored = stored_mask(set);
    let (start, by_cluster) = transpose(texel_panes, members.len(), |k, i| texel_panes[k][i].1);
    let (exact_start, exact_by_cluster) = transpose(exact, members.len(), |k, i| exact[k][i].1);
    let panes: Vec<PaneOut> = (0..members.len())
        .into_par_iter()
        .map(|c| {
            let exact = &exact_by_cluster[exact_start[c]..exact_start[c + 1]];
            let img = pane_image(set, smoothing, &by_cluster[start[c]..start[c + 1]], exact);
            encode_pane(set, &grid, &stored, &img, drop_threshold)
        })
        .collect();
    assemble(panes, members, centroids, &stored)
}

/// The atlas cut into square tiles, row-major.
struct Grid {
    w: usize,
    h: usize,
    ts: usize,
    tx: usize,
    ty: usize,
}

impl Grid {
    fn new(set: &TexelSet, tile_size: u32) -> Self {
        let (w, h, ts) = (set.width as usize, set.height as usize, tile_size as usize);
        Grid { w, h, ts, tx: w.div_ceil(ts), ty: h.div_ceil(ts) }
    }

    /// Row-major atlas texels of tile `index`, in row-major order.
    fn texels(&self, index: usize) -> impl Iterator<Item = usize> + '_ {
        let (i, j) = (index % self.tx, index / self.tx);
        (j * self.ts..((j + 1) * self.ts).min(self.h))
            .flat_map(move |y| (i * self.ts..((i + 1) * self.ts).min(self.w)).map(move |x| y * self.w + x))
    }
}

/// Texels a pane stores: covered or a dilation target.
fn stored_mask(set: &TexelSet) -> Vec<bool> {
    let mut stored = set.mask();
    for d in &set.dilation {
        stored[d.target as usize] = true;
    }
    stored
}

/// Texel-major contributions as cluster-major lists (a counting sort): cluster c's
/// (texel, value) pairs are `list[start[c]..start[c + 1]]`, in texel order; `value(k, i)` is
/// what texel k's i-th contribution carries.
fn transpose<T: Copy + Default>(
    texel_panes: &[TexelPanes],
    clusters: usize,
    value: impl Fn(usize, usize) -> T,
) -> (Vec<usize>, Vec<(u32, T)>) {
    let mut counts = vec![0usize; clusters];
    for tp in texel_panes {
        for &(c, _) in tp {
            counts[c as usize] += 1;
        }
    }
    let mut start = vec![0usize; clusters + 1];
    for c in 0..clusters {
        start[c + 1] = start[c] + counts[c];
    }
    let mut fill = start.clone();
    let mut list = vec![(0u32, T::default()); start[clusters]];
    for (k, tp) in texel_panes.iter().enumerate() {
        for (i, &(c, _)) in tp.iter().enumerate() {
            list[fill[c as usize]] = (k as u32, value(k, i));
            fill[c as usize] += 1;
        }
    }
    (start, list)
}

/// One pane as a full-atlas image: its texels' walked values smoothed with `smoothing`, plus the
/// part known exactly (`exact`: the near links' first bounce, sharp where a texel meets a
/// wall, so not smoothed), dilated.
fn pane_image(
    set: &TexelSet,
    smoothing: Option<&Smoothing>,
    contributions: &[(u32, Vec3)],
    exact: &[(u32, Vec3)],
) -> Vec<Vec3> {
    let w = set.width as usize;
    let at = |t: &prm::Texel| t.j as usize * w + t.i as usize;
    let mut img = vec![Vec3::ZERO; w * set.height as usize];
    for &(k, v) in contributions {
        img[at(&set.texels[k as usize])] = v;
    }
    if let Some(smoothing) = smoothing {
        smoothing.apply(&mut img);
    }
    for &(k, v) in exact {
        img[at(&set.texels[k as usize])] += v;
    }
    set.dilate(&mut img);
    img
}

/// One pane's stored tiles and what its dropped tiles held.
struct PaneOut {
    /// Signed luminance over the covered texels (the runtime's ranking energy).
    energy: f32,
    /// (atlas tile, RGB scale, half-float intensities of the stored texels).
    tiles: Vec<(u32, Vec3, Vec<u8>)>,
    dropped: u32,
    dropped_energy: f64,
    total_energy: f64,
}

fn encode_pane(set: &TexelSet, grid: &Grid, stored: &[bool], img: &[Vec3], drop_threshold: f64) -> PaneOut {
    let w = grid.w;
    let energy: f64 = set.texels.iter().map(|t| luminance(img[t.j as usize * w + t.i as usize]) as f64).sum();
    let tiles = tile_energies(grid, img);
    let total: f64 = tiles.iter().map(|t| t.1).sum();
    let (keep, dropped, dropped_energy) = drop_tiles(&tiles, drop_threshold * total);
    let tiles = tiles
        .iter()
        .zip(&keep)
        .filter(|(_, &k)| k)
        .map(|(&(index, _), _)| {
            let vals: Vec<Vec3> =
                grid.texels(index as usize).filter(|&k| stored[k]).map(|k| img[k]).collect();
            let (scale, data) = encode_tile(&vals);
            (index, scale, data)
        })
        .collect();
    PaneOut { energy: energy as f32, tiles, dropped, dropped_energy, total_energy: total }
}

/// The tiles holding any non-zero texel, with their energy (sum of |luminance|).
fn tile_energies(grid: &Grid, img: &[Vec3]) -> Vec<(u32, f64)> {
    let mut tiles = Vec::new();
    for index in 0..grid.tx * grid.ty {
        let mut e = 0.0f64;
        let mut any = false;
        for k in grid.texels(index) {
            if img[k] != Vec3::ZERO {
                any = true;
                e += luminance(img[k]).abs() as f64;
            }
        }
        if any {
            tiles.push((index as u32, e));
        }
    }
    tiles
}

/// Which tiles to keep: the weakest go while their total stays within `budget` (ties by
/// index). Returns the keep flags, the count dropped and the energy dropped.
fn drop_tiles(tiles: &[(u32, f64)], budget: f64) -> (Vec<bool>, u32, f64) {
    let mut order: Vec<usize> = (0..tiles.len()).collect();
    order.sort_by(|&a, &b| tiles[a].1.total_cmp(&tiles[b].1).then(a.cmp(&b)));
    let mut keep = vec![true; tiles.len()];
    let (mut dropped, mut dropped_energy) = (0u32, 0.0f64);
    for &k in &order {
        if dropped_energy + tiles[k].1 > budget {
            break;
        }
        dropped_energy += tiles[k].1;
        dropped += 1;
        keep[k] = false;
    }
    (keep, dropped, dropped_energy)
}

/// A tile's stored texels as an RGB scale (the mean chromaticity at luminance 1, times the
/// peak luminance) and intensity codes (luminance over the peak, `prm::prm_file::intensity`).
fn encode_tile(vals: &[Vec3]) -> (Vec3, Vec<u8>) {
    let (sum, sum_y) = vals
        .iter()
        .fold((Vec3::ZERO, 0.0f32), |(s, y), v| (s + v.max(Vec3::ZERO), y + luminance(v.max(Vec3::ZERO))));
    let chroma = if sum_y > 0.0 { sum / sum_y } else { Vec3::ONE };
    let peak =
        vals.iter().map(|v| luminance(v.max(Vec3::ZERO))).fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
    let data = vals.iter().map(|v| intensity_code(luminance(v.max(Vec3::ZERO)) / peak)).collect();
    (chroma * peak, data)
}

/// The panes in cluster order as clusters, tiles and data, with the drop statistics.
fn assemble(panes: Vec<PaneOut>, members: &[Vec<u32>], centroids: &[Vec3], stored: &[bool]) -> Tiled {
    let mut out = Tiled {
        clusters: Vec::with_capacity(members.len()),
        mask: prm::prm_file::pack_mask(stored),
        tiles: Vec::new(),
        data: Vec::new(),
        tiles_dropped: 0,
        dropped_energy: 0.0,
    };
    let (mut dropped_e, mut total_e) = (0.0f64, 0.0f64);
    for (c, p) in panes.into_iter().enumerate() {
        out.clusters.push(Cluster {
            members: members[c].clone(),
            centroid: centroids[c],
            energy: p.energy,
            first_tile: out.tiles.len() as u32,
            tile_count: p.tiles.len() as u32,
        });
        for (index, scale, data) in p.tiles {
            out.tiles.push(Tile { cluster: c as u32, index, scale });
            out.data.extend(data);
        }
        out.tiles_dropped += p.dropped;
        dropped_e += p.dropped_energy;
        total_e += p.total_energy;
    }
    out.dropped_energy = if total_e > 0.0 { dropped_e / total_e } else { 0.0 };
    out
}

/// The clusters' dipole panes (`prm::prm_file::Dipoles`): per cluster and used axis, the
/// texels' dipole responses smoothed and dilated like the panes (the smoothing matters more
/// here: a dipole pane is a difference of walks, noisier than its pane), averaged over `block`
/// x `block` blocks of stored texels, tiled, and stored as signed codes with an RGB scale per
/// tile; tiles are dropped by the same rule as the panes'. `dipoles` (from
/// `crate::dipole::frames`) gets its tile counts, first tiles and energies filled in.
#[allow(clippy::too_many_arguments)]
pub fn tile_dipoles(
    set: &TexelSet,
    smoothing: Option<&Smoothing>,
    texel_panes: &[TexelPanes],
    texel_dipoles: &[TexelDipoles],
    mut dipoles: Vec<Dipole>,
    tile_size: u32,
    block: u32,
    drop_threshold: f64,
) -> Dipoles {
    let grid = Grid::new(set, tile_size);
    let stored = stored_mask(set);
    let clusters = dipoles.len();
    let b = block as usize;
    let (bw, bh) = (grid.w.div_ceil(b), grid.h.div_ceil(b));
    let mut count = vec![0u32; bw * bh];
    for (k, _) in stored.iter().enumerate().filter(|(_, s)| **s) {
        count[(k / grid.w / b) * bw + (k % grid.w) / b] += 1;
    }
    let (start, list) = transpose(texel_panes, clusters, |k, i| texel_dipoles[k][i]);
    let per_axis: Vec<(f32, Vec<EncodedTile>)> = (0..clusters * 3)
        .into_par_iter()
        .map(|pk| {
            let (c, k) = (pk / 3, pk % 3);
            if dipoles[c].axes[k].inv_lambda == 0.0 {
                return (0.0, Vec::new());
            }
            let axis: Vec<(u32, Vec3)> =
                list[start[c]..start[c + 1]].iter().map(|&(t, d)| (t, d[k])).collect();
            let img = pane_image(set, smoothing, &axis, &[]);
            let w = grid.w;
            let energy: f64 =
                set.texels.iter().map(|t| luminance(img[t.j as usize * w + t.i as usize]) as f64).sum();
            let mut means = vec![Vec3::ZERO; bw * bh];
            for (k, v) in img.iter().enumerate() {
                if stored[k] {
                    means[(k / w / b) * bw + (k % w) / b] += *v;
                }
            }
            for (m, &n) in means.iter_mut().zip(&count) {
                if n > 0 {
                    *m /= n as f32;
                }
            }
            (energy as f32, encode_dipole(&grid, &means, &count, b, bw, drop_threshold))
        })
        .collect();
    let mut out = Dipoles { block, clusters: Vec::new(), tiles: Vec::new(), data: Vec::new() };
    for (pk, (energy, tiles)) in per_axis.into_iter().enumerate() {
        let (c, k) = (pk / 3, pk % 3);
        if k == 0 {
            dipoles[c].first_tile = out.tiles.len() as u32;
        }
        dipoles[c].axes[k].energy = energy;
        dipoles[c].axes[k].tile_count = tiles.len() as u32;
        for (index, scale, data) in tiles {
            out.tiles.push(Tile { cluster: pk as u32, index, scale });
            out.data.extend(data);
        }
    }
    out.clusters = dipoles;
    out
}
/// A stored tile: (atlas tile, RGB scale, codes).
type EncodedTile = (u32, Vec3, Vec<u8>);

/// One dipole pane's kept tiles from its block means (`bw` blocks a row; `count`: covered
/// texels per block): (atlas tile, RGB scale, one code per block of the tile, row-major).
fn encode_dipole(
    grid: &Grid,
    means: &[Vec3],
    count: &[u32],
    b: usize,
    bw: usize,
    drop_threshold: f64,
) -> Vec<EncodedTile> {
    let side = grid.ts.div_ceil(b);
    let bh = means.len() / bw;
    let blocks: Vec<(u32, Vec<Vec3>, f64)> = (0..grid.tx * grid.ty)
        .filter_map(|index| {
            let (ti, tj) = (index % grid.tx, index / grid.tx);
            let mut vals = vec![Vec3::ZERO; side * side];
            let mut energy = 0.0f64;
            for (q, v) in vals.iter_mut().enumerate() {
                let (x, y) = (ti * side + q % side, tj * side + q / side);
                if x < bw && y < bh {
                    *v = means[y * bw + x];
                    energy += (luminance(*v).abs() * count[y * bw + x] as f32) as f64;
                }
            }
            (energy > 0.0).then_some((index as u32, vals, energy))
        })
        .collect();
    let energies: Vec<(u32, f64)> = blocks.iter().map(|(i, _, e)| (*i, *e)).collect();
    let total: f64 = energies.iter().map(|t| t.1).sum();
    let (keep, _, _) = drop_tiles(&energies, drop_threshold * total);
    blocks
        .into_iter()
        .zip(keep)
        .filter(|(_, k)| *k)
        .map(|((index, vals, _), _)| {
            let (sum, sum_y) =
                vals.iter().fold((Vec3::ZERO, 0.0f32), |(s, y), v| (s + v.abs(), y + luminance(*v).abs()));
            let chroma = if sum_y > 0.0 { sum / sum_y } else { Vec3::ONE };
            let peak = vals.iter().map(|v| luminance(*v).abs()).fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
            let data = vals.iter().map(|v| dipole_code(luminance(*v) / peak)).collect();
            (index, chroma * peak, data)
        })
        .collect()
}
