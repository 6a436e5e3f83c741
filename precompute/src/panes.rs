//! Pane atlases: per-texel contributions become per-cluster panes, dilated, tiled and stored as
//! 8-bit logarithmic intensities with an RGB scale per tile (format in `prm::prm_file`).
//!
//! **A band at a time.** The walks are not held for the whole atlas: the precompute walks the
//! texels of a band of tile rows ([`BAND_TILE_ROWS`]), plus a margin of the smoothing's and the
//! dilation's reach above and below ([`Encoder::bands`]), encodes every pane's tiles in that
//! band ([`Encoder::encode_band`]), and frees the walks that no later band needs. Smoothing
//! and dilation read at most `margin` rows away, so a band's tiles are exactly those of the
//! whole-atlas pane (the same bytes), while the memory the walks take is a band's, not the
//! level's: on the 4 x 4 halls the walks of every texel took 330 MB.
//!
//! **Dropping tiles.** A cluster's light reaches mostly nearby surfaces; far tiles hold little.
//! For each pane, tiles are sorted by energy (sum of texel luminance) and the smallest are left
//! out while their total stays within `drop_threshold` of the pane's energy (default 1e-3: at
//! most 0.1 % of every pane's light is lost). The rule is relative to the pane, so the light a
//! cluster sends into a dim room is a small share of its total and goes first: at 1e-2 the
//! second room of two_rooms lost 12 % of its indirect light, at 1e-3 none measurable. The file
//! records the fraction dropped overall. The rule needs the pane's whole energy, so tiles are
//! encoded as the bands pass ([`Accumulated`]) and dropped once all have.
//!
//! Panes are dilated before tiling (the dilation of [`prm::TexelSet`] is linear, so a sum of
//! dilated panes is the dilated sum): the runtime's bilinear lookups need no extra pass.

use std::ops::Range;

use glam::Vec3;
use prm::prm_file::{intensity_code, Cluster, Group, Tile};
use prm::{luminance, Smoothing, TexelSet};
use rayon::prelude::*;

use crate::transport::TexelPanes;
use crate::update::CachedTile;

/// Tile rows a band encodes at once, by default. With the margin (at most 17 rows each side)
/// a band of 1 holds the walks of up to 50 texel rows; taller bands hold more walks, shorter
/// ones smooth the margins' texels more often (walked once, smoothed once per band they are
/// in). 4 rows took more memory on the 4 x 4 halls, in the same time; on the 16 chambers,
/// where every texel's walks name every cluster of its room, 2 rows held 264 MB of walks and
/// exact first bounce at their largest band and 1 row 144 MB, in the same time.
pub const BAND_TILE_ROWS: u32 = 1;

/// Tiles and their data for all panes (clusters, then groups), plus drop statistics.
pub struct Tiled {
    pub clusters: Vec<Cluster>,
    pub groups: Vec<Group>,
    /// Stored-texel mask (covered or dilated), packed.
    pub mask: Vec<u8>,
    pub tiles: Vec<Tile>,
    pub data: Vec<u8>,
    /// Tiles dropped from the clusters' panes (the groups' are not counted).
    pub tiles_dropped: u32,
    /// The share of the clusters' pane energy dropped.
    pub dropped_energy: f64,
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

/// One band: the tile rows it encodes, their texel rows, and the texel rows whose walks those
/// need (the rows widened by the encoder's margin, within the atlas).
#[derive(Clone, Debug, PartialEq)]
pub struct Band {
    pub tile_rows: Range<usize>,
    pub rows: Range<u32>,
    pub window: Range<u32>,
}

/// Encodes panes a band at a time (module doc).
pub struct Encoder<'a> {
    set: &'a TexelSet,
    smoothing: Option<&'a Smoothing>,
    grid: Grid,
    stored: Vec<bool>,
    /// Walked rows a band needs beyond its own: the smoothing's reach and the dilation's row.
    margin: u32,
    /// Columns a pane's smoothed and dilated light reaches beyond its own texels.
    column_margin: u32,
    /// Tile rows per band.
    band_tile_rows: usize,
}

