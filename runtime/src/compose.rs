//! Compose on the GPU (DESIGN.md §5 step 4; `shaders/compose.wgsl`): the indirect lightmap
//! `sum_c selected_c x pane_c`, read from stored tiles only.
//!
//! The `.prm`'s tiles are regrouped once, at load, by the atlas tile they cover
//! (`tile_range(t)` = a run of [`TileRecord`]s), and every atlas texel gets its slot among its
//! atlas tile's stored texels (or `NO_SLOT`). The 8-bit texel codes are uploaded as is, four
//! to a `u32`. Per compose, one invocation per atlas tile lists the stored tiles of selected
//! panes with their weight at the tile's four corners already applied to the tile's colour
//! scale (one weight under a global budget; a local budget's picks at the tile grid's vertices
//! come first, one workgroup per vertex: `cpu::compose_local` says what and why, and is the
//! twin); then each texel sums just those: a 64-byte entry (the corners blended at the texel)
//! and a byte each. A
//! compose reads `1 byte x stored texels` of each selected pane, never a whole atlas per
//! cluster, and its work per texel is the number of selected panes stored there. Texels with
//! near-field links or far field add their sum (`crate::near`, `crate::far`), and the total is
//! clamped at zero.
//!
//! The lightmap is `Rgba32Float` (irradiance in W/m² in RGB, A = 1), atlas-sized, row 0 at
//! v = 0: DESIGN.md §3's layout.

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, CORNER_WORDS, LINEAR, NO_SLOT, TILE, WG_LINEAR};
use crate::gpu;
use crate::layout::{ActiveRecord, ComposeParams, GpuStruct, TileRecord};
use crate::near::NearPass;
use crate::tile_changes::{self, ComposeBuffers, TileChanges};

/// The two buffers of the panes' codes ([`split_words`]), as the GPU memory estimate
/// names them.
pub const PANE_DATA: [&str; 2] = ["pane data", "pane data, second half"];

/// The texel slots and tile ranges' buffer, as the GPU memory estimate names it.
pub const SLOTS_AND_RANGES: &str = "texel slots and tile ranges";

/// Of `words` words of codes, how many the first of the two buffers holds (the rest go in the
/// second): half, rounded up. A device binds at most `max_storage_buffer_binding_size` bytes
/// a buffer (128 MiB on lavapipe and WebGPU's default), and the 4 x 4 halls' codes are 144 MB:
/// in two halves a map may have twice that.
pub fn split_words(words: usize) -> usize {
    words.div_ceil(2)
}

