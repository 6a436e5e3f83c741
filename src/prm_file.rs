//! The `.prm` file, format v2 (DESIGN.md §8): one level's precomputed radiance map.
//!
//! Layout, little-endian:
//!
//! ```text
//! 0   magic  b"PRMAP\0\r\n"     (the CR LF catches text-mode mangling)
//! 8   u32    version = 2
//! 12  u32    JSON header length H
//! 16  H      JSON header: fingerprint, atlas, tile size, counts, parameters, statistics
//!     then sections, each  [u8; 4] tag, u64 byte length, payload:
//!     ENTR  N x 48 B: position, normal, albedo (3 x f32 each), area f32, triangle u32, pad u32
//!     CLUS  C x 32 B: first member u32, member count u32, centroid (3 x f32), energy f32,
//!                     first tile u32, tile count u32
//!     MEMB  u32 entry indices, grouped by cluster
//!     GRUP  G x 16 B: energy f32, first tile u32, tile count u32, pad u32; then (when G > 0)
//!           C x u32: the group of each cluster
//!     MASK  ceil(W x H / 8) B: bit (j W + i) set where a texel is stored (covered or dilated)
//!     TILE  K x 20 B: pane u32 (cluster c < C, or group C + g), tile index u32, colour scale
//!           (3 x f32)
//!     DATA  f16 per-texel intensity in [0, 1]: for each tile in TILE order, its masked texels
//!           in row-major order (empty atlas texels are not stored)
//! end u64    FNV-1a 64 checksum of every byte before it
//! ```
//!
//! A pane is the indirect irradiance (W/m², RGB) at every texel when its cluster's entry points
//! receive 1 W/m². Its texels are stored in tile_size x tile_size tiles of the atlas; tiles
//! holding a negligible share of the pane's energy are left out (the header says how much was
//! dropped). A texel's value is `scale x intensity`: one RGB scale per tile (the tile's mean
//! chromaticity times its peak luminance) and one half-float intensity per texel, so luminance
//! is kept exactly (to half-float precision) and colour to the tile's mean. A pane's colour is
//! mostly its cluster's albedo, the same over the tile; the saving is 3x over RGB half floats.
//!
//! **Groups** (v2) are a coarse level over the clusters: each group's pane is the sum of its
//! clusters' panes. A runtime composing only the K strongest clusters adds each group's pane
//! weighted by the light of its clusters left out (see [`Prm::residual_weights`]), so the light
//! of the many weak clusters is kept in total and placed at the group's scale instead of lost.
//!
//! Loading checks, before using anything: magic, version, the checksum, every section length
//! against the file, every index against its table, and (when a scene is given) the
//! fingerprint of the scene geometry, lightmap UVs, albedos and atlas layout. Any mismatch is a
//! [`PrmError`] naming the file and the problem. Writing is atomic.

use std::path::{Path, PathBuf};

use glam::Vec3;
use half::f16;
use serde::{Deserialize, Serialize};

use crate::scene::Scene;

/// File magic.
pub const MAGIC: [u8; 8] = *b"PRMAP\0\r\n";
/// The format version this code writes and reads.
pub const VERSION: u32 = 2;

/// An entry point (DESIGN.md §4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Entry {
    pub position: Vec3,
    /// Unit front-face normal.
    pub normal: Vec3,
    /// Linear albedo at the entry.
    pub albedo: Vec3,
    /// Surface area the entry stands for (A / N), square scene units.
    pub area: f32,
    /// Scene triangle it lies on.
    pub triangle: u32,
}

/// A cluster of entry points sharing one pane and one runtime weight.
#[derive(Clone, Debug, PartialEq)]
pub struct Cluster {
    /// Member entries (indices into [`Prm::entries`]).
    pub members: Vec<u32>,
    /// Mean position of the members.
    pub centroid: Vec3,
    /// Sum of the pane's luminance over all texels (texel count weighted, per unit weight):
    /// the runtime ranks clusters by weight x energy.
    pub energy: f32,
    /// Range of this cluster's tiles in [`Prm::tiles`].
    pub first_tile: u32,
    pub tile_count: u32,
}