impl<'a> Encoder<'a> {
    pub fn new(
        set: &'a TexelSet,
        smoothing: Option<&'a Smoothing>,
        tile_size: u32,
        band_tile_rows: u32,
    ) -> Self {
        let margin = smoothing.map_or(0, Smoothing::row_reach) + 1;
        let column_margin = smoothing.map_or(0, Smoothing::column_reach) + 1;
        let band_tile_rows = band_tile_rows.max(1) as usize;
        Encoder {
            set,
            smoothing,
            grid: Grid::new(set, tile_size),
            stored: stored_mask(set),
            margin,
            column_margin,
            band_tile_rows,
        }
    }

    /// The bands, top to bottom; their windows only move down.
    pub fn bands(&self) -> Vec<Band> {
        let h = self.grid.h as u32;
        (0..self.grid.ty)
            .step_by(self.band_tile_rows)
            .map(|t0| {
                let tile_rows = t0..(t0 + self.band_tile_rows).min(self.grid.ty);
                let rows =
                    (tile_rows.start * self.grid.ts) as u32..((tile_rows.end * self.grid.ts) as u32).min(h);
                let window = rows.start.saturating_sub(self.margin)..(rows.end + self.margin).min(h);
                Band { tile_rows, rows, window }
            })
            .collect()
    }

    /// The covered texels (indices into `TexelSet::texels`, which are row-major) in `rows`.
    pub fn texel_range(&self, rows: Range<u32>) -> Range<usize> {
        let texels = &self.set.texels;
        texels.partition_point(|t| t.j < rows.start)..texels.partition_point(|t| t.j < rows.end)
    }

    /// Encode the band's tiles of `acc`'s panes into it (an error if its scratch file fails).
    /// `panes` and `exact` hold what each texel of the band's window gives each pane
    /// (texel-major from texel `first`; `exact` may be empty): the walked part, smoothed, and
    /// the exact part, added after smoothing.
    ///
    /// With `reuse` (`prm precompute --update`, `crate::update`), only the tiles it marks
    /// dirty are encoded; every other tile is the cached one (`reuse.1[c]`: pane c's cached
    /// tiles, in atlas order), and the pane's energy is carried over both alike.
    pub fn encode_band(
        &self,
        band: &Band,
        first: usize,
        panes: &[TexelPanes],
        exact: &[TexelPanes],
        acc: &mut Accumulated,
        reuse: Option<(&[bool], &[Vec<CachedTile>])>,
    ) -> std::io::Result<()> {
        // A few clusters at a time, so that the band's contributions are held once more per
        // chunk, not once more whole (with the walks' next bounce a texel names every
        // cluster of its room: on the 4 x 4 chambers that copy was 230 MB).
        for chunk in cluster_chunks(&[panes, exact], acc.len(), TRANSPOSE_ITEMS) {
            let ((start, list), (exact_start, exact_list)) = rayon::join(
                || transpose(panes, first, chunk.clone(), |k, i| panes[k][i].1),
                || transpose(exact, first, chunk.clone(), |k, i| exact[k][i].1),
            );
            let size = self.grid.w * band.window.len();
            let out: Vec<Option<PaneBand>> = chunk
                .clone()
                .into_par_iter()
                .map_init(
                    || vec![Vec3::ZERO; size],
                    |img, c| {
                        let j = c - chunk.start;
                        let walked = &list[start[j]..start[j + 1]];
                        let exact =
                            exact_start.get(j + 1).map_or(&[][..], |&e| &exact_list[exact_start[j]..e]);
                        let reuse = reuse.map(|(dirty, cached)| (dirty, &cached[c][..]));
                        let pane = if walked.is_empty() && exact.is_empty() {
                            self.encode_pane_band(band, None, &[], acc.energy[c], reuse)
                        } else {
                            // The pane's light in this band, and the runs of tile columns it
                            // reaches: work and clearing stay there, so a pane costs its own
                            // charts, not the band.
                            let tiles = self.footprint(walked.iter().chain(exact));
                            let ts = self.grid.ts as u32;
                            let cols: Vec<Range<u32>> =
                                tiles.iter().map(|t| t.start as u32 * ts..t.end as u32 * ts).collect();
                            self.band_image(band, walked, exact, img, &cols);
                            let pane = self.encode_pane_band(band, Some(img), &tiles, acc.energy[c], reuse);
                            let w = self.grid.w;
                            for row in img.chunks_mut(w) {
                                for c in &cols {
                                    row[c.start as usize..(c.end as usize).min(w)].fill(Vec3::ZERO);
                                }
                            }
                            pane
                        };
                        (!pane.tiles.is_empty()).then_some(pane)
                    },
                )
                .collect();
            acc.add(chunk.start, out)?;
        }
        Ok(())
    }

