//! The update cache (`X.prm.cache`): what `prm precompute --update` needs from the bake of
//! `X.prm` and the file does not hold.
//!
//! Little-endian, in this order:
//!
//! ```text
//! magic "PRMUPDT\n", version u32
//! prm checksum u64            the .prm's own checksum (its last 8 bytes): the pair belongs together
//! params: u32 length, UTF-8   the parameters it was baked with (PrecomputeParams::canonical)
//! grid: origin 3 f32, side f32, dims 3 u32
//! bounds: lo 3 f32, hi 3 f32   (v9) the level's bounds as baked (prm::Scene::bounds)
//! triangles u32, then per triangle: corners 9 f32, digest u64
//! entries u32, then the cluster of each u32
//! clusters u32, groups u32, then the group of each cluster u32 (none without groups)
//! rows u32, then per entry its next-bounce row's digest u64 (none without the table)
//! row inputs u32, then per entry the digest of what its row is made of u64
//! tiles u32, then per atlas tile: inputs digest u64 (v4: of the exact first bounce's inputs,
//!     not its values), walks cut u64, unowned vertices u64,
//!     footprint (grid words x u64), rooms u32 then each room u32 (sorted; u32::MAX: any)
//! panes u32 (clusters + groups), then per pane: tiles u32, then per tile:
//!     atlas tile u32, energy f64, carried f64, scale 3 f32 (v12), in map u8, then unless
//!     in map: codes u32, codes bytes
//! checksum u64                FNV-1a 64 of everything before it
//! ```
//!
//! A tile *in map* (v5) is one the `.prm` beside the cache keeps with the same codes: the
//! reader takes them from that map (since v12 its scale is written here: the map's tiles are
//! scaled to their pane's power, `crate::precompute::match_power`, and the cache keeps the
//! panes as walked) (`UpdateCache::read` is given it). Only the tiles the
//! drop rule left out carry their codes here, so the cache no longer holds the map's panes a
//! second time (16 chambers: 370 -> 134 MB; the rest is mostly the footprints and the
//! dropped tiles). Read beside another map, a tile may be missing (an error) or be that map's;
//! the cache's tie to its own map (the map's checksum, checked before an update uses it) then
//! refuses the update.
//!
//! The panes' tiles are every tile the bake encoded, before the drop rule (the file keeps only
//! those it did not drop), with both energies the rule and the pane's total are made from.

use std::io::Write;
use std::path::Path;

use glam::Vec3;
use prm::fingerprint::{fnv1a, FNV_START};
use prm::prm_file::{PaneTile, Prm, TileLayout};

use super::footprint::VoxelGrid;

const MAGIC: [u8; 8] = *b"PRMUPDT\n";
/// 6: the digests of the rows' inputs (`NextBounce::input_digests`) too; 7: those digests
/// include the rows' cutoff of weak elements; 8: a texel's far-field digest leaves out the
/// pairs in which its neighbour sees nothing; 9: the level's bounds (`prm::Scene::bounds`),
/// which every ray's offsets follow (an update of a level whose bounds moved is refused); 10:
/// the far field's energies are the runtime's own sums (`crate::far`), and an update keeps a
/// settled entry's: an older bake's were estimates, so its cache is refused and the level
/// baked whole; 11: those sums are added in parts of 128 far texels (were 1,024), so an
/// older bake's settled entries could differ from a fresh precompute's in their last bit; 12:
/// every tile's scale is written, a tile in the map beside it takes only its codes from it.
const VERSION: u32 = 12;

/// Per atlas tile: a digest of everything but the walks its texels' values are made from, the
/// walks' counters, the voxels its own texels' walks passed through and the rooms
/// (`prm::rooms`, labelled as in the level baked) their points lay in, sorted, with
/// [`crate::transport::ANY_ROOM`] when a walk lay in none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TileRecord {
    pub inputs: u64,
    pub truncated: u64,
    pub unowned: u64,
    pub footprint: Vec<u64>,
    pub rooms: Vec<u32>,
}

/// One encoded pane tile before the drop rule.
#[derive(Clone, Debug, PartialEq)]
pub struct CachedTile {
    pub index: u32,
    pub scale: Vec3,
    /// Sum of |luminance| over its texels (what the drop rule ranks).
    pub energy: f64,
    /// Sum of signed luminance over its covered texels (what the pane's energy adds up).
    pub carried: f64,
    pub codes: Vec<u8>,
}

