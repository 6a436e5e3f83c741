//! GPU memory: what a `.prm` costs on the device, stated before any device is touched
//! ([`GpuMemory::estimate`], `prm info --prm`) and recorded as the runtime allocates it
//! ([`crate::Runtime::gpu_memory`]), the two held to each other by a test.
//!
//! The estimate lists every table that grows with the atlas, the tiles or the links (pane
//! data, tile records, the compose's per-tile lists, texel slots, the lightmap's pages, the
//! near and far fields, the echo, the entries' cells), each at exactly the bytes allocated;
//! buffers of a fixed size (uniforms, the far field's source list) and the per-frame state of
//! the entries (under 200 bytes an entry) are left out. Shadow maps depend on the lights, not the map: [`shadow_bytes_per_layer`] gives their
//! cost per layer (a point light takes 6, a spot or directional light 1).

use std::cell::RefCell;

use prm::prm_file::Prm;

use crate::compose::{split_words, PANE_DATA, SLOTS_AND_RANGES};
use crate::layout::{
    ActiveRecord, FarEntry, GpuCellTriangle, GpuEchoLink, GpuFarTexel, GpuHotEntry, GpuNearLink, NearTexel,
    TileRecord,
};

/// The name of the lightmap texture's item (not a storage buffer).
pub const LIGHTMAP: &str = "indirect lightmap";

/// Named byte counts of GPU allocations.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GpuMemory {
    pub items: Vec<(String, u64)>,
}

impl GpuMemory {
    /// All of it, in bytes.
    pub fn total(&self) -> u64 {
        self.items.iter().map(|(_, b)| b).sum()
    }

    /// The bytes of items named `name`.
    pub fn get(&self, name: &str) -> u64 {
        self.items.iter().filter(|(n, _)| n == name).map(|(_, b)| b).sum()
    }

    /// The device memory the runtime's tables for `prm` take (before shadow maps), from the
    /// map alone: what `Runtime::new` allocates, less buffers of a fixed size.
    pub fn estimate(prm: &Prm) -> GpuMemory {
        let size = |n: usize, each: usize| storage(n as u64 * each as u64);
        let atlas = prm.header().atlas();
        let per_tile = tiles_per_atlas_tile(prm);
        let records = prm.tiles().len();
        let (n, c, g) = (prm.entries().len(), prm.clusters().len(), prm.groups().len());
        let near = prm.near().len();
        let points = prm.near_points().len();
        let far_texels = prm.far().texels.len();
        let members: usize = prm.clusters().iter().map(|c| c.members.len()).sum();
        let rooms = crate::cpu::rooms::room_count(&crate::cpu::rooms::cluster_rooms(prm));
        // The near sums hold the near points, then the far field's texels that are not one.
        let linked = |texel: u32| prm.near_points().binary_search_by_key(&texel, |p| p.texel).is_ok();
        let far_only = prm.far().texels.iter().filter(|t| !linked(t.texel)).count();
        // The echo's tables, with each near point of a cell listed once under it.
        let echoed = !prm.echo().links.is_empty();
        let in_cells =
            crate::cpu::point_cells(prm).iter().filter(|&&c| c != crate::contract::NO_CELL).count();
        let words = prm.data().len().div_ceil(4).max(1);
        let split = split_words(words);
        let items = [
            (PANE_DATA[0], storage(4 * split as u64)),
            (PANE_DATA[1], storage(4 * (words - split) as u64)),
            ("tile records", size(records, std::mem::size_of::<TileRecord>())),
            ("active records", size(records, std::mem::size_of::<ActiveRecord>())),
            (
                "active counts and corner weights",
                size(
                    per_tile.len()
                        + records * 4 * crate::contract::CORNER_WORDS as usize
                        + crate::tile_changes::state_words(per_tile.len() as u32) as usize,
                    4,
                ),
            ),
            (SLOTS_AND_RANGES, storage(atlas.texels() * 8 + per_tile.len() as u64 * 8)),
            (LIGHTMAP, atlas.texels() * 16),
            ("link ids by entry", size(crate::concentrate::link_ids_len(prm), 4)),
            ("entry cells", size(prm.cells().triangles.len(), std::mem::size_of::<GpuCellTriangle>())),
            ("near links", size(near, std::mem::size_of::<GpuNearLink>())),
            ("link light", size(near, 16)),
            ("near texels", size(points, std::mem::size_of::<NearTexel>())),
            ("far visibility", size(crate::far::far_words_len(prm.far()), 4)),
            (
                crate::far::SOURCE_SEES,
                if far_texels > 0 { size(crate::far::source_sees_words(n), 4) } else { 0 },
            ),
            ("far texels", size(far_texels, std::mem::size_of::<GpuFarTexel>())),
            ("hot entries", size(n, std::mem::size_of::<GpuHotEntry>())),
            // Each entry's irradiance, then where its light lands and which way it leaves.
            ("entry irradiance", size(3 * n.max(1), 16)),
            // The near pass's deviations and the far field's per-entry tables after them.
            ("entry deviations", size(crate::far::deviation_len(n), 16)),
            (crate::irradiance::ENTRY_HIDDEN, size(n, 8)),
            ("far entries", size(n, std::mem::size_of::<FarEntry>())),
            // The sums, then the near points' expected light.
            ("near sums", size(2 * points + far_only, 16)),
            ("last composed near sums", size((points + far_only).max(1), 16)),
            ("near sums' tiles", size(points + far_only, 4)),
            ("echo links", size(prm.echo().links.len(), std::mem::size_of::<GpuEchoLink>())),
            ("echo runs", size(points, 16)),
            ("echo sums", size(points, 16)),
            ("echo cells", if echoed { size(n.max(1), 16) } else { 0 }),
            ("echo cell points", if echoed { size(in_cells.max(1), 4) } else { 0 }),
            ("cluster weights", size(c.max(1), 16)),
            ("selected weights", size((c + g).max(1), 16)),
            (crate::tile_changes::LAST_RECORDS, size(records.max(1), 16)),
            // Without a far field there is no lift (`crate::lift`).
            // The relay's and the lift's (`crate::near::cluster_members`).
            // Four words a member, then each far texel's slot under its nearest entry's cell.
            ("cluster members", if far_texels > 0 { size(4 * members + far_texels, 4) } else { 0 }),
            ("lifted weights", if far_texels > 0 { size(crate::lift::lifted_len(c, rooms), 16) } else { 0 }),
            // The clusters' energies, the rooms, the entries' (A/N) g rho, the slots' areas.
            (
                "lift tables",
                if far_texels > 0 {
                    let areas = if prm.far().areas.is_empty() { 1 } else { 4 * members + far_texels };
                    size(4 * c + crate::lift::room_words_len(c, rooms) + 4 * n + areas, 4)
                } else {
                    0
                },
            ),
        ];
        GpuMemory { items: items.iter().map(|(n, b)| (n.to_string(), *b)).collect() }
    }
}