    /// Codes a stored pane tile holds, per atlas tile.
    pub fn tile_codes(&self) -> Vec<usize> {
        tile_codes(&self.grid, &self.stored)
    }

    /// Tiles across and down the atlas.
    pub fn tiles(&self) -> (usize, usize) {
        (self.grid.tx, self.grid.ty)
    }

    /// The runs of tile columns (ascending, apart) that the texels `values` name light, each
    /// texel's reach grown by the columns smoothing and dilation carry its light: two runs are
    /// independent, no texel's light reaching the other's columns.
    fn footprint<'v>(&self, values: impl Iterator<Item = &'v (u32, Vec3)>) -> Vec<Range<usize>> {
        let (m, ts, tx) = (self.column_margin as usize, self.grid.ts, self.grid.tx);
        let mut lit = vec![false; tx];
        for &(k, _) in values {
            let i = self.set.texels[k as usize].i as usize;
            let (lo, hi) = (i.saturating_sub(m) / ts, ((i + m) / ts).min(tx - 1));
            lit[lo..=hi].fill(true);
        }
        let mut runs: Vec<Range<usize>> = Vec::new();
        for (t, &on) in lit.iter().enumerate() {
            match runs.last_mut() {
                Some(r) if on && r.end == t => r.end = t + 1,
                _ if on => runs.push(t..t + 1),
                _ => {}
            }
        }
        runs
    }

    /// One pane over the band's window rows, into `img` (zero where this writes nothing): its
    /// walked values smoothed, its exact part added, dilated; exact in the band's own rows
    /// (module doc), in the column runs `cols`, which must hold every texel the values reach.
    fn band_image(
        &self,
        band: &Band,
        walked: &[(u32, Vec3)],
        exact: &[(u32, Vec3)],
        img: &mut [Vec3],
        cols: &[Range<u32>],
    ) {
        let w = self.grid.w;
        let r0 = band.window.start as usize;
        let at = |k: u32| {
            let t = &self.set.texels[k as usize];
            (t.j as usize - r0) * w + t.i as usize
        };
        for &(k, v) in walked {
            img[at(k)] = v;
        }
        if let Some(smoothing) = self.smoothing {
            smoothing.apply_rows_in(img, band.window.clone(), self.grid.h as u32, cols);
        }
        for &(k, v) in exact {
            img[at(k)] += v;
        }
        for c in cols {
            self.set.dilate_rows_in(img, band.window.start, band.rows.clone(), c.clone());
        }
    }

    /// A pane's tiles in the band (those holding any non-zero texel; none without an image),
    /// encoded, and its energy (signed luminance over the covered texels, the runtime's
    /// ranking energy) carried on from `energy`, tile after tile in atlas order, so the sum is
    /// the same to the bit whichever tiles came from a cache. With `reuse`, tiles not marked
    /// dirty are the cached ones. The image is zero outside the runs of tile columns `columns`.
    fn encode_pane_band(
        &self,
        band: &Band,
        img: Option<&[Vec3]>,
        columns: &[Range<usize>],
        energy: f64,
        reuse: Option<(&[bool], &[CachedTile])>,
    ) -> PaneBand {
        let grid = &self.grid;
        let offset = band.window.start as usize * grid.w;
        let mut tiles = Vec::new();
        for index in band.tile_rows.start * grid.tx..band.tile_rows.end * grid.tx {
            // Outside `columns` the image is zero: only cached tiles can be there.
            let inside = columns.iter().any(|r| r.contains(&(index % grid.tx)));
            if reuse.is_none() && !inside {
                continue;
            }
            if let Some((dirty, cached)) = reuse {
                if !dirty[index] {
                    if let Ok(k) = cached.binary_search_by_key(&(index as u32), |t| t.index) {
                        let t = &cached[k];
                        tiles.push(EncodedTile {
                            index: t.index,
                            scale: t.scale,
                            energy: t.energy,
                            carried: t.carried,
                            data: t.codes.clone(),
                        });
                    }
                    continue;
                }
            }
            let Some(img) = img else { continue };
            if !inside {
                continue;
            }
            let (mut e, mut carried) = (0.0f64, 0.0f64);
            let mut any = false;
            for k in grid.texels(index) {
                let v = img[k - offset];
                if v != Vec3::ZERO {
                    any = true;
                    e += luminance(v).abs() as f64;
                }
                if self.set.index[k] != TexelSet::EMPTY {
                    carried += luminance(v) as f64;
                }
            }
            if any {
                let vals: Vec<Vec3> =
                    grid.texels(index).filter(|&k| self.stored[k]).map(|k| img[k - offset]).collect();
                let (scale, data) = encode_tile(&vals);
                tiles.push(EncodedTile { index: index as u32, scale, energy: e, carried, data });
            }
        }
        let energy = tiles.iter().fold(energy, |a, t| a + t.carried);
        PaneBand { energy, tiles }
    }

    /// The stored-texel mask, packed, as the file keeps it.
    pub fn mask(&self) -> Vec<u8> {
        prm::prm_file::pack_mask(&self.stored)
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

/// Texel-major contributions as pane-major lists (a counting sort): pane c's (texel, value)
/// pairs are `list[start[c]..start[c + 1]]`, in texel order, texels numbered from `first`;
/// `value(k, i)` is what texel k's i-th contribution carries.
fn transpose<T: Copy + Default>(
    texel_panes: &[TexelPanes],
    first: usize,
    panes: Range<usize>,
    value: impl Fn(usize, usize) -> T,
) -> (Vec<usize>, Vec<(u32, T)>) {
    let (lo, m) = (panes.start, panes.len());
    // Each texel's entries for these panes (its list is ascending).
    let spans: Vec<Range<usize>> = texel_panes.iter().map(|tp| span(tp, panes.clone())).collect();
    let mut start = vec![0usize; m + 1];
    for (tp, s) in texel_panes.iter().zip(&spans) {
        for &(c, _) in &tp[s.clone()] {
            start[c as usize - lo + 1] += 1;
        }
    }
    for c in 0..m {
        start[c + 1] += start[c];
    }
    let mut fill = start.clone();
    let mut list = vec![(0u32, T::default()); start[m]];
    for (k, (tp, s)) in texel_panes.iter().zip(&spans).enumerate() {
        for i in s.clone() {
            let c = tp[i].0 as usize - lo;
            list[fill[c]] = ((first + k) as u32, value(k, i));
            fill[c] += 1;
        }
    }
    (start, list)
}

/// The entries of `tp` (ascending by pane) for the panes in `panes`.
fn span(tp: &[(u32, Vec3)], panes: Range<usize>) -> Range<usize> {
    debug_assert!(tp.windows(2).all(|w| w[0].0 < w[1].0), "a texel's pane list must ascend");
    tp.partition_point(|&(c, _)| (c as usize) < panes.start)
        ..tp.partition_point(|&(c, _)| (c as usize) < panes.end)
}

/// Contributions (texel, pane) a band transposes at once (16 bytes each): 2^21, 32 MB.
const TRANSPOSE_ITEMS: usize = 1 << 21;

/// Runs of panes, in order, each naming at most `items` contributions over `lists` (a run of
/// one pane may name more), covering `0..panes`.
fn cluster_chunks(lists: &[&[TexelPanes]], panes: usize, items: usize) -> Vec<Range<usize>> {
    let mut count = vec![0usize; panes];
    for tp in lists.iter().flat_map(|l| l.iter()) {
        for &(c, _) in tp {
            count[c as usize] += 1;
        }
    }
    let mut chunks = Vec::new();
    let (mut from, mut held) = (0, 0);
    for (c, &k) in count.iter().enumerate() {
        if held + k > items && c > from {
            chunks.push(from..c);
            (from, held) = (c, 0);
        }
        held += k;
    }
    if from < panes {
        chunks.push(from..panes);
    }
    chunks
}

/// A tile encoded before the drop rule: its atlas index, RGB scale, energy (|luminance|
/// over its texels, what the rule ranks), carried energy (signed luminance over its covered
/// texels, what the pane's energy sums) and codes.
struct EncodedTile {
    index: u32,
    scale: Vec3,
    energy: f64,
    carried: f64,
    data: Vec<u8>,
}

/// One pane's tiles in one band and its energy so far.
struct PaneBand {
    energy: f64,
    tiles: Vec<EncodedTile>,
}

/// Every pane's tiles encoded so far, before the drop rule. The tiles wait in an anonymous
/// scratch file, band after band (each its atlas index, scale, carried energy and codes), and
/// only their energies (what the drop rule ranks) stay in memory: the output is then filled
/// pane after pane from the file (`drain_into`), so the codes are held once, in the output,
/// instead of once per band and again in the output (on the 4 x 4 halls, 124 MB of codes;
/// held in memory, the heap kept the bands' pieces and the peak grew by twice that). The
/// records stayed in memory until the 16 chambers' 2.5 million tiles made them 80 MB.
pub struct Accumulated {
    /// Each pane's energy so far.
    energy: Vec<f64>,
    /// Each pane's tiles' energies and atlas indices so far, in atlas tile order.
    tiles: Vec<Vec<f64>>,
    index: Vec<Vec<u32>>,
    /// Each pane's runs of tiles in the scratch file, one per band holding any of its tiles:
    /// (offset, tiles, bytes).
    runs: Vec<Vec<(u64, u32, u32)>>,
    spill: std::io::BufWriter<std::fs::File>,
    written: u64,
}

/// A spilled tile's record before its codes: atlas index, RGB scale, carried energy, codes.
const RECORD: usize = 4 + 12 + 8 + 4;

impl Accumulated {
    /// Room for `panes` panes, with a scratch file (the error if none can be made).
    pub fn new(panes: usize) -> std::io::Result<Self> {
        Ok(Accumulated {
            energy: vec![0.0; panes],
            tiles: vec![Vec::new(); panes],
            index: vec![Vec::new(); panes],
            runs: vec![Vec::new(); panes],
            spill: std::io::BufWriter::new(tempfile::tempfile()?),
            written: 0,
        })
    }

    pub fn len(&self) -> usize {
        self.energy.len()
    }

    pub fn is_empty(&self) -> bool {
        self.energy.is_empty()
    }

    /// Add one band's output for panes `first..`, pane by pane (None: nothing of that pane in
    /// the band).
    fn add(&mut self, first: usize, out: Vec<Option<PaneBand>>) -> std::io::Result<()> {
        use std::io::Write;
        for (c, pane) in (first..).zip(out) {
            let Some(pane) = pane else { continue };
            self.energy[c] = pane.energy;
            if pane.tiles.is_empty() {
                continue;
            }
            let start = self.written;
            for t in &pane.tiles {
                self.tiles[c].push(t.energy);
                self.index[c].push(t.index);
                self.spill.write_all(&t.index.to_le_bytes())?;
                for x in t.scale.to_array() {
                    self.spill.write_all(&x.to_le_bytes())?;
                }
                self.spill.write_all(&t.carried.to_le_bytes())?;
                self.spill.write_all(&(t.data.len() as u32).to_le_bytes())?;
                self.spill.write_all(&t.data)?;
                self.written += (RECORD + t.data.len()) as u64;
            }
            let bytes = u32::try_from(self.written - start).map_err(std::io::Error::other)?;
            self.runs[c].push((start, pane.tiles.len() as u32, bytes));
        }
        Ok(())
    }

    /// Each pane's tiles, read back from the scratch file run by run: `each(pane, tile in
    /// the pane, the tile)`.
    fn read_back(&mut self, mut each: impl FnMut(usize, usize, CachedTile)) -> std::io::Result<()> {
        use std::io::{Read, Seek, SeekFrom, Write};
        self.spill.flush()?;
        let file = self.spill.get_mut();
        let mut buf = Vec::new();
        for (c, (pane, runs)) in self.tiles.iter().zip(&self.runs).enumerate() {
            let mut t = 0;
            for &(offset, count, bytes) in runs {
                buf.resize(bytes as usize, 0);
                file.seek(SeekFrom::Start(offset))?;
                file.read_exact(&mut buf)?;
                let mut at = 0;
                for &energy in &pane[t..t + count as usize] {
                    let (tile, len) = spilled_tile(&buf[at..], energy)?;
                    each(c, t, tile);
                    at += len;
                    t += 1;
                }
            }
        }
        file.seek(SeekFrom::End(0))?;
        Ok(())
    }

    /// Every pane's tiles with their codes, read back from the scratch file: what
    /// `crate::update` caches.
    pub fn export(&mut self) -> std::io::Result<Vec<Vec<CachedTile>>> {
        let mut out: Vec<Vec<CachedTile>> = self.tiles.iter().map(|p| Vec::with_capacity(p.len())).collect();
        self.read_back(|c, _, tile| out[c].push(tile))?;
        Ok(out)
    }

    /// The drop rule on each pane: its keep flags, and the tiles and codes kept in all
    /// (`codes(index)`: codes a tile at atlas tile `index` has) with what was dropped.
    fn keep(
        &self,
        drop_threshold: f64,
        codes: &impl Fn(u32) -> usize,
    ) -> (Vec<Vec<bool>>, usize, usize, DropTotals) {
        let mut dropped = DropTotals::default();
        let (mut tiles, mut kept_codes) = (0, 0);
        let keep = self
            .tiles
            .iter()
            .zip(&self.index)
            .map(|(e, index)| {
                let total: f64 = e.iter().sum();
                let (keep, n, energy) = drop_tiles(e, drop_threshold * total);
                dropped.tiles += n;
                dropped.energy += energy;
                dropped.total += total;
                for (&i, &k) in index.iter().zip(&keep) {
                    if k {
                        tiles += 1;
                        kept_codes += codes(i);
                    }
                }
                keep
            })
            .collect();
        (keep, tiles, kept_codes, dropped)
    }

    /// Append the kept tiles (their `cluster` the pane plus `first_pane`) to `tiles` and
    /// their codes, read back from the scratch file, to `data`, pane after pane. Per pane:
    /// (energy, first tile, tile count).
    fn drain_into(
        mut self,
        keep: &[Vec<bool>],
        first_pane: u32,
        tiles: &mut Vec<Tile>,
        data: &mut Vec<u8>,
    ) -> std::io::Result<Vec<(f32, u32, u32)>> {
        let before = tiles.len() as u32;
        let mut count = vec![0u32; self.tiles.len()];
        self.read_back(|c, t, tile| {
            if keep[c][t] {
                tiles.push(Tile { cluster: first_pane + c as u32, index: tile.index, scale: tile.scale });
                data.extend_from_slice(&tile.codes);
                count[c] += 1;
            }
        })?;
        let mut first = before;
        Ok(count
            .iter()
            .zip(&self.energy)
            .map(|(&n, &energy)| {
                first += n;
                (energy as f32, first - n, n)
            })
            .collect())
    }
}

/// A spilled tile read back (`Accumulated::add` wrote it; `energy` was kept in memory) and
/// the bytes it took.
fn spilled_tile(bytes: &[u8], energy: f64) -> std::io::Result<(CachedTile, usize)> {
    let short = || std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "a spilled pane tile is cut short");
    let head = bytes.get(..RECORD).ok_or_else(short)?;
    let word = |k: usize| <[u8; 4]>::try_from(&head[k..k + 4]).unwrap_or_default();
    let index = u32::from_le_bytes(word(0));
    let scale =
        Vec3::new(f32::from_le_bytes(word(4)), f32::from_le_bytes(word(8)), f32::from_le_bytes(word(12)));
    let carried = f64::from_le_bytes(<[u8; 8]>::try_from(&head[16..24]).unwrap_or_default());
    let n = u32::from_le_bytes(word(24)) as usize;
    let codes = bytes.get(RECORD..RECORD + n).ok_or_else(short)?.to_vec();
    Ok((CachedTile { index, scale, energy, carried, codes }, RECORD + n))
}

