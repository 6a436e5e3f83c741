//! One writer and one reader per `.prm` section (layout in the module doc of [`super`]).
//!
//! Readers check what a section can say about itself (its length against the header's counts,
//! ranges into the sections read before it) and build the parts; the invariants that tie the
//! parts together are checked once, by [`super::Prm::new`], for files and fresh bakes alike.

use glam::Vec3;
use half::f16;

use super::{
    decode_octahedral, dequantize_position, encode_octahedral, near_point_box, quantize_position, Cells,
    Cluster, Echo, EchoLink, Entry, Far, FarTexel, Group, Header, NearLink, NearPoint, Tile,
};

/// Bytes of one link's sight in `SEEN`: its index and its bits.
const SEEN_BYTES: usize = 12;
/// Bytes of one run of near-field links: texel, count, point, normal.
const NEAR_RUN_BYTES: usize = 16;

/// Section byte sizes.
pub(super) const ENTRY_BYTES: usize = 48;
pub(super) const CELL_TRIANGLE_BYTES: usize = 36;
pub(super) const CLUSTER_BYTES: usize = 32;
pub(super) const GROUP_BYTES: usize = 16;
pub(super) const TILE_BYTES: usize = 20;
pub(super) const FAR_TEXEL_BYTES: usize = 60;

/// Writes tagged, length-prefixed sections to a stream, hashing what it writes (the file's
/// checksum) and counting it; the first write error is kept and every later write skipped.
pub(super) struct Writer<'a> {
    out: &'a mut dyn std::io::Write,
    pub(super) sum: u64,
    pub(super) len: u64,
    pub(super) error: Option<std::io::Error>,
}

impl<'a> Writer<'a> {
    pub(super) fn new(out: &'a mut dyn std::io::Write) -> Self {
        Writer { out, sum: crate::fingerprint::FNV_START, len: 0, error: None }
    }

    /// Write raw bytes (hashed and counted).
    pub(super) fn put(&mut self, bytes: &[u8]) {
        if self.error.is_some() {
            return;
        }
        self.sum = crate::fingerprint::fnv1a(self.sum, bytes);
        self.len += bytes.len() as u64;
        if let Err(e) = self.out.write_all(bytes) {
            self.error = Some(e);
        }
    }

    fn section(&mut self, tag: &[u8; 4], payload: &[u8]) {
        self.put(tag);
        self.put(&(payload.len() as u64).to_le_bytes());
        self.put(payload);
    }

    pub(super) fn entries(&mut self, entries: &[Entry], stays: &[f32]) {
        let mut e = Vec::with_capacity(entries.len() * ENTRY_BYTES);
        for (j, en) in entries.iter().enumerate() {
            for v in [en.position, en.normal, en.albedo] {
                e.extend_from_slice(bytemuck::bytes_of(&v.to_array()));
            }
            e.extend_from_slice(&en.area.to_le_bytes());
            e.extend_from_slice(&en.triangle.to_le_bytes());
            e.extend_from_slice(&stays.get(j).copied().unwrap_or(1.0).to_le_bytes());
        }
        self.section(b"ENTR", &e);
    }

    /// `GAIN`: each entry's bounce gain (none: empty).
    pub(super) fn gains(&mut self, gains: &[Vec3]) {
        let g: Vec<f32> = gains.iter().flat_map(|g| g.to_array()).collect();
        self.section(b"GAIN", bytemuck::cast_slice(&g));
    }

    /// `CELL`: the triangle count, the offsets, the triangles.
    pub(super) fn cells(&mut self, cells: &Cells) {
        let mut c =
            Vec::with_capacity(4 + cells.first.len() * 4 + cells.triangles.len() * CELL_TRIANGLE_BYTES);
        c.extend_from_slice(&(cells.triangles.len() as u32).to_le_bytes());
        for f in &cells.first {
            c.extend_from_slice(&f.to_le_bytes());
        }
        for t in &cells.triangles {
            for v in t {
                c.extend_from_slice(bytemuck::bytes_of(&v.to_array()));
            }
        }
        self.section(b"CELL", &c);
    }