/// Bytes of the shadow maps of `lights` at `size`^2 a layer, a directional light's map in
/// `sun_tiles` x `sun_tiles` tiles ([`sun_tiles`]), and the cubes of the first
/// [`CLOSE_SIGHTS`](crate::cpu::CLOSE_SIGHTS) spots that could own one (those whose spots the
/// far field sees: `crate::lights::layers`): at most what they take.
pub fn shadow_bytes(lights: &[prm::Light], size: u32, sun_tiles: u32) -> u64 {
    let own: u64 = lights.iter().map(|l| crate::lights::layers(l, sun_tiles, false) as u64).sum();
    let cubed = lights
        .iter()
        .filter(|l| crate::lights::layers(l, sun_tiles, true) > crate::lights::layers(l, sun_tiles, false))
        .count()
        .min(crate::cpu::CLOSE_SIGHTS) as u64;
    (own + cubed * crate::contract::CUBE_LAYERS as u64) * shadow_bytes_per_layer(size)
}

pub use crate::lights::SUN_TILES_MAX;

/// Tiles per side of a directional light's shadow map over `scene`, at most `max`
/// ([`crate::RuntimeParams::sun_tiles`]): what [`shadow_bytes`] is given.
pub fn sun_tiles(scene: &prm::Scene, max: u32) -> u32 {
    crate::lights::sun_tiles(crate::shadow::scene_bounds(scene), max)
}

/// Bytes of one shadow-map layer of `size`^2 (32-bit depth) with its block minima
/// (`crate::shadow`).
pub fn shadow_bytes_per_layer(size: u32) -> u64 {
    size as u64 * size as u64 * 4 + crate::shadow::BLOCK_BYTES_PER_LAYER
}

/// What [`crate::gpu::storage_buffer`] allocates for `bytes` of data (at least 256, a whole
/// number of words).
fn storage(bytes: u64) -> u64 {
    bytes.max(256).next_multiple_of(4)
}

/// Stored tiles (panes' and groups') over each atlas tile.
pub(crate) fn tiles_per_atlas_tile(prm: &Prm) -> Vec<u64> {
    let mut per_tile = vec![0u64; (prm.tiles_x() as usize) * (prm.tiles_y() as usize)];
    for t in prm.tiles() {
        if let Some(n) = per_tile.get_mut(t.index as usize) {
            *n += 1;
        }
    }
    per_tile
}

thread_local! {
    static RECORDING: RefCell<Option<Vec<(String, u64)>>> = const { RefCell::new(None) };
}

/// Note an allocation of `bytes` named `label` in this thread's recording, if one is open.
pub(crate) fn record(label: &str, bytes: u64) {
    RECORDING.with(|r| {
        if let Some(items) = r.borrow_mut().as_mut() {
            items.push((label.to_string(), bytes));
        }
    });
}

/// A recording of the allocations this thread makes until [`Recording::finish`]; a recording
/// already open resumes after it (also when this one is dropped unfinished).
pub(crate) struct Recording {
    /// The recording to resume; `None` once finished.
    outer: Option<Option<Vec<(String, u64)>>>,
}

impl Recording {
    pub(crate) fn start() -> Recording {
        Recording { outer: Some(RECORDING.with(|r| r.borrow_mut().replace(Vec::new()))) }
    }

    /// What was allocated since `start`.
    pub(crate) fn finish(mut self) -> GpuMemory {
        let outer = self.outer.take().flatten();
        GpuMemory {
            items: RECORDING.with(|r| std::mem::replace(&mut *r.borrow_mut(), outer)).unwrap_or_default(),
        }
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        if let Some(outer) = self.outer.take() {
            RECORDING.with(|r| *r.borrow_mut() = outer);
        }
    }
}