/// What the drop rule left out of some panes: tiles, their energy, and the panes' whole energy.
#[derive(Default)]
struct DropTotals {
    tiles: u32,
    energy: f64,
    total: f64,
}

/// The panes' part of the file: the clusters' (`members`, `centroids`) and the groups' tiles
/// after the drop rule, in the order the file keeps them (each pane's tiles together,
/// clusters then groups); an error if the scratch file fails.
pub fn assemble(
    encoder: &Encoder,
    fine: Accumulated,
    groups: Accumulated,
    members: &[Vec<u32>],
    centroids: &[Vec3],
    drop_threshold: f64,
) -> std::io::Result<Tiled> {
    let layout = tile_codes(&encoder.grid, &encoder.stored);
    let codes = |index: u32| layout[index as usize];
    let (fine_keep, fine_tiles, fine_codes, dropped) = fine.keep(drop_threshold, &codes);
    let (group_keep, group_tiles, group_codes, _) = groups.keep(drop_threshold, &codes);
    let mut tiles = Vec::with_capacity(fine_tiles + group_tiles);
    let mut data = Vec::with_capacity(fine_codes + group_codes);
    let fine_panes = fine.drain_into(&fine_keep, 0, &mut tiles, &mut data)?;
    let clusters = fine_panes
        .into_iter()
        .zip(members.iter().zip(centroids))
        .map(|((energy, first_tile, tile_count), (m, &centroid))| Cluster {
            members: m.clone(),
            centroid,
            energy,
            first_tile,
            tile_count,
        })
        .collect::<Vec<_>>();
    let first_group = clusters.len() as u32;
    let groups = groups
        .drain_into(&group_keep, first_group, &mut tiles, &mut data)?
        .into_iter()
        .map(|(energy, first_tile, tile_count)| Group { energy, first_tile, tile_count })
        .collect();
    Ok(Tiled {
        clusters,
        groups,
        mask: encoder.mask(),
        tiles,
        data,
        tiles_dropped: dropped.tiles,
        dropped_energy: if dropped.total > 0.0 { dropped.energy / dropped.total } else { 0.0 },
    })
}