    /// `NEAR`: the box of the points, runs of links per texel with the texel's point, then
    /// the entries, then the factors as half floats. Entries are u16 when every index fits
    /// (width 2); else, when every run's entries lie within 65,536 of its smallest, each run's
    /// smallest (u32, after the heads) and the entries as u16 above it (width 3, v11: a level
    /// of more than 65,536 entries, where one past that bound made every link 4 bytes: 12 MB
    /// of the 16 chambers' 406); else u32 (width 4). A run longer than u16 allows is split (the
    /// reader joins runs of one texel again).
    pub(super) fn near(&mut self, near: &[NearLink], points: &[NearPoint]) {
        let runs: Vec<&[NearLink]> =
            near.chunk_by(|a, b| a.texel == b.texel).flat_map(|r| r.chunks(u16::MAX as usize)).collect();
        let span = |r: &[NearLink]| {
            let lo = r.iter().map(|l| l.entry).min().unwrap_or(0);
            (lo, r.iter().map(|l| l.entry - lo).max().unwrap_or(0))
        };
        let width: u32 = if near.iter().all(|l| l.entry <= u16::MAX as u32) {
            2
        } else if runs.iter().all(|r| span(r).1 <= u16::MAX as u32) {
            3
        } else {
            4
        };
        let bounds = near_point_box(points);
        let mut n = Vec::with_capacity(36 + runs.len() * (NEAR_RUN_BYTES + 4) + near.len() * 6);
        n.extend_from_slice(&(runs.len() as u32).to_le_bytes());
        n.extend_from_slice(&(near.len() as u32).to_le_bytes());
        n.extend_from_slice(&width.to_le_bytes());
        for v in bounds.0.to_array().into_iter().chain(bounds.1.to_array()) {
            n.extend_from_slice(&v.to_le_bytes());
        }
        let mut point = points.iter().peekable();
        for r in &runs {
            n.extend_from_slice(&r[0].texel.to_le_bytes());
            n.extend_from_slice(&(r.len() as u16).to_le_bytes());
            // The point of this run's texel (a missing one is written as zeros and refused on
            // reading, as the checks refuse it in memory).
            while point.peek().is_some_and(|p| p.texel < r[0].texel) {
                point.next();
            }
            let p = point.peek().filter(|p| p.texel == r[0].texel);
            let (q, o) = p.map_or(([0; 3], [0; 2]), |p| {
                (quantize_position(p.position, bounds), encode_octahedral(p.normal))
            });
            for v in q {
                n.extend_from_slice(&v.to_le_bytes());
            }
            for v in o {
                n.extend_from_slice(&v.to_le_bytes());
            }
        }
        match width {
            2 => near.iter().for_each(|l| n.extend_from_slice(&(l.entry as u16).to_le_bytes())),
            3 => {
                for r in &runs {
                    n.extend_from_slice(&span(r).0.to_le_bytes());
                }
                for r in &runs {
                    let lo = span(r).0;
                    r.iter().for_each(|l| n.extend_from_slice(&((l.entry - lo) as u16).to_le_bytes()));
                }
            }
            _ => near.iter().for_each(|l| n.extend_from_slice(&l.entry.to_le_bytes())),
        }
        for l in near {
            n.extend_from_slice(&f16::from_f32(l.factor).to_le_bytes());
        }
        self.section(b"NEAR", &n);
    }

    /// `SEEN` (v15): the links whose texel does not see all of their cell
    /// ([`NearLink::hidden`] not 0), a few per cent of them: their count u32, then per link its
    /// index in `near` (u32) and its bits (u64), in increasing index.
    pub(super) fn seen(&mut self, near: &[NearLink]) {
        let hidden: Vec<(usize, u64)> =
            near.iter().enumerate().filter(|(_, l)| l.hidden != 0).map(|(k, l)| (k, l.hidden)).collect();
        let mut n = Vec::with_capacity(4 + SEEN_BYTES * hidden.len());
        n.extend_from_slice(&(hidden.len() as u32).to_le_bytes());
        for (k, bits) in hidden {
            n.extend_from_slice(&(k as u32).to_le_bytes());
            n.extend_from_slice(&bits.to_le_bytes());
        }
        self.section(b"SEEN", &n);
    }