/// The cache (module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct UpdateCache {
    pub prm_checksum: u64,
    pub params: String,
    pub grid: VoxelGrid,
    /// The level's bounds as baked (`prm::Scene::bounds`: every vertex, so the ray offsets'
    /// diagonal).
    pub bounds: (Vec3, Vec3),
    /// Corners and digest of every triangle of the level as baked.
    pub triangles: Vec<([Vec3; 3], u64)>,
    /// Cluster of each entry.
    pub assignment: Vec<u32>,
    pub clusters: u32,
    /// Group of each cluster (empty without groups) and the group count.
    pub group_of: Vec<u32>,
    pub groups: u32,
    /// Per entry, a digest of its row of the walks' next-bounce table (empty without one:
    /// `crate::transport::NextBounce::row_digests`), and of what the row is made of
    /// (`NextBounce::input_digests`).
    pub rows: Vec<u64>,
    pub row_inputs: Vec<u64>,
    pub tiles: Vec<TileRecord>,
    /// Clusters' panes, then groups'.
    pub panes: Vec<Vec<CachedTile>>,
}

/// A cache that cannot be used: unreadable, damaged or of another version.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    #[error("cannot read the update cache {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("the update cache {path} is damaged: {what}")]
    Corrupt { path: String, what: String },
    #[error(
        "the update cache {path} is of version {found}, this build reads version {VERSION}: bake OLD \
         again with --cache"
    )]
    Version { path: String, found: u32 },
}

impl UpdateCache {
    /// The cache's bytes (module doc) beside `map`, the map it was baked with: a pane tile the
    /// map keeps as it is here is written without its codes, which the reader takes from the map.
    pub fn to_bytes(&self, map: &Prm) -> Vec<u8> {
        let mut out = Vec::new();
        // Writing to a Vec cannot fail.
        let _ = self.write_to(&mut out, map);
        out
    }

    /// Writes [`UpdateCache::to_bytes`] to `out` a megabyte at a time, the checksum made as it
    /// goes: no copy of the whole cache is held.
    pub fn write_to(&self, out: &mut dyn Write, map: &Prm) -> std::io::Result<()> {
        let layout = map.layout();
        let mut sum = FNV_START;
        let mut b = Vec::new();
        let mut flush = |b: &mut Vec<u8>, at_least: usize| -> std::io::Result<()> {
            if b.len() >= at_least {
                sum = fnv1a(sum, b);
                out.write_all(b)?;
                b.clear();
            }
            Ok(())
        };
        b.extend_from_slice(&MAGIC);
        put_u32(&mut b, VERSION);
        put_u64(&mut b, self.prm_checksum);
        put_u32(&mut b, self.params.len() as u32);
        b.extend_from_slice(self.params.as_bytes());
        put_vec3(&mut b, self.grid.origin);
        put_f32(&mut b, self.grid.side);
        self.grid.dims.iter().for_each(|&d| put_u32(&mut b, d));
        put_vec3(&mut b, self.bounds.0);
        put_vec3(&mut b, self.bounds.1);
        put_u32(&mut b, self.triangles.len() as u32);
        for (corners, digest) in &self.triangles {
            corners.iter().for_each(|&c| put_vec3(&mut b, c));
            put_u64(&mut b, *digest);
        }
        put_u32(&mut b, self.assignment.len() as u32);
        self.assignment.iter().for_each(|&c| put_u32(&mut b, c));
        put_u32(&mut b, self.clusters);
        put_u32(&mut b, self.groups);
        self.group_of.iter().for_each(|&g| put_u32(&mut b, g));
        put_u32(&mut b, self.rows.len() as u32);
        self.rows.iter().for_each(|&d| put_u64(&mut b, d));
        put_u32(&mut b, self.row_inputs.len() as u32);
        self.row_inputs.iter().for_each(|&d| put_u64(&mut b, d));
        put_u32(&mut b, self.tiles.len() as u32);
        for t in &self.tiles {
            put_u64(&mut b, t.inputs);
            put_u64(&mut b, t.truncated);
            put_u64(&mut b, t.unowned);
            t.footprint.iter().for_each(|&w| put_u64(&mut b, w));
            put_u32(&mut b, t.rooms.len() as u32);
            t.rooms.iter().for_each(|&r| put_u32(&mut b, r));
            flush(&mut b, 1 << 20)?;
        }
        put_u32(&mut b, self.panes.len() as u32);
        for (p, pane) in self.panes.iter().enumerate() {
            let kept = kept_tiles(map, &layout, p);
            put_u32(&mut b, pane.len() as u32);
            for t in pane {
                put_u32(&mut b, t.index);
                b.extend_from_slice(&t.energy.to_le_bytes());
                b.extend_from_slice(&t.carried.to_le_bytes());
                let in_map = kept
                    .binary_search_by_key(&t.index, |k| k.tile.index)
                    .ok()
                    .is_some_and(|k| kept[k].data == &t.codes[..]);
                put_vec3(&mut b, t.scale);
                b.push(in_map as u8);
                if !in_map {
                    put_u32(&mut b, t.codes.len() as u32);
                    b.extend_from_slice(&t.codes);
                }
                flush(&mut b, 1 << 20)?;
            }
        }
        flush(&mut b, 0)?;
        out.write_all(&sum.to_le_bytes())
    }