/// A group of clusters whose summed pane stands in for those of its clusters a frame leaves out.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    /// Energy of the group's pane (the sum of its clusters' energies, less dropped tiles).
    pub energy: f32,
    /// Range of this group's tiles in [`Prm::tiles`] (their `cluster` is C + group index).
    pub first_tile: u32,
    pub tile_count: u32,
}

/// One stored tile of a pane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tile {
    pub cluster: u32,
    /// Tile index in the atlas tile grid, row-major.
    pub index: u32,
    /// RGB multiplier of the stored half-float intensities.
    pub scale: Vec3,
}

/// Header facts, stored as JSON.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Hex FNV-1a 64 of the scene (see [`scene_fingerprint`]).
    pub fingerprint: String,
    pub atlas_width: u32,
    pub atlas_height: u32,
    pub tile_size: u32,
    pub entries: u32,
    pub clusters: u32,
    pub tiles: u32,
    /// Tiles left out because their energy was negligible.
    pub tiles_dropped: u32,
    /// Fraction of the panes' total energy in the dropped tiles.
    pub dropped_energy: f64,
    /// The relative threshold tiles were dropped by.
    pub drop_threshold: f64,
    /// Free-form provenance: the parameters and statistics of the precompute.
    #[serde(default)]
    pub provenance: serde_json::Value,
    /// Groups (coarse panes) after the clusters; 0 = none.
    #[serde(default)]
    pub groups: u32,
}

/// A loaded or freshly computed radiance map.
#[derive(Clone, Debug, PartialEq)]
pub struct Prm {
    pub header: Header,
    pub entries: Vec<Entry>,
    pub clusters: Vec<Cluster>,
    /// Coarse panes over the clusters (may be empty).
    pub groups: Vec<Group>,
    /// The group of each cluster (empty when there are no groups).
    pub group_of: Vec<u32>,
    pub tiles: Vec<Tile>,
    /// Stored-texel mask of the atlas, one bit per texel, row-major (covered or dilated).
    pub mask: Vec<u8>,
    /// Half-float intensities of all tiles' masked texels, in tile order.
    pub data: Vec<f16>,
}

/// Where each stored tile's texels are: per atlas tile index, the row-major atlas texels stored
/// there (in storage order), and per stored tile, the start of its data.
#[derive(Clone, Debug)]
pub struct TileLayout {
    pub texels: Vec<Vec<u32>>,
    pub offsets: Vec<usize>,
    /// Total stored texels over all tiles.
    pub len: usize,
}

/// Pack a per-texel boolean mask into bits.
pub fn pack_mask(mask: &[bool]) -> Vec<u8> {
    let mut out = vec![0u8; mask.len().div_ceil(8)];
    for (k, &m) in mask.iter().enumerate() {
        if m {
            out[k / 8] |= 1 << (k % 8);
        }
    }
    out
}

/// What can be wrong with a `.prm` file.
#[derive(Debug, thiserror::Error)]
pub enum PrmError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a .prm file (bad magic)")]
    Magic { path: PathBuf },
    #[error("{path}: .prm version {found}, this build reads version {VERSION}")]
    Version { path: PathBuf, found: u32 },
    #[error("{path}: truncated ({size} bytes; {what})")]
    Truncated { path: PathBuf, size: u64, what: String },
    #[error("{path}: checksum mismatch: the file is corrupt")]
    Checksum { path: PathBuf },
    #[error("{path}: corrupt: {what}")]
    Corrupt { path: PathBuf, what: String },
    #[error("{path}: baked for another scene or atlas (file fingerprint {file}, scene {scene}, atlas {file_atlas} vs {scene_atlas}); run prm precompute again")]
    WrongScene { path: PathBuf, file: String, scene: String, file_atlas: String, scene_atlas: String },
}