    /// `ECHO`: point and link counts, each point's albedo (3 bytes, linear / 255), then the
    /// links' receivers and sources (u32) and factors (half floats).
    pub(super) fn echo(&mut self, echo: &Echo) {
        let mut n = Vec::with_capacity(8 + echo.albedo.len() * 3 + echo.links.len() * 10);
        n.extend_from_slice(&(echo.albedo.len() as u32).to_le_bytes());
        n.extend_from_slice(&(echo.links.len() as u32).to_le_bytes());
        for a in &echo.albedo {
            let q = (a.clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round();
            n.extend_from_slice(&[q.x as u8, q.y as u8, q.z as u8]);
        }
        for l in &echo.links {
            n.extend_from_slice(&l.receiver.to_le_bytes());
        }
        for l in &echo.links {
            n.extend_from_slice(&l.source.to_le_bytes());
        }
        for l in &echo.links {
            n.extend_from_slice(&f16::from_f32(l.factor).to_le_bytes());
        }
        self.section(b"ECHO", &n);
    }

    /// `CRSE` (v16): the crease points' count (u32), then each one's texel's near point
    /// (u32; [`Echo::creases`]).
    pub(super) fn creases(&mut self, creases: &[u32]) {
        let mut n = Vec::with_capacity(4 + 4 * creases.len());
        n.extend_from_slice(&(creases.len() as u32).to_le_bytes());
        creases.iter().for_each(|c| n.extend_from_slice(&c.to_le_bytes()));
        self.section(b"CRSE", &n);
    }

    /// `CLUS` and `MEMB`: each cluster's record points at its run of the member list.
    pub(super) fn clusters(&mut self, clusters: &[Cluster]) {
        let (mut c, mut m) = (Vec::new(), Vec::new());
        let mut first = 0u32;
        for cl in clusters {
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
        self.section(b"CLUS", &c);
        self.section(b"MEMB", &m);
    }

    /// `GRUP`: the groups, then (when there are any) the group of each cluster.
    pub(super) fn groups(&mut self, groups: &[Group], group_of: &[u32]) {
        let mut g = Vec::new();
        for gr in groups {
            g.extend_from_slice(&gr.energy.to_le_bytes());
            g.extend_from_slice(&gr.first_tile.to_le_bytes());
            g.extend_from_slice(&gr.tile_count.to_le_bytes());
            g.extend_from_slice(&0u32.to_le_bytes());
        }
        if !groups.is_empty() {
            for &x in group_of {
                g.extend_from_slice(&x.to_le_bytes());
            }
        }
        self.section(b"GRUP", &g);
    }

    pub(super) fn mask(&mut self, mask: &[u8]) {
        self.section(b"MASK", mask);
    }

    pub(super) fn tiles(&mut self, tiles: &[Tile]) {
        let mut t = Vec::with_capacity(tiles.len() * TILE_BYTES);
        put_tiles(&mut t, tiles);
        self.section(b"TILE", &t);
    }

    /// `FARF`: counts, reach and radius, the blocks' pairs and visibility words, the texels, the
    /// entries' energies. Written piece by piece: the visibility is one of the largest sections
    /// after the panes' codes, so no copy of it is made.
    pub(super) fn far(&mut self, f: &Far) {
        let words = f.block_first.len() + f.pair_block.len() + f.visible.len();
        let len = 20 + words * 4 + f.texels.len() * FAR_TEXEL_BYTES + f.energy.len() * 4;
        let start = self.len;
        self.put(b"FARF");
        self.put(&(len as u64).to_le_bytes());
        self.put(&(f.texels.len() as u32).to_le_bytes());
        self.put(&(f.block_first.len() as u32).to_le_bytes());
        self.put(&(f.pair_block.len() as u32).to_le_bytes());
        self.put(&f.reach.to_le_bytes());
        self.put(&f.radius.to_le_bytes());
        self.put(bytemuck::cast_slice(&f.block_first));
        self.put(bytemuck::cast_slice(&f.pair_block));
        self.put(bytemuck::cast_slice(&f.visible));
        let mut b = Vec::with_capacity(1024 * FAR_TEXEL_BYTES);
        for chunk in f.texels.chunks(1024) {
            b.clear();
            for t in chunk {
                b.extend_from_slice(&t.texel.to_le_bytes());
                b.extend_from_slice(bytemuck::bytes_of(&t.position.to_array()));
                b.extend_from_slice(bytemuck::bytes_of(&t.normal.to_array()));
                b.extend_from_slice(bytemuck::cast_slice(&t.entries));
                b.extend_from_slice(bytemuck::cast_slice(&t.weights));
            }
            self.put(&b);
        }
        self.put(bytemuck::cast_slice(&f.energy));
        debug_assert!(self.error.is_some() || self.len - start == 12 + len as u64, "FARF's length");
    }

    /// `TXAR` (v17): the far texels' areas, or none.
    pub(super) fn texel_areas(&mut self, areas: &[f32]) {
        self.section(b"TXAR", bytemuck::cast_slice(areas));
    }

    pub(super) fn data(&mut self, data: &[u8]) {
        self.section(b"DATA", data);
    }
}

fn put_tiles(out: &mut Vec<u8>, tiles: &[Tile]) {
    for tile in tiles {
        out.extend_from_slice(&tile.cluster.to_le_bytes());
        out.extend_from_slice(&tile.index.to_le_bytes());
        out.extend_from_slice(bytemuck::bytes_of(&tile.scale.to_array()));
    }
}

fn get_tile(b: &[u8]) -> Tile {
    Tile { cluster: u32_at(b, 0), index: u32_at(b, 4), scale: v3(b, 8) }
}

/// Why a section could not be read: cut short, or saying something impossible.
pub(super) enum SectionError {
    Truncated(String),
    Corrupt(String),
    /// A part of an older version this build no longer reads.
    Retired(String),
}

use SectionError::{Corrupt, Retired, Truncated};

/// Reads the sections of a checksummed body in order.
pub(super) struct Reader<'a> {
    body: &'a [u8],
    at: usize,
}

fn f32_at(b: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

fn u32_at(b: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

fn v3(b: &[u8], i: usize) -> Vec3 {
    Vec3::new(f32_at(b, i), f32_at(b, i + 4), f32_at(b, i + 8))
}

/// Whether `len` bytes hold exactly `count` records of `size` bytes.
fn holds(len: usize, count: u64, size: usize) -> bool {
    len as u64 == count * size as u64
}

impl<'a> Reader<'a> {
    /// A reader of `body` from byte `at` (just past the JSON header).
    pub(super) fn new(body: &'a [u8], at: usize) -> Self {
        Reader { body, at }
    }

    /// The payload of the next section, which must be `tag`.
    fn next(&mut self, tag: &[u8; 4]) -> Result<&'a [u8], SectionError> {
        let name = String::from_utf8_lossy(tag);
        let body = self.body;
        if self.at + 12 > body.len() {
            return Err(Truncated(format!("section {name} missing")));
        }
        if &body[self.at..self.at + 4] != tag {
            return Err(Corrupt(format!("expected section {name}")));
        }
        let len = u64::from_le_bytes(body[self.at + 4..self.at + 12].try_into().unwrap_or_default());
        let start = self.at + 12;
        if len > (body.len() - start) as u64 {
            return Err(Truncated(format!("section {name} runs past the end")));
        }
        self.at = start + len as usize;
        Ok(&body[start..self.at])
    }

    /// Error unless every byte of the body has been read.
    pub(super) fn finish(&self) -> Result<(), SectionError> {
        match self.body.len() - self.at {
            0 => Ok(()),
            n => Err(Corrupt(format!("{n} unexpected bytes after the last section"))),
        }
    }

    /// `ENTR`: the entries and their stay shares (none before v12, whose slot was padding).
    pub(super) fn entries(
        &mut self,
        header: &Header,
        version: u32,
    ) -> Result<(Vec<Entry>, Vec<f32>), SectionError> {
        let e = self.next(b"ENTR")?;
        if !holds(e.len(), header.entries as u64, ENTRY_BYTES) {
            return Err(Corrupt(format!(
                "{} entries declared, {} bytes of entries",
                header.entries,
                e.len()
            )));
        }
        let entries = e
            .chunks_exact(ENTRY_BYTES)
            .map(|b| Entry {
                position: v3(b, 0),
                normal: v3(b, 12),
                albedo: v3(b, 24),
                area: f32_at(b, 36),
                triangle: u32_at(b, 40),
            })
            .collect();
        let stays = if version >= 12 {
            e.chunks_exact(ENTRY_BYTES).map(|b| f32_at(b, 44)).collect()
        } else {
            Vec::new()
        };
        Ok((entries, stays))
    }

    /// `GAIN` (v14): the bounce gains of `entries` entries, or none.
    pub(super) fn gains(&mut self, entries: usize) -> Result<Vec<Vec3>, SectionError> {
        let g = self.next(b"GAIN")?;
        if !g.is_empty() && !holds(g.len(), entries as u64, 12) {
            return Err(Corrupt(format!("{entries} entries, {} bytes of bounce gains", g.len())));
        }
        Ok(g.chunks_exact(12).map(|b| v3(b, 0)).collect())
    }

    /// `CLUS` and `MEMB`. Members must be entries, and together the clusters may claim at most
    /// the member list: otherwise a small file could make every cluster copy the whole list
    /// (quadratic memory).
    pub(super) fn clusters(&mut self, header: &Header, entries: usize) -> Result<Vec<Cluster>, SectionError> {
        let c = self.next(b"CLUS")?;
        if !holds(c.len(), header.clusters as u64, CLUSTER_BYTES) {
            return Err(Corrupt(format!(
                "{} clusters declared, {} bytes of clusters",
                header.clusters,
                c.len()
            )));
        }
        let m = self.next(b"MEMB")?;
        if m.len() % 4 != 0 {
            return Err(Corrupt("member list is not whole u32s".into()));
        }
        let members: Vec<u32> = m.chunks_exact(4).map(|b| u32_at(b, 0)).collect();
        if let Some(bad) = members.iter().find(|&&x| x as usize >= entries) {
            return Err(Corrupt(format!("member {bad} is not an entry (there are {entries})")));
        }
        let claimed: u64 = c.chunks_exact(CLUSTER_BYTES).map(|b| u32_at(b, 4) as u64).sum();
        if claimed > members.len() as u64 {
            return Err(Corrupt(format!(
                "clusters claim {claimed} members, the list holds {}",
                members.len()
            )));
        }
        let mut clusters = Vec::with_capacity(header.clusters as usize);
        for (k, b) in c.chunks_exact(CLUSTER_BYTES).enumerate() {
            let (first, count) = (u32_at(b, 0) as usize, u32_at(b, 4) as usize);
            if first.checked_add(count).is_none_or(|end| end > members.len()) {
                return Err(Corrupt(format!("cluster {k}'s members run past the member list")));
            }
            clusters.push(Cluster {
                members: members[first..first + count].to_vec(),
                centroid: v3(b, 8),
                energy: f32_at(b, 20),
                first_tile: u32_at(b, 24),
                tile_count: u32_at(b, 28),
            });
        }
        Ok(clusters)
    }

    /// `CELL` for `entries` entries (that the offsets run from 0 to T without going back is an
    /// invariant, checked with the others).
    pub(super) fn cells(&mut self, entries: usize) -> Result<Cells, SectionError> {
        let c = self.next(b"CELL")?;
        if c.len() < 4 {
            return Err(Corrupt(format!("cell section of {} bytes", c.len())));
        }
        let t = u32_at(c, 0) as u64;
        let want = 4 + (entries as u64 + 1) * 4 + t * CELL_TRIANGLE_BYTES as u64;
        if c.len() as u64 != want {
            return Err(Corrupt(format!(
                "{t} cell triangles for {entries} entries declared, {} bytes of cells",
                c.len()
            )));
        }
        let (first, tris) = c[4..].split_at((entries + 1) * 4);
        Ok(Cells {
            first: first.chunks_exact(4).map(|b| u32_at(b, 0)).collect(),
            triangles: tris
                .chunks_exact(CELL_TRIANGLE_BYTES)
                .map(|b| [v3(b, 0), v3(b, 12), v3(b, 24)])
                .collect(),
        })
    }

    /// `FARF` (what its indices point at is checked with the other invariants).
    pub(super) fn far(&mut self) -> Result<Far, SectionError> {
        let b = self.next(b"FARF")?;
        if b.len() < 20 {
            return Err(Corrupt(format!("far-field section of {} bytes", b.len())));
        }
        let (texels, offsets, pairs) = (u32_at(b, 0) as u64, u32_at(b, 4) as u64, u32_at(b, 8) as u64);
        let words = offsets + pairs * (1 + Far::BLOCK as u64);
        let fixed = 20 + words * 4 + texels * FAR_TEXEL_BYTES as u64;
        if (b.len() as u64) < fixed || (b.len() as u64 - fixed) % 4 != 0 {
            return Err(Corrupt(format!(
                "{texels} far-field texels, {offsets} block offsets and {pairs} pairs of blocks declared, {} bytes",
                b.len()
            )));
        }
        let (reach, radius) = (f32_at(b, 12), f32_at(b, 16));
        let words_of = |c: &[u8]| c.chunks_exact(4).map(|c| u32_at(c, 0)).collect::<Vec<u32>>();
        let (first, rest) = b[20..].split_at(offsets as usize * 4);
        let (others, rest) = rest.split_at(pairs as usize * 4);
        let (v, rest) = rest.split_at(pairs as usize * Far::BLOCK * 4);
        let (t, e) = rest.split_at(texels as usize * FAR_TEXEL_BYTES);
        let energy = e.chunks_exact(4).map(|c| f32_at(c, 0)).collect();
        let (block_first, pair_block, visible) = (words_of(first), words_of(others), words_of(v));
        let at = |c: &[u8], i: usize| [u32_at(c, i), u32_at(c, i + 4), u32_at(c, i + 8), u32_at(c, i + 12)];
        let texels = t
            .chunks_exact(FAR_TEXEL_BYTES)
            .map(|c| FarTexel {
                texel: u32_at(c, 0),
                position: v3(c, 4),
                normal: v3(c, 16),
                entries: at(c, 28),
                weights: at(c, 44).map(f32::from_bits),
            })
            .collect();
        Ok(Far { reach, radius, block_first, pair_block, visible, texels, energy, areas: Vec::new() })
    }

    /// `TXAR` (v17): the areas of `texels` far texels, or none.
    pub(super) fn texel_areas(&mut self, texels: usize) -> Result<Vec<f32>, SectionError> {
        let a = self.next(b"TXAR")?;
        if !a.is_empty() && !holds(a.len(), texels as u64, 4) {
            return Err(Corrupt(format!("{texels} far-field texels, {} bytes of their areas", a.len())));
        }
        Ok(a.chunks_exact(4).map(|c| f32_at(c, 0)).collect())
    }

    /// `ECHO` for `points` near points (what the links point at is checked with the others).
    pub(super) fn echo(&mut self, points: usize) -> Result<Echo, SectionError> {
        let n = self.next(b"ECHO")?;
        if n.len() < 8 {
            return Err(Corrupt(format!("echo section of {} bytes", n.len())));
        }
        let (albedos, links) = (u32_at(n, 0) as u64, u32_at(n, 4) as u64);
        if n.len() as u64 != 8 + albedos * 3 + links * 10 {
            return Err(Corrupt(format!(
                "{albedos} echo albedos and {links} links declared, {} bytes",
                n.len()
            )));
        }
        if albedos != 0 && albedos != points as u64 {
            return Err(Corrupt(format!("{albedos} echo albedos for {points} near-field points")));
        }
        let (a, rest) = n[8..].split_at(albedos as usize * 3);
        let (receivers, rest) = rest.split_at(links as usize * 4);
        let (sources, factors) = rest.split_at(links as usize * 4);
        let albedo =
            a.chunks_exact(3).map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) / 255.0).collect();
        let links = (0..links as usize)
            .map(|k| EchoLink {
                receiver: u32_at(receivers, 4 * k),
                source: u32_at(sources, 4 * k),
                factor: f16::from_le_bytes([factors[2 * k], factors[2 * k + 1]]).to_f32(),
            })
            .collect();
        Ok(Echo { albedo, links, creases: Vec::new() })
    }