/// Codes a stored pane tile holds, per atlas tile: its stored texels.
fn tile_codes(grid: &Grid, stored: &[bool]) -> Vec<usize> {
    (0..grid.tx * grid.ty).map(|index| grid.texels(index).filter(|&k| stored[k]).count()).collect()
}

/// Which tiles to keep: the weakest go while their total stays within `budget` (ties by
/// index). Returns the keep flags, the count dropped and the energy dropped.
fn drop_tiles(energies: &[f64], budget: f64) -> (Vec<bool>, u32, f64) {
    let mut order: Vec<usize> = (0..energies.len()).collect();
    order.sort_by(|&a, &b| energies[a].total_cmp(&energies[b]).then(a.cmp(&b)));
    let mut keep = vec![true; energies.len()];
    let (mut dropped, mut dropped_energy) = (0u32, 0.0f64);
    for &k in &order {
        if dropped_energy + energies[k] > budget {
            break;
        }
        dropped_energy += energies[k];
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Random per-texel lists over `panes` panes, each ascending.
    fn lists(texels: usize, panes: u32, seed: u64) -> Vec<TexelPanes> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        (0..texels)
            .map(|_| {
                let mut tp = TexelPanes::new();
                for c in 0..panes {
                    if rng.random::<f32>() < 0.3 {
                        tp.push((c, Vec3::splat(rng.random::<f32>())));
                    }
                }
                tp
            })
            .collect()
    }

    /// The band is transposed a run of panes at a time: each run's lists are exactly the
    /// whole transpose's for those panes, and the runs cover every pane within the bound.
    #[test]
    fn transposing_by_runs_of_panes_is_the_whole_transpose() {
        let (walked, exact) = (lists(200, 40, 1), lists(200, 40, 2));
        let (start, list) = transpose(&walked, 7, 0..40, |k, i| walked[k][i].1);
        for items in [1, 50, 300, 1 << 20] {
            let chunks = cluster_chunks(&[&walked, &exact], 40, items);
            assert_eq!(chunks.first().map(|c| c.start), Some(0));
            assert_eq!(chunks.last().map(|c| c.end), Some(40));
            assert!(chunks.windows(2).all(|w| w[0].end == w[1].start));
            let count = |c: usize| {
                walked.iter().chain(&exact).filter(|tp| tp.iter().any(|&(p, _)| p as usize == c)).count()
            };
            for chunk in &chunks {
                let held: usize = chunk.clone().map(count).sum();
                assert!(held <= items || chunk.len() == 1, "run {chunk:?} holds {held} > {items}");
                let (s, l) = transpose(&walked, 7, chunk.clone(), |k, i| walked[k][i].1);
                for c in chunk.clone() {
                    let j = c - chunk.start;
                    assert_eq!(l[s[j]..s[j + 1]], list[start[c]..start[c + 1]], "pane {c}");
                }
            }
            if items == 1 << 20 {
                assert_eq!(chunks.len(), 1);
            } else {
                assert!(chunks.len() > 1);
            }
        }
    }
}