    /// Write it atomically (never half a file), beside `map` ([`UpdateCache::to_bytes`]).
    pub fn write(&self, path: &Path, map: &Prm) -> std::io::Result<()> {
        prm::fsutil::write_atomic(path, |w| self.write_to(w, map))
    }

    /// Read the cache of the map `map` (module doc).
    pub fn read(path: &Path, map: &Prm) -> Result<UpdateCache, CacheError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| CacheError::Io { path: name.clone(), source })?;
        // An intact cache of another build is not damaged, only of another version.
        Self::parse(&bytes, map).map_err(|bad| match bad {
            Bad::Version(found) => CacheError::Version { path: name, found },
            Bad::Other(what) => CacheError::Corrupt { path: name, what },
        })
    }

    /// Parse and check the bytes, the pane tiles written without codes taken from `map`; the
    /// error says what is wrong.
    pub fn from_bytes(bytes: &[u8], map: &Prm) -> Result<UpdateCache, String> {
        Self::parse(bytes, map).map_err(|bad| match bad {
            Bad::Version(found) => format!("version {found}, this build reads version {VERSION}"),
            Bad::Other(what) => what,
        })
    }

    fn parse(bytes: &[u8], map: &Prm) -> Result<UpdateCache, Bad> {
        if bytes.len() < 20 || bytes[..8] != MAGIC {
            return Err("not an update cache (no PRMUPDT magic)".into());
        }
        let (body, tail) = bytes.split_at(bytes.len() - 8);
        let sum = u64::from_le_bytes(tail.try_into().map_err(|_| "short file".to_string())?);
        if fnv1a(FNV_START, body) != sum {
            return Err("checksum mismatch (the file was changed or cut short)".into());
        }
        let mut r = Reader { b: body, at: 8 };
        let version = r.u32()?;
        if version != VERSION {
            return Err(Bad::Version(version));
        }
        Self::sections(body, map).map_err(Bad::Other)
    }

    /// Everything after the version, of a cache whose magic, checksum and version are right.
    fn sections(body: &[u8], map: &Prm) -> Result<UpdateCache, String> {
        let mut r = Reader { b: body, at: 12 };
        let prm_checksum = r.u64()?;
        let n = r.count(1)?;
        let params =
            String::from_utf8(r.take(n)?.to_vec()).map_err(|_| "parameters not UTF-8".to_string())?;
        let origin = r.vec3()?;
        let side = r.f32()?;
        let dims = [r.u32()?, r.u32()?, r.u32()?];
        let voxels = dims.iter().map(|&d| d as u64).product::<u64>();
        if !(side > 0.0 && side.is_finite() && origin.is_finite()) || voxels == 0 || voxels > 1 << 24 {
            return Err(format!("bad voxel grid (side {side}, dims {dims:?})"));
        }
        let grid = VoxelGrid { origin, side, dims };
        let bounds = (r.vec3()?, r.vec3()?);
        let n = r.count(44)?;
        let triangles = (0..n)
            .map(|_| Ok(([r.vec3()?, r.vec3()?, r.vec3()?], r.u64()?)))
            .collect::<Result<Vec<_>, String>>()?;
        let n = r.count(4)?;
        let assignment = (0..n).map(|_| r.u32()).collect::<Result<Vec<_>, _>>()?;
        let clusters = r.u32()?;
        let groups = r.u32()?;
        if assignment.iter().any(|&c| c >= clusters) {
            return Err(format!("an entry's cluster is not below the {clusters} clusters"));
        }
        let group_of = if groups > 0 {
            let g = (0..clusters).map(|_| r.u32()).collect::<Result<Vec<_>, _>>()?;
            if g.iter().any(|&x| x >= groups) {
                return Err(format!("a cluster's group is not below the {groups} groups"));
            }
            g
        } else {
            Vec::new()
        };
        let n = r.count(8)?;
        let rows = (0..n).map(|_| r.u64()).collect::<Result<Vec<_>, _>>()?;
        if !rows.is_empty() && rows.len() != assignment.len() {
            return Err(format!("{} table rows for {} entries", rows.len(), assignment.len()));
        }
        let n = r.count(8)?;
        let row_inputs = (0..n).map(|_| r.u64()).collect::<Result<Vec<_>, _>>()?;
        if row_inputs.len() != rows.len() {
            return Err(format!("{} rows' inputs for {} table rows", row_inputs.len(), rows.len()));
        }
        let words = grid.words();
        let n = r.count(28 + 8 * words)?;
        let tiles = (0..n)
            .map(|_| {
                let (inputs, truncated, unowned) = (r.u64()?, r.u64()?, r.u64()?);
                let footprint = (0..words).map(|_| r.u64()).collect::<Result<Vec<_>, _>>()?;
                let m = r.count(4)?;
                let rooms = (0..m).map(|_| r.u32()).collect::<Result<Vec<_>, _>>()?;
                if rooms.windows(2).any(|w| w[0] >= w[1]) {
                    return Err("a tile's rooms are not sorted".to_string());
                }
                Ok(TileRecord { inputs, truncated, unowned, footprint, rooms })
            })
            .collect::<Result<Vec<_>, String>>()?;
        let n = r.count(4)?;
        if n != clusters as usize + groups as usize {
            return Err(format!("{n} panes for {clusters} clusters and {groups} groups"));
        }
        let mut panes = Vec::with_capacity(n);
        let layout = map.layout();
        for p in 0..n {
            let m = r.count(33)?;
            let mut pane = Vec::with_capacity(m);
            let kept = kept_tiles(map, &layout, p);
            for _ in 0..m {
                let index = r.u32()?;
                if index as usize >= tiles.len() {
                    return Err(format!("a pane tile at atlas tile {index} of {}", tiles.len()));
                }
                let (energy, carried) = (r.f64()?, r.f64()?);
                let scale = r.vec3()?;
                let codes = match r.take(1)?[0] {
                    0 => {
                        let k = r.count(1)?;
                        r.take(k)?.to_vec()
                    }
                    1 => {
                        let Ok(k) = kept.binary_search_by_key(&index, |k| k.tile.index) else {
                            return Err(format!(
                                "pane {p}'s tile at atlas tile {index} is not in the map beside it (another map's cache?)"
                            ));
                        };
                        kept[k].data.to_vec()
                    }
                    f => return Err(format!("pane {p}'s tile at atlas tile {index} has flag {f}")),
                };
                pane.push(CachedTile { index, scale, energy, carried, codes });
            }
            if pane.windows(2).any(|w| w[0].index >= w[1].index) {
                return Err("a pane's tiles are not in atlas order".into());
            }
            panes.push(pane);
        }
        if r.at != r.b.len() {
            return Err(format!("{} bytes after the last pane", r.b.len() - r.at));
        }
        Ok(UpdateCache {
            prm_checksum,
            params,
            grid,
            bounds,
            triangles,
            assignment,
            clusters,
            group_of,
            groups,
            rows,
            row_inputs,
            tiles,
            panes,
        })
    }
}