    /// `CRSE` (v16; what the parents are is an invariant, checked with the others).
    pub(super) fn creases(&mut self) -> Result<Vec<u32>, SectionError> {
        let n = self.next(b"CRSE")?;
        if n.len() < 4 || n.len() as u64 != 4 + 4 * u32_at(n, 0) as u64 {
            return Err(Corrupt(format!("crease section of {} bytes", n.len())));
        }
        Ok(n[4..].chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
    }

    /// `NEAR` (what the links point at is an invariant, checked with the others).
    pub(super) fn near(&mut self) -> Result<(Vec<NearLink>, Vec<NearPoint>), SectionError> {
        let n = self.next(b"NEAR")?;
        if n.len() < 36 {
            return Err(Corrupt(format!("near-field section of {} bytes", n.len())));
        }
        let (runs, links, width) = (u32_at(n, 0) as u64, u32_at(n, 4) as u64, u32_at(n, 8) as u64);
        // Width 3: a u32 base per run, then u16 entries above it.
        let (bases, bytes) = match width {
            2 | 4 => (0, width),
            3 => (4 * runs, 2),
            _ => (0, 0),
        };
        if bytes == 0 || n.len() as u64 != 36 + runs * NEAR_RUN_BYTES as u64 + bases + links * (bytes + 2) {
            return Err(Corrupt(format!(
                "{runs} near-field runs and {links} links of {width}-byte entries declared, {} bytes",
                n.len()
            )));
        }
        let bounds = (v3(n, 12), v3(n, 24));
        let (heads, rest) = n[36..].split_at(runs as usize * NEAR_RUN_BYTES);
        let (base, rest) = rest.split_at(bases as usize);
        let (entries, factors) = rest.split_at((links * bytes) as usize);
        let entry = |k: usize, run: usize| -> Result<u32, SectionError> {
            let i = k * bytes as usize;
            match width {
                2 => Ok(u16::from_le_bytes([entries[i], entries[i + 1]]) as u32),
                3 => u32_at(base, 4 * run)
                    .checked_add(u16::from_le_bytes([entries[i], entries[i + 1]]) as u32)
                    .ok_or_else(|| Corrupt("a near-field run's base overflows".into())),
                _ => Ok(u32_at(entries, i)),
            }
        };
        let mut out = Vec::with_capacity(links as usize);
        let mut points: Vec<NearPoint> = Vec::with_capacity(runs as usize);
        let i16_at = |b: &[u8], i: usize| i16::from_le_bytes([b[i], b[i + 1]]);
        let u16_at = |b: &[u8], i: usize| u16::from_le_bytes([b[i], b[i + 1]]);
        for (run, h) in heads.chunks_exact(NEAR_RUN_BYTES).enumerate() {
            let (texel, count) = (u32_at(h, 0), u16_at(h, 4) as u64);
            if out.len() as u64 + count > links {
                return Err(Corrupt("near-field runs hold more links than declared".into()));
            }
            if points.last().is_none_or(|p| p.texel != texel) {
                let q = [u16_at(h, 6), u16_at(h, 8), u16_at(h, 10)];
                let position = dequantize_position(q, bounds);
                points.push(NearPoint {
                    texel,
                    position,
                    normal: decode_octahedral([i16_at(h, 12), i16_at(h, 14)]),
                });
            }
            for _ in 0..count {
                let k = out.len();
                let factor = f16::from_le_bytes([factors[2 * k], factors[2 * k + 1]]).to_f32();
                out.push(NearLink { texel, entry: entry(k, run)?, factor, hidden: 0 });
            }
        }
        if out.len() as u64 != links {
            return Err(Corrupt("near-field runs hold fewer links than declared".into()));
        }
        Ok((out, points))
    }

    /// `SEEN` (v15): each listed link's [`NearLink::hidden`] bits, into `near` as read.
    pub(super) fn seen(&mut self, near: &mut [NearLink]) -> Result<(), SectionError> {
        let n = self.next(b"SEEN")?;
        let count = if n.len() >= 4 { u32_at(n, 0) as u64 } else { u64::MAX };
        if n.len() as u64 != 4u64.saturating_add(count.saturating_mul(SEEN_BYTES as u64)) {
            return Err(Corrupt(format!("near-field sight section of {} bytes", n.len())));
        }
        let mut last = None;
        for pair in n[4..].chunks_exact(SEEN_BYTES) {
            let k = u32_at(pair, 0) as usize;
            let bits = u64::from_le_bytes(pair[4..12].try_into().unwrap_or_default());
            if last.is_some_and(|l| k <= l) || k >= near.len() || bits == 0 {
                return Err(Corrupt(format!(
                    "near-field sight {bits:#x} of link {k} ({} links; listed in increasing order, none 0)",
                    near.len()
                )));
            }
            near[k].hidden = bits;
            last = Some(k);
        }
        Ok(())
    }

    /// `GRUP`: the groups and the group of each cluster (empty when there are no groups).
    pub(super) fn groups(&mut self, header: &Header) -> Result<(Vec<Group>, Vec<u32>), SectionError> {
        let g = self.next(b"GRUP")?;
        let (n_groups, n_clusters) = (header.groups as u64, header.clusters as u64);
        let want = if n_groups == 0 { 0 } else { n_groups * GROUP_BYTES as u64 + n_clusters * 4 };
        if g.len() as u64 != want {
            return Err(Corrupt(format!(
                "{n_groups} groups over {n_clusters} clusters declared, {} bytes of groups",
                g.len()
            )));
        }
        let (records, of) = g.split_at(n_groups as usize * GROUP_BYTES);
        let groups = records
            .chunks_exact(GROUP_BYTES)
            .map(|b| Group { energy: f32_at(b, 0), first_tile: u32_at(b, 4), tile_count: u32_at(b, 8) })
            .collect();
        Ok((groups, of.chunks_exact(4).map(|b| u32_at(b, 0)).collect()))
    }

    pub(super) fn mask(&mut self) -> Result<Vec<u8>, SectionError> {
        Ok(self.next(b"MASK")?.to_vec())
    }

    pub(super) fn tiles(&mut self, header: &Header) -> Result<Vec<Tile>, SectionError> {
        let t = self.next(b"TILE")?;
        if !holds(t.len(), header.tiles as u64, TILE_BYTES) {
            return Err(Corrupt(format!("{} tiles declared, {} bytes of tiles", header.tiles, t.len())));
        }
        Ok(t.chunks_exact(TILE_BYTES).map(get_tile).collect())
    }

    /// `DIPO`, the dipole panes of versions 6 to 12: skipped when it holds none (every file
    /// the default preset wrote), refused when it holds some, since this build does not compose
    /// them (removed in v13: with the far field they made every measured placement worse).
    pub(super) fn retired_dipoles(&mut self) -> Result<(), SectionError> {
        let d = self.next(b"DIPO")?;
        if d.len() < 12 {
            return Err(Corrupt(format!("dipole section of {} bytes", d.len())));
        }
        match u32_at(d, 0) {
            0 if d.len() == 12 && u32_at(d, 4) == 0 => Ok(()),
            0 => Err(Corrupt(format!(
                "an empty dipole section of {} bytes and {} tiles",
                d.len(),
                u32_at(d, 4)
            ))),
            n => Err(Retired(format!(
                "holds dipole panes for {n} clusters (prm precompute --dipole-block, versions 6 to 12), \
                 which this build no longer reads"
            ))),
        }
    }

    /// `DATA`: the intensity codes of every tile's stored texels (how many is the tile
    /// layout's business, checked with the other invariants).
    pub(super) fn data(&mut self) -> Result<Vec<u8>, SectionError> {
        Ok(self.next(b"DATA")?.to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Links written and read back, their points round as stored.
    fn round_trip(near: &[NearLink], points: &[NearPoint]) -> (u32, usize, Vec<NearLink>) {
        let mut bytes = Vec::new();
        let mut w = Writer::new(&mut bytes);
        w.near(near, points);
        assert!(w.error.is_none());
        let width = u32_at(&bytes, 12 + 8);
        let Ok((back, _)) = Reader::new(&bytes, 0).near() else { panic!("width {width} not read back") };
        (width, bytes.len(), back)
    }

    /// The three entry widths: 2 bytes while every entry fits, 2 above each run's smallest
    /// when the level has more entries but a texel's links lie together, 4 when they do not;
    /// each reads back the same links, and a base that overflows is refused.
    #[test]
    fn near_entries_take_the_narrowest_width_that_holds_them() {
        let points: Vec<NearPoint> = (0..40)
            .map(|t| NearPoint { texel: t, position: Vec3::splat(t as f32), normal: Vec3::Y })
            .collect();
        let links = |entry: &dyn Fn(u32, u32) -> u32| -> Vec<NearLink> {
            (0..40)
                .flat_map(|t| (0..5).map(move |k| (t, k)))
                .map(|(t, k)| NearLink { texel: t, entry: entry(t, k), factor: 0.25 * k as f32, hidden: 0 })
                .collect()
        };
        let small = links(&|t, k| t * 100 + k);
        let together = links(&|t, k| 70_000 + t * 1_000 + 7 * k);
        let apart = links(&|t, k| if k == 4 { 200_000 } else { t });
        let mut sizes = Vec::new();
        for (near, want) in [(&small, 2), (&together, 3), (&apart, 4)] {
            let (width, size, back) = round_trip(near, &points);
            assert_eq!(width, want);
            assert_eq!(&back, near, "width {want}");
            sizes.push(size);
        }
        // Width 3 pays 4 bytes a run (40 runs) against 2 a link (200 links) at width 4.
        assert_eq!(sizes[1], sizes[0] + 40 * 4);
        assert_eq!(sizes[2], sizes[0] + 200 * 2);
        // A run's base plus its offset past u32: refused, not wrapped.
        let mut bytes = Vec::new();
        Writer::new(&mut bytes).near(&together, &points);
        let base = 12 + 36 + 40 * NEAR_RUN_BYTES;
        bytes[base..base + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(Reader::new(&bytes, 0).near(), Err(Corrupt(_))));
    }

    /// `SEEN` lists the links that hide triangles, by index, and reads back into them; a
    /// length that is not its count's, a zero, an index out of order or past the links are
    /// refused.
    #[test]
    fn hidden_triangles_round_trip_and_bad_lists_are_refused() {
        let link = |entry: u32, hidden: u64| NearLink { texel: 0, entry, factor: 0.5, hidden };
        let near = vec![link(0, 0), link(1, 0b110), link(2, 0), link(3, 1 << 63)];
        let mut bytes = Vec::new();
        Writer::new(&mut bytes).seen(&near);
        // Tag and length, count, two links of 12 bytes.
        assert_eq!(bytes.len(), 12 + 4 + 2 * SEEN_BYTES);
        let mut back: Vec<NearLink> = near.iter().map(|l| NearLink { hidden: 0, ..*l }).collect();
        assert!(Reader::new(&bytes, 0).seen(&mut back).is_ok());
        assert_eq!(back, near);
        let patched = |words: &[(usize, u32)]| {
            let mut b = bytes.clone();
            for &(at, word) in words {
                b[12 + at..12 + at + 4].copy_from_slice(&word.to_le_bytes());
            }
            let mut links = near.clone();
            Reader::new(&b, 0).seen(&mut links)
        };
        let cases: [(&str, &[(usize, u32)]); 4] = [
            ("count", &[(0, 3)]),
            ("a zero", &[(8, 0), (12, 0)]),
            ("out of order", &[(4 + SEEN_BYTES, 1)]),
            ("past the links", &[(4 + SEEN_BYTES, 4)]),
        ];
        for (what, words) in cases {
            assert!(matches!(patched(words), Err(Corrupt(_))), "{what}");
        }
    }
}