/// The pass's one bind group.
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(ComposeParams::NAME), COMPUTE),
    // The weight pass's output: C clusters, then G groups.
    b("selected", Res::Read("array<vec4f>"), COMPUTE),
    b("records", Res::Read("array<TileRecord>"), COMPUTE),
    // Per atlas texel: its slot among its atlas tile's stored texels, or NO_SLOT; and its index
    // in near_sum, or NO_SLOT. Then per atlas tile: (first record, record count). One buffer,
    // for the stage's 8 storage buffers.
    b("slots", Res::Read("array<vec2u>"), COMPUTE),
    // The panes' codes, four a word: the first `ComposeParams::data_split` words, then
    // the rest ([`split_words`]).
    b("data", Res::Read("array<u32>"), COMPUTE),
    b("data_hi", Res::Read("array<u32>"), COMPUTE),
    b("lightmap", Res::WriteTexture2dArray(wgpu::TextureFormat::Rgba32Float), COMPUTE),
    b("active_records", Res::ReadWrite("array<ActiveRecord>"), COMPUTE),
    // Per atlas tile, the records gathered; then, under a local budget, per record and corner
    // of its tile its pane's state and weight at that vertex (`shaders/compose.wgsl`: one
    // buffer, for the stage's 8 storage buffers).
    b("counts", Res::ReadWrite("array<u32>"), COMPUTE),
    // The near pass's output (`crate::near`).
    b("near_sum", Res::Read("array<vec4f>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "compose",
    body: include_str!("../../shaders/compose.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "select_main", workgroup: LINEAR },
        Compute { entry: "gather_main", workgroup: LINEAR },
        Compute { entry: "compose_main", workgroup: TILE },
    ],
};

pub struct ComposePass {
    pipeline: wgpu::ComputePipeline,
    select: wgpu::ComputePipeline,
    params: ComposeParams,
    params_buf: wgpu::Buffer,
    gather: wgpu::ComputePipeline,
    tiles: u32,
    group: wgpu::BindGroup,
    size: (u32, u32),
    /// The indirect lightmap.
    pub lightmap: wgpu::Texture,
    /// Per atlas tile, the records covering it (for byte counts).
    records_per_tile: Vec<u32>,
    /// Per atlas tile, its stored texels (for byte counts).
    texels_per_tile: Vec<u64>,
    /// Per atlas tile, the records the last compose summed (`gather_main`'s count).
    counts: wgpu::Buffer,
    texels: u64,
    /// The tiles to compose again (`crate::tile_changes`).
    changes: TileChanges,
    /// Whether the next compose works every tile (the first, or the budget changed).
    all_next: bool,
}

/// What the compose reads, built on the CPU once per map.
struct Tables {
    /// Each stored texel's place in its atlas tile's list (`NO_SLOT` elsewhere).
    slots: Vec<u32>,
    /// Per atlas tile, (first record, record count).
    ranges: Vec<[u32; 2]>,
    /// Stored tiles grouped by atlas tile, panes in order within each.
    records: Vec<TileRecord>,
}

impl Tables {
    fn new(prm: &Prm, atlas_tiles: usize) -> Tables {
        let layout = prm.layout();
        let mut slots = vec![NO_SLOT; prm.texel_count()];
        for list in &layout.texels {
            for (k, &texel) in list.iter().enumerate() {
                slots[texel as usize] = k as u32;
            }
        }
        let mut by_tile: Vec<Vec<TileRecord>> = vec![Vec::new(); atlas_tiles];
        for (k, t) in prm.tiles().iter().enumerate() {
            by_tile[t.index as usize].push(TileRecord {
                scale: t.scale.to_array(),
                cluster: t.cluster,
                data_offset: layout.offsets[k] as u32,
                energy: crate::cpu::stored_tile_energy(prm, &layout, k),
                group: prm.group_of().get(t.cluster as usize).copied().unwrap_or(NO_SLOT),
                ..Default::default()
            });
        }
        // Pane order within each atlas tile (clusters, then groups): a local budget finds
        // panes by binary search and breaks ties to the lower pane (`cpu::vertex_weights`).
        for list in &mut by_tile {
            list.sort_by_key(|r| r.cluster);
        }
        let mut ranges = Vec::with_capacity(atlas_tiles);
        let mut records = Vec::with_capacity(prm.tiles().len());
        for list in &by_tile {
            ranges.push([records.len() as u32, list.len() as u32]);
            records.extend_from_slice(list);
        }
        link_corners(prm, &ranges, &mut records);
        Tables { slots, ranges, records }
    }
}

/// Fills what a local budget's picks need of each record (`TileRecord::next`, `owner`,
/// `summed`): the chains of each group's clusters within a tile, and per corner of the tile the
/// record standing for the pane at that vertex and the pane's energy around it (as
/// `cpu::vertex_weights` merges them).
fn link_corners(prm: &Prm, ranges: &[[u32; 2]], records: &mut [TileRecord]) {
    let (tx, ty) = (prm.tiles_x() as usize, prm.tiles_y() as usize);
    for &[first, count] in ranges {
        let range = first as usize..(first + count) as usize;
        let mut head: std::collections::HashMap<u32, u32> = Default::default();
        for k in range.rev() {
            let r = records[k];
            if r.group != NO_SLOT {
                records[k].next = head.insert(r.group, k as u32).unwrap_or(NO_SLOT);
            } else {
                records[k].next = NO_SLOT;
            }
        }
        let (c, g) = (prm.clusters().len() as u32, prm.groups().len() as u32);
        for r in &mut records[first as usize..(first + count) as usize] {
            if r.cluster >= c && r.cluster < c + g {
                r.next = head.get(&(r.cluster - c)).copied().unwrap_or(NO_SLOT);
            }
        }
    }
    let find = |t: usize, pane: u32| -> Option<usize> {
        let [first, count] = ranges[t];
        let list = &records[first as usize..(first + count) as usize];
        list.binary_search_by_key(&pane, |r| r.cluster).ok().map(|i| first as usize + i)
    };
    let mut corners = vec![([0u32; 4], [0.0f32; 4]); records.len()];
    for (t, &[first, count]) in ranges.iter().enumerate() {
        let (x, y) = (t % tx, t / tx);
        for k in first as usize..(first + count) as usize {
            let pane = records[k].cluster;
            for q in 0..4 {
                let around = crate::cpu::tiles_around(x + (q & 1), y + (q >> 1), tx, ty);
                // The record itself is in the tile around its corner (slot 3 - q).
                let (mut owner, mut summed) = (None, 0.0f32);
                for (slot, tile) in around.iter().enumerate() {
                    if let Some(j) = tile.and_then(|u| find(u, pane)) {
                        // The vertex is corner 3 - slot of the tile in slot `slot`.
                        owner.get_or_insert((j * 4 + 3 - slot) as u32);
                        summed += records[j].energy;
                    }
                }
                corners[k].0[q] = owner.unwrap_or((k * 4 + q) as u32);
                corners[k].1[q] = summed;
            }
        }
    }
    for (r, (owner, summed)) in records.iter_mut().zip(corners) {
        (r.owner, r.summed) = (owner, summed);
    }
}

/// The indirect lightmap the compose writes and shading reads: a layer per page.
fn lightmap_texture(device: &wgpu::Device, w: u32, page_rows: u32, pages: u32) -> wgpu::Texture {
    crate::memory::record(crate::memory::LIGHTMAP, w as u64 * page_rows as u64 * pages as u64 * 16);
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("indirect lightmap"),
        size: wgpu::Extent3d { width: w, height: page_rows, depth_or_array_layers: pages },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::STORAGE_BINDING
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

/// A view of every layer of the lightmap, as an array (even with one layer).
pub(crate) fn array_view() -> wgpu::TextureViewDescriptor<'static> {
    wgpu::TextureViewDescriptor { dimension: Some(wgpu::TextureViewDimension::D2Array), ..Default::default() }
}

impl ComposePass {
    pub fn new(device: &wgpu::Device, prm: &Prm, selected: &wgpu::Buffer, near: &NearPass) -> ComposePass {
        let (w, h) = (prm.header().atlas_width, prm.header().atlas_height);
        let pages = prm.header().atlas().pages;
        let ts = prm.header().tile_size;
        let tiles_x = prm.tiles_x();
        let atlas_tiles = (tiles_x * prm.tiles_y()) as usize;
        let Tables { slots, ranges, records } = Tables::new(prm, atlas_tiles);
        let mut data: Vec<u8> = prm.data().to_vec();
        data.resize(data.len().next_multiple_of(4).max(4), 0);
        let split = split_words(data.len() / 4) * 4;
        // After the per-tile counts and the records' corner words: the tiles' states and list.
        let state_offset = atlas_tiles + records.len() * 4 * CORNER_WORDS as usize;
        let sum_tiles = tile_changes::sum_tiles(&near.index, w, ts, tiles_x);
        let params = ComposeParams {
            atlas_width: w,
            atlas_height: h,
            tile_size: ts,
            tiles_x,
            tile_count: atlas_tiles as u32,
            local_k: 0,
            cluster_count: prm.clusters().len() as u32,
            group_count: prm.groups().len() as u32,
            residual: 0,
            page_rows: h / pages,
            data_split: (split / 4) as u32,
            sum_count: sum_tiles.len() as u32,
            state_offset: state_offset as u32,
            recompose_all: 1,
            ..Default::default()
        };
        let texel_slots: Vec<[u32; 2]> = slots.iter().zip(&near.index).map(|(&s, &n)| [s, n]).collect();
        let params_buf = {
            use wgpu::util::DeviceExt;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("compose params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            })
        };
        let none = wgpu::BufferUsages::empty();
        let records_buf = gpu::storage_buffer(device, "tile records", bytemuck::cast_slice(&records), none);
        let slots_and_ranges: Vec<[u32; 2]> = texel_slots.into_iter().chain(ranges.iter().copied()).collect();
        let slots_buf =
            gpu::storage_buffer(device, SLOTS_AND_RANGES, bytemuck::cast_slice(&slots_and_ranges), none);
        let data_buf = gpu::storage_buffer(device, PANE_DATA[0], &data[..split], none);
        let data_hi_buf = gpu::storage_buffer(device, PANE_DATA[1], &data[split..], none);
        let active_buf = gpu::storage_buffer(
            device,
            "active records",
            // An atlas tile's active records take the places of its own records (at most all).
            &vec![0u8; records.len() * std::mem::size_of::<ActiveRecord>()],
            none,
        );
        // Per atlas tile a count, then per record and corner of its tile CORNER_WORDS words,
        // then the tiles' states and the list of those to compose.
        let count_buf = gpu::storage_buffer(
            device,
            "active counts and corner weights",
            &vec![0u8; (state_offset + tile_changes::state_words(atlas_tiles as u32) as usize) * 4],
            wgpu::BufferUsages::COPY_SRC,
        );
        let lightmap = lightmap_texture(device, w, h / pages, pages);
        let bgl = SHADER.layout(device, 0);
        let view = lightmap.create_view(&array_view());
        let group = bind(
            device,
            "compose",
            &bgl,
            BINDINGS,
            &[
                ("params", params_buf.as_entire_binding()),
                ("selected", selected.as_entire_binding()),
                ("records", records_buf.as_entire_binding()),
                ("slots", slots_buf.as_entire_binding()),
                ("data", data_buf.as_entire_binding()),
                ("data_hi", data_hi_buf.as_entire_binding()),
                ("lightmap", wgpu::BindingResource::TextureView(&view)),
                ("active_records", active_buf.as_entire_binding()),
                ("counts", count_buf.as_entire_binding()),
                ("near_sum", near.sums.as_entire_binding()),
            ],
        );
        let changes = TileChanges::new(
            device,
            ComposeBuffers {
                params: &params_buf,
                selected,
                records: &records_buf,
                slots: &slots_buf,
                near_sum: &near.sums,
                counts: &count_buf,
            },
            &sum_tiles,
            atlas_tiles as u32,
            state_offset as u32,
        );
        let source = SHADER.source();
        let pipeline = gpu::compute_pipeline(device, "compose.wgsl", &source, "compose_main", &[&bgl]);
        let gather = gpu::compute_pipeline(device, "compose.wgsl", &source, "gather_main", &[&bgl]);
        let select = gpu::compute_pipeline(device, "compose.wgsl", &source, "select_main", &[&bgl]);
        ComposePass {
            pipeline,
            select,
            params,
            params_buf,
            gather,
            tiles: atlas_tiles as u32,
            group,
            size: (w, h),
            lightmap,
            records_per_tile: ranges.iter().map(|r| r[1]).collect(),
            texels_per_tile: prm.layout().texels.iter().map(|t| t.len() as u64).collect(),
            counts: count_buf,
            texels: slots.iter().filter(|s| **s != NO_SLOT).count() as u64,
            changes,
            all_next: true,
        }
    }

    /// The budget the next composes apply: `local_k` panes picked at each vertex of the tile
    /// grid (0: the weight pass's global selection as it is), with `residual` groups for the
    /// others; and the change below which a weight or sum counts as unchanged (`tolerance`,
    /// `crate::tile_changes`).
    pub fn set_budget(&mut self, queue: &wgpu::Queue, local_k: u32, residual: bool, tolerance: f32) {
        let next = ComposeParams { local_k, residual: residual as u32, tolerance, ..self.params };
        if next != self.params {
            // The picks change without any pane's weight changing.
            self.all_next = true;
            self.params = next;
            queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        }
    }

    /// Records the compose of the tiles whose light may have changed since the last one
    /// (`crate::tile_changes`), or of every tile when `all` (or the budget changed); `timer`
    /// times the compose as pass 2, the tile changes as pass 7.
    pub fn encode(
        &mut self,
        queue: &wgpu::Queue,
        enc: &mut wgpu::CommandEncoder,
        all: bool,
        timer: Option<&crate::timer::PassTimer>,
    ) {
        let all = (all || self.all_next) as u32;
        self.all_next = false;
        if all != self.params.recompose_all {
            self.params.recompose_all = all;
            queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        }
        self.changes.encode(enc, &self.counts, timer.map(|t| t.writes(7)));
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("compose"),
            timestamp_writes: timer.map(|t| t.writes(2)),
        });
        pass.set_bind_group(0, &self.group, &[]);
        if self.params.local_k > 0 {
            // One workgroup per vertex of the tile grid, in rows of at most 32768 (the limit
            // is 65535).
            let p = &self.params;
            let vertices = (p.tiles_x + 1) * (p.tile_count / p.tiles_x.max(1) + 1);
            let x = vertices.min(32768);
            pass.set_pipeline(&self.select);
            pass.dispatch_workgroups(x, vertices.div_ceil(x), 1);
        }
        pass.set_pipeline(&self.gather);
        pass.dispatch_workgroups(self.tiles.div_ceil(WG_LINEAR), 1, 1);
        pass.set_pipeline(&self.pipeline);
        pass.dispatch_workgroups_indirect(&self.changes.dispatch, 0);
    }

    /// The atlas tiles the last compose wrote (read back; waits for the GPU).
    pub fn composed_tiles(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<u32, gpu::GpuError> {
        let bytes = gpu::read_buffer(device, queue, &self.counts)?;
        let at = self.changes.list_bytes() as usize;
        Ok(u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]))
    }

    /// Atlas tiles.
    pub fn tile_count(&self) -> u32 {
        self.tiles
    }

    /// The records each atlas tile's last compose summed (read back; waits for the GPU).
    pub fn read_active_counts(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<u32>, gpu::GpuError> {
        let bytes = gpu::read_buffer(device, queue, &self.counts)?;
        Ok(bytes
            .chunks_exact(4)
            .take(self.tiles as usize)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }

    /// Bytes a compose that summed `active[t]` records in atlas tile t reads and writes: one
    /// byte per stored texel of each summed record,
    /// the gather's reads of the tile's records (a 4-byte pane id each for the weight pass's
    /// global selection; under a local budget each 64-byte record read by the four vertices
    /// around its tile, and its four corners' 16 bytes of state and weight written and read),
    /// its 64-byte active entries (written once, read per texel from cache), the slot table,
    /// the selection table, and the RGBA32F lightmap written.
    pub fn bytes(&self, active: &[u32]) -> ComposeBytes {
        let local = self.params.local_k > 0;
        let pane: u64 = active.iter().zip(&self.texels_per_tile).map(|(&a, &t)| a as u64 * t).sum();
        let (w, h) = self.size;
        let texels = (w * h) as u64;
        let record = std::mem::size_of::<TileRecord>() as u64;
        let record_bytes = if local { 4 * record + 2 * 4 * 4 * CORNER_WORDS as u64 } else { 4 };
        let headers: u64 = self.records_per_tile.iter().map(|&r| r as u64 * record_bytes).sum::<u64>()
            + active.iter().map(|&a| a as u64 * 2 * 64).sum::<u64>();
        let panes = (self.params.cluster_count + self.params.group_count) as u64;
        ComposeBytes {
            pane_data: pane,
            headers,
            tables: texels * 4 + panes * 16,
            written: texels * 16,
            stored_texels: self.texels,
            records: active.iter().map(|&a| a as u64).sum(),
            most_per_tile: active.iter().copied().max().unwrap_or(0),
        }
    }
}

/// What one compose moves, in bytes (`Runtime::compose_bytes`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ComposeBytes {
    pub pane_data: u64,
    /// The gather's reads of the records and its active entries.
    pub headers: u64,
    pub tables: u64,
    pub written: u64,
    pub stored_texels: u64,
    /// Stored tiles summed, over all atlas tiles (panes and groups).
    pub records: u64,
    /// The most stored tiles one atlas tile summed: the compose's work per texel.
    pub most_per_tile: u32,
}