/// Why bytes are not a cache: an intact one of another version, or anything else, in words.
enum Bad {
    Version(u32),
    Other(String),
}

impl From<String> for Bad {
    fn from(what: String) -> Self {
        Bad::Other(what)
    }
}

impl From<&str> for Bad {
    fn from(what: &str) -> Self {
        Bad::Other(what.to_string())
    }
}

/// The tiles `map` keeps of pane `p` (none past its panes), in atlas order.
fn kept_tiles<'a>(map: &'a Prm, layout: &'a TileLayout, p: usize) -> Vec<PaneTile<'a>> {
    if p < map.clusters().len() + map.groups().len() {
        map.pane_tiles(p, layout).collect()
    } else {
        Vec::new()
    }
}

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(b: &mut Vec<u8>, v: f32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_vec3(b: &mut Vec<u8>, v: Vec3) {
    v.to_array().iter().for_each(|&x| put_f32(b, x));
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let end = end.ok_or_else(|| format!("cut short at byte {}", self.at))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap_or_default()))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap_or_default()))
    }
    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into().unwrap_or_default()))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap_or_default()))
    }
    fn vec3(&mut self) -> Result<Vec3, String> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }
    /// A count of items at least `min_bytes` each, refused if the rest cannot hold them.
    fn count(&mut self, min_bytes: usize) -> Result<usize, String> {
        let n = self.u32()? as usize;
        if n.saturating_mul(min_bytes) > self.b.len() - self.at {
            return Err(format!("a count of {n} at byte {} exceeds the file", self.at - 4));
        }
        Ok(n)
    }
}