/// FNV-1a 64 over bytes, continuing from `h`.
pub fn fnv1a(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// FNV-1a 64 offset basis.
pub const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

/// Fingerprint of what a radiance map depends on: triangle corners, lightmap UVs, albedos,
/// sidedness and the atlas size. Lights are not in it: they change at run time.
pub fn scene_fingerprint(scene: &Scene, width: u32, height: u32) -> u64 {
    let mut h = fnv1a(FNV_START, &width.to_le_bytes());
    h = fnv1a(h, &height.to_le_bytes());
    h = fnv1a(h, &(scene.triangles.len() as u64).to_le_bytes());
    for t in 0..scene.triangles.len() {
        for p in scene.corners(t) {
            h = fnv1a(h, bytemuck::bytes_of(&p.to_array()));
        }
        for uv in scene.uv1_corners(t) {
            h = fnv1a(h, bytemuck::bytes_of(&uv.to_array()));
        }
        let m = scene.material(t);
        h = fnv1a(h, bytemuck::bytes_of(&m.albedo.to_array()));
        h = fnv1a(h, &[m.double_sided as u8, m.albedo_texture.is_some() as u8]);
    }
    h
}

impl Prm {
    /// True when atlas texel `k` (row-major) is stored.
    #[inline]
    pub fn stored(&self, k: usize) -> bool {
        self.mask[k / 8] & (1 << (k % 8)) != 0
    }

    /// Tiles across the atlas.
    pub fn tiles_x(&self) -> u32 {
        self.header.atlas_width.div_ceil(self.header.tile_size)
    }

    /// Tiles down the atlas.
    pub fn tiles_y(&self) -> u32 {
        self.header.atlas_height.div_ceil(self.header.tile_size)
    }

    /// Where every stored tile's texels live: built once per map, then used by every compose.
    pub fn layout(&self) -> TileLayout {
        let ts = self.header.tile_size as usize;
        let (w, h) = (self.header.atlas_width as usize, self.header.atlas_height as usize);
        let tx = self.tiles_x() as usize;
        let texels: Vec<Vec<u32>> = (0..self.tiles_x() as usize * self.tiles_y() as usize)
            .map(|index| {
                let (ti, tj) = (index % tx, index / tx);
                let mut out = Vec::new();
                for j in tj * ts..((tj + 1) * ts).min(h) {
                    for i in ti * ts..((ti + 1) * ts).min(w) {
                        if self.stored(j * w + i) {
                            out.push((j * w + i) as u32);
                        }
                    }
                }
                out
            })
            .collect();
        let mut offsets = Vec::with_capacity(self.tiles.len());
        let mut len = 0;
        for t in &self.tiles {
            offsets.push(len);
            len += texels.get(t.index as usize).map_or(0, Vec::len);
        }
        TileLayout { texels, offsets, len }
    }

    /// Add `weight x pane_c` into a full-atlas image (row-major, W x H).
    pub fn add_pane(&self, c: usize, weight: Vec3, img: &mut [Vec3]) {
        self.add_pane_with(c, weight, img, &self.layout());
    }

    /// [`Prm::add_pane`] with a [`Prm::layout`] built beforehand.
    pub fn add_pane_with(&self, c: usize, weight: Vec3, img: &mut [Vec3], layout: &TileLayout) {
        let cl = &self.clusters[c];
        self.add_tiles(cl.first_tile, cl.tile_count, weight, img, layout);
    }

    /// Add `weight x` the pane of group `g` into a full-atlas image.
    pub fn add_group_with(&self, g: usize, weight: Vec3, img: &mut [Vec3], layout: &TileLayout) {
        let gr = &self.groups[g];
        self.add_tiles(gr.first_tile, gr.tile_count, weight, img, layout);
    }

    /// The weight of each group's pane when only the clusters in `selected` are composed:
    /// `r_g = sum over left-out clusters c of g of w_c x energy_c / energy_g`, which gives the
    /// group's pane the (luminance) energy of the light those clusters would have added.
    pub fn residual_weights(&self, weights: &[Vec3], selected: &[bool]) -> Vec<Vec3> {
        let mut r = vec![Vec3::ZERO; self.groups.len()];
        for (c, &g) in self.group_of.iter().enumerate() {
            if !selected[c] {
                r[g as usize] += weights[c] * self.clusters[c].energy;
            }
        }
        for (v, g) in r.iter_mut().zip(&self.groups) {
            *v = if g.energy > 0.0 { *v / g.energy } else { Vec3::ZERO };
        }
        r
    }

    /// The lightmap from the clusters in `selected` (weights `weights`), plus, with `residual`,
    /// the groups standing in for the rest. The slow, obvious twin of the runtime's compose.
    pub fn compose_selected(
        &self,
        weights: &[Vec3],
        selected: &[bool],
        residual: bool,
        layout: &TileLayout,
    ) -> Vec<Vec3> {
        let mut img = vec![Vec3::ZERO; (self.header.atlas_width * self.header.atlas_height) as usize];
        for c in 0..self.clusters.len() {
            if selected[c] && weights[c] != Vec3::ZERO {
                self.add_pane_with(c, weights[c], &mut img, layout);
            }
        }
        if residual {
            for (g, w) in self.residual_weights(weights, selected).into_iter().enumerate() {
                if w != Vec3::ZERO {
                    self.add_group_with(g, w, &mut img, layout);
                }
            }
        }
        img
    }

    fn add_tiles(&self, first: u32, count: u32, weight: Vec3, img: &mut [Vec3], layout: &TileLayout) {
        for k in first as usize..(first + count) as usize {
            let tile = &self.tiles[k];
            let s = weight * tile.scale;
            let data = &self.data[layout.offsets[k]..];
            for (&texel, v) in layout.texels[tile.index as usize].iter().zip(data) {
                img[texel as usize] += s * v.to_f32();
            }
        }
    }

    /// The indirect lightmap for per-cluster weights (W/m² of entry irradiance): the sum of
    /// every pane times its weight. The slow, obvious compose.
    pub fn compose(&self, weights: &[Vec3]) -> Vec<Vec3> {
        assert_eq!(weights.len(), self.clusters.len());
        let mut img = vec![Vec3::ZERO; (self.header.atlas_width * self.header.atlas_height) as usize];
        let layout = self.layout();
        for (c, w) in weights.iter().enumerate() {
            if *w != Vec3::ZERO {
                self.add_pane_with(c, *w, &mut img, &layout);
            }
        }
        img
    }

    /// Cluster weights from per-entry irradiance: the mean over each cluster's members.
    pub fn cluster_weights(&self, entry_irradiance: &[Vec3]) -> Vec<Vec3> {
        self.clusters
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

    /// Error unless this map was baked for `scene` at its atlas size.
    pub fn check_scene(&self, path: &Path, scene: &Scene) -> Result<(), PrmError> {
        let fp =
            format!("{:016x}", scene_fingerprint(scene, self.header.atlas_width, self.header.atlas_height));
        if fp != self.header.fingerprint {
            return Err(PrmError::WrongScene {
                path: path.into(),
                file: self.header.fingerprint.clone(),
                scene: fp,
                file_atlas: format!("{}x{}", self.header.atlas_width, self.header.atlas_height),
                scene_atlas: format!("{}x{}", self.header.atlas_width, self.header.atlas_height),
            });
        }
        Ok(())
    }

    /// The file bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        let header = serde_json::to_vec(&self.header).unwrap_or_default();
        out.extend_from_slice(&(header.len() as u32).to_le_bytes());
        out.extend_from_slice(&header);
        let mut section = |tag: &[u8; 4], payload: Vec<u8>| {
            out.extend_from_slice(tag);
            out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
            out.extend_from_slice(&payload);
        };
        let mut e = Vec::with_capacity(self.entries.len() * 48);
        for en in &self.entries {
            for v in [en.position, en.normal, en.albedo] {
                e.extend_from_slice(bytemuck::bytes_of(&v.to_array()));
            }
            e.extend_from_slice(&en.area.to_le_bytes());
            e.extend_from_slice(&en.triangle.to_le_bytes());
            e.extend_from_slice(&0u32.to_le_bytes());
        }
        section(b"ENTR", e);
        let (mut c, mut m) = (Vec::new(), Vec::new());
        let mut first = 0u32;
        for cl in &self.clusters {
            c.extend_from_slice(&first.to_le_bytes());
            c.extend_from_slice(&(cl.members.len() as u32).to_le_bytes());
            c.extend_from_slice(bytemuck::bytes_of(&cl.centroid.to_array()));
            c.extend_from_slice(&cl.energy.to_le_bytes());
            c.extend_from_slice(&cl.first_tile.to_le_bytes());
            c.extend_from_slice(&cl.tile_count.to_le_bytes());
            for &x in &cl.members {
                m.extend_from_slice(&x.to_le_bytes());
            }
            first += cl.members.len() as u32;
        }
        section(b"CLUS", c);
        section(b"MEMB", m);
        let mut g = Vec::new();
        for gr in &self.groups {
            g.extend_from_slice(&gr.energy.to_le_bytes());
            g.extend_from_slice(&gr.first_tile.to_le_bytes());
            g.extend_from_slice(&gr.tile_count.to_le_bytes());
            g.extend_from_slice(&0u32.to_le_bytes());
        }
        if !self.groups.is_empty() {
            for &x in &self.group_of {
                g.extend_from_slice(&x.to_le_bytes());
            }
        }
        section(b"GRUP", g);
        section(b"MASK", self.mask.clone());
        let mut t = Vec::with_capacity(self.tiles.len() * 20);
        for tile in &self.tiles {
            t.extend_from_slice(&tile.cluster.to_le_bytes());
            t.extend_from_slice(&tile.index.to_le_bytes());
            t.extend_from_slice(bytemuck::bytes_of(&tile.scale.to_array()));
        }
        section(b"TILE", t);
        section(b"DATA", bytemuck::cast_slice::<f16, u8>(&self.data).to_vec());
        let sum = fnv1a(FNV_START, &out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Write atomically.
    pub fn write(&self, path: &Path) -> Result<(), PrmError> {
        crate::fsutil::write_bytes_atomic(path, &self.to_bytes())
            .map_err(|source| PrmError::Io { path: path.into(), source })
    }

    /// Read and validate a file; with `scene`, also check it was baked for that scene.
    pub fn read(path: &Path, scene: Option<&Scene>) -> Result<Prm, PrmError> {
        let bytes = std::fs::read(path).map_err(|source| PrmError::Io { path: path.into(), source })?;
        let prm = Self::from_bytes(path, &bytes)?;
        if let Some(s) = scene {
            prm.check_scene(path, s)?;
        }
        Ok(prm)
    }

    /// Parse and validate file bytes (`path` is only for messages).
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Prm, PrmError> {
        let size = bytes.len() as u64;
        let truncated = |what: &str| PrmError::Truncated { path: path.into(), size, what: what.into() };
        let corrupt = |what: String| PrmError::Corrupt { path: path.into(), what };
        if bytes.len() < 8 || bytes[..8] != MAGIC {
            if bytes.len() < 8 && MAGIC.starts_with(bytes) && !bytes.is_empty() {
                return Err(truncated("shorter than the magic"));
            }
            return Err(PrmError::Magic { path: path.into() });
        }
        if bytes.len() < 16 {
            return Err(truncated("no header"));
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
        if version != VERSION {
            return Err(PrmError::Version { path: path.into(), found: version });
        }
        if bytes.len() < 24 {
            return Err(truncated("no checksum"));
        }
        let body = &bytes[..bytes.len() - 8];
        let stored = u64::from_le_bytes(bytes[bytes.len() - 8..].try_into().unwrap_or_default());
        let header_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap_or_default()) as usize;
        if 16 + header_len > body.len() {
            return Err(truncated("header runs past the end"));
        }
        if fnv1a(FNV_START, body) != stored {
            return Err(PrmError::Checksum { path: path.into() });
        }
        let header: Header = serde_json::from_slice(&body[16..16 + header_len])
            .map_err(|e| corrupt(format!("header: {e}")))?;
        if header.tile_size == 0
            || header.tile_size > 4096
            || header.atlas_width == 0
            || header.atlas_height == 0
            || header.atlas_width > 65536
            || header.atlas_height > 65536
        {
            return Err(corrupt(format!(
                "implausible atlas {}x{} / tile size {}",
                header.atlas_width, header.atlas_height, header.tile_size
            )));
        }
        let mut at = 16 + header_len;
        let mut next = |tag: &[u8; 4]| -> Result<&[u8], PrmError> {
            if at + 12 > body.len() {
                return Err(truncated(&format!("section {} missing", String::from_utf8_lossy(tag))));
            }
            if &body[at..at + 4] != tag {
                return Err(corrupt(format!("expected section {}", String::from_utf8_lossy(tag))));
            }
            let len = u64::from_le_bytes(body[at + 4..at + 12].try_into().unwrap_or_default());
            let start = at + 12;
            if len > (body.len() - start) as u64 {
                return Err(truncated(&format!(
                    "section {} runs past the end",
                    String::from_utf8_lossy(tag)
                )));
            }
            at = start + len as usize;
            Ok(&body[start..at])
        };
        let f32_at = |b: &[u8], i: usize| f32::from_le_bytes(b[i..i + 4].try_into().unwrap_or_default());
        let u32_at = |b: &[u8], i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap_or_default());
        let v3 = |b: &[u8], i: usize| Vec3::new(f32_at(b, i), f32_at(b, i + 4), f32_at(b, i + 8));

        let e = next(b"ENTR")?;
        if e.len() as u64 != header.entries as u64 * 48 {
            return Err(corrupt(format!(
                "{} entries declared, {} bytes of entries",
                header.entries,
                e.len()
            )));
        }
        let entries: Vec<Entry> = e
            .chunks_exact(48)
            .map(|b| Entry {
                position: v3(b, 0),
                normal: v3(b, 12),
                albedo: v3(b, 24),
                area: f32_at(b, 36),
                triangle: u32_at(b, 40),
            })
            .collect();
        if let Some(k) = entries.iter().position(|e| {
            !(e.position.is_finite()
                && e.normal.is_finite()
                && e.albedo.is_finite()
                && e.area.is_finite()
                && e.area >= 0.0)
        }) {
            return Err(corrupt(format!("entry {k} has non-finite or negative values")));
        }
        let c = next(b"CLUS")?;
        if c.len() as u64 != header.clusters as u64 * 32 {
            return Err(corrupt(format!(
                "{} clusters declared, {} bytes of clusters",
                header.clusters,
                c.len()
            )));
        }
        let m = next(b"MEMB")?;
        if m.len() % 4 != 0 {
            return Err(corrupt("member list is not whole u32s".into()));
        }
        let members: Vec<u32> = m.chunks_exact(4).map(|b| u32_at(b, 0)).collect();
        if let Some(bad) = members.iter().find(|&&x| x as usize >= entries.len()) {
            return Err(corrupt(format!("member {bad} is not an entry (there are {})", entries.len())));
        }
        let gsec = next(b"GRUP")?;
        let (n_groups, n_clusters) = (header.groups as u64, header.clusters as u64);
        let want = if n_groups == 0 { 0 } else { n_groups * 16 + n_clusters * 4 };
        if gsec.len() as u64 != want {
            return Err(corrupt(format!(
                "{n_groups} groups over {n_clusters} clusters declared, {} bytes of groups",
                gsec.len()
            )));
        }
        let mask = next(b"MASK")?.to_vec();
        if mask.len() as u64 != (header.atlas_width as u64 * header.atlas_height as u64).div_ceil(8) {
            return Err(corrupt(format!(
                "mask is {} bytes for a {}x{} atlas",
                mask.len(),
                header.atlas_width,
                header.atlas_height
            )));
        }
        let t = next(b"TILE")?;
        if t.len() as u64 != header.tiles as u64 * 20 {
            return Err(corrupt(format!("{} tiles declared, {} bytes of tiles", header.tiles, t.len())));
        }
        let tiles: Vec<Tile> = t
            .chunks_exact(20)
            .map(|b| Tile { cluster: u32_at(b, 0), index: u32_at(b, 4), scale: v3(b, 8) })
            .collect();
        let grid = (header.atlas_width.div_ceil(header.tile_size) as u64)
            * (header.atlas_height.div_ceil(header.tile_size) as u64);
        for (k, tile) in tiles.iter().enumerate() {
            if tile.cluster as u64 >= n_clusters + n_groups
                || tile.index as u64 >= grid
                || !tile.scale.is_finite()
                || tile.scale.min_element() < 0.0
            {
                return Err(corrupt(format!(
                    "tile {k} is out of range (cluster {}, index {}, scale {})",
                    tile.cluster, tile.index, tile.scale
                )));
            }
        }
        // Together the clusters may claim at most the member list: otherwise a small file could
        // make every cluster copy the whole list (quadratic memory).
        let claimed: u64 = c.chunks_exact(32).map(|b| u32_at(b, 4) as u64).sum();
        if claimed > members.len() as u64 {
            return Err(corrupt(format!(
                "clusters claim {claimed} members, the list holds {}",
                members.len()
            )));
        }
        let mut clusters = Vec::with_capacity(header.clusters as usize);
        for (k, b) in c.chunks_exact(32).enumerate() {
            let (first, count) = (u32_at(b, 0) as usize, u32_at(b, 4) as usize);
            let (ft, tc) = (u32_at(b, 24), u32_at(b, 28));
            if first.checked_add(count).is_none_or(|end| end > members.len()) {
                return Err(corrupt(format!("cluster {k}'s members run past the member list")));
            }
            if (ft as u64 + tc as u64) > tiles.len() as u64
                || tiles[ft as usize..(ft + tc) as usize].iter().any(|t| t.cluster != k as u32)
            {
                return Err(corrupt(format!("cluster {k}'s tile range is wrong")));
            }
            clusters.push(Cluster {
                members: members[first..first + count].to_vec(),
                centroid: v3(b, 8),
                energy: f32_at(b, 20),
                first_tile: ft,
                tile_count: tc,
            });
        }
        let mut groups = Vec::with_capacity(n_groups as usize);
        for (g, b) in gsec[..n_groups as usize * 16].chunks_exact(16).enumerate() {
            let (energy, ft, tc) = (f32_at(b, 0), u32_at(b, 4), u32_at(b, 8));
            let pane = n_clusters + g as u64;
            if !(energy.is_finite() && energy >= 0.0)
                || (ft as u64 + tc as u64) > tiles.len() as u64
                || tiles[ft as usize..(ft + tc) as usize].iter().any(|t| t.cluster as u64 != pane)
            {
                return Err(corrupt(format!("group {g} has a bad energy or tile range")));
            }
            groups.push(Group { energy, first_tile: ft, tile_count: tc });
        }
        // The panes' ranges must cover every tile (the runtime reads tiles by pane id, the CPU
        // twin by range: a stray tile would make them disagree), one tile per atlas index each.
        let covered: u64 = clusters
            .iter()
            .map(|c| c.tile_count as u64)
            .chain(groups.iter().map(|g| g.tile_count as u64))
            .sum();
        if covered != tiles.len() as u64 {
            return Err(corrupt(format!("the panes' tile ranges cover {covered} of {} tiles", tiles.len())));
        }
        let mut seen = std::collections::HashSet::with_capacity(tiles.len());
        if let Some(k) = tiles.iter().position(|t| !seen.insert((t.cluster, t.index))) {
            return Err(corrupt(format!(
                "tile {k} repeats atlas tile {} of pane {}",
                tiles[k].index, tiles[k].cluster
            )));
        }
        let group_of: Vec<u32> =
            gsec[n_groups as usize * 16..].chunks_exact(4).map(|b| u32_at(b, 0)).collect();
        if let Some(c) = group_of.iter().position(|&g| g as u64 >= n_groups) {
            return Err(corrupt(format!("cluster {c} is in group {}, of {n_groups}", group_of[c])));
        }
        let d = next(b"DATA")?;
        if at != body.len() {
            return Err(corrupt(format!("{} unexpected bytes after the last section", body.len() - at)));
        }
        let mut prm = Prm { header, entries, clusters, groups, group_of, tiles, mask, data: Vec::new() };
        let want = prm.layout().len;
        if d.len() as u64 != want as u64 * 2 {
            return Err(corrupt(format!(
                "tile data is {} bytes, the tiles' masked texels need {}",
                d.len(),
                want * 2
            )));
        }
        prm.data = d.chunks_exact(2).map(|b| f16::from_le_bytes([b[0], b[1]])).collect();
        if let Some(k) = prm.data.iter().position(|v| !(v.is_finite() && v.to_f32() >= 0.0)) {
            return Err(corrupt(format!("tile texel {k} is not a finite, non-negative intensity")));
        }
        if let Some(c) = prm
            .clusters
            .iter()
            .position(|c| !(c.energy.is_finite() && c.energy >= 0.0 && c.centroid.is_finite()))
        {
            return Err(corrupt(format!("cluster {c} has a non-finite energy or centroid")));
        }
        Ok(prm)
    }
}
