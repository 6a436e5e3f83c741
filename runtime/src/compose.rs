//! Compose on the GPU (DESIGN.md §5 step 4; `shaders/compose.wgsl`): the indirect lightmap
//! `sum_c selected_c x pane_c`, read from stored tiles only.
//!
//! The `.prm`'s tiles are regrouped once, at load, by the atlas tile they cover
//! (`tile_ranges[t]` = a run of [`TileRecord`]s), and every atlas texel gets its slot among its
//! atlas tile's stored texels (or `NO_SLOT`). The 8-bit texel codes are uploaded as is, four
//! to a `u32`. Per compose, one invocation per atlas tile lists the stored tiles of selected
//! panes (reading the pane id of each tile's record) with their weight already applied to the tile's
//! colour scale; then each texel sums just those: a 16-byte entry and a byte each. A
//! compose reads `1 byte x stored texels` of each selected pane, never a whole atlas per
//! cluster, and its work per texel is the number of selected panes stored there. Texels with
//! near-field links or far field add their sum (`crate::near`, `crate::far`), and the total is
//! clamped at zero.
//!
//! The lightmap is `Rgba32Float` (irradiance in W/m² in RGB, A = 1), atlas-sized, row 0 at
//! v = 0: DESIGN.md §3's layout.

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, DIPOLE_RECORD, LINEAR, NO_SLOT, TILE, WG_LINEAR, WG_TILE};
use crate::gpu;
use crate::layout::{ActiveRecord, ComposeParams, GpuStruct, TileRecord};
use crate::near::NearPass;

/// The pass's one bind group.
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(ComposeParams::NAME), COMPUTE),
    // The weight pass's output: C clusters, then G groups.
    b("selected", Res::Read("array<vec4f>"), COMPUTE),
    // Per atlas tile: (first record, record count).
    b("tile_ranges", Res::Read("array<vec2u>"), COMPUTE),
    b("records", Res::Read("array<TileRecord>"), COMPUTE),
    // Per atlas texel: its slot among its atlas tile's stored texels, or NO_SLOT; and its index
    // in near_sum, or NO_SLOT.
    b("slots", Res::Read("array<vec2u>"), COMPUTE),
    // f16 intensities, two per u32.
    b("data", Res::Read("array<u32>"), COMPUTE),
    b("lightmap", Res::WriteTexture2d(wgpu::TextureFormat::Rgba32Float), COMPUTE),
    b("active_records", Res::ReadWrite("array<ActiveRecord>"), COMPUTE),
    b("active_count", Res::ReadWrite("array<u32>"), COMPUTE),
    // The near pass's output (`crate::near`).
    b("near_sum", Res::Read("array<vec4f>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "compose",
    body: include_str!("../../shaders/compose.wgsl"),
    lights: false,
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "gather_main", workgroup: LINEAR },
        Compute { entry: "compose_main", workgroup: TILE },
    ],
};

pub struct ComposePass {
    pipeline: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    tiles: u32,
    group: wgpu::BindGroup,
    size: (u32, u32),
    /// The indirect lightmap.
    pub lightmap: wgpu::Texture,
    /// Per atlas tile, the records covering it (for byte counts).
    records_per_tile: Vec<u32>,
    /// Per cluster, stored tiles (for byte counts).
    tiles_per_cluster: Vec<u64>,
    /// Per cluster, stored texels over all its tiles (for byte counts).
    texels_per_cluster: Vec<u64>,
    texels: u64,
}

/// What the compose reads, built on the CPU once per map.
struct Tables {
    /// Each stored texel's place in its atlas tile's list (`NO_SLOT` elsewhere).
    slots: Vec<u32>,
    /// Per atlas tile, (first record, record count).
    ranges: Vec<[u32; 2]>,
    /// Stored tiles grouped by atlas tile, panes in order within each.
    records: Vec<TileRecord>,
    texels_per_cluster: Vec<u64>,
    /// The most records any atlas tile has (at least 1).
    stride: u32,
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
        let mut texels_per_cluster = vec![0u64; prm.pane_count()];
        for (k, t) in prm.tiles().iter().enumerate() {
            by_tile[t.index as usize].push(TileRecord {
                scale: t.scale.to_array(),
                cluster: t.cluster,
                data_offset: layout.offsets[k] as u32,
                ..Default::default()
            });
            texels_per_cluster[t.cluster as usize] += layout.texels[t.index as usize].len() as u64;
        }
        // Dipole tiles: pane C + G + 3 c + axis, codes after the panes' in the data buffer,
        // their offset flagged (`DIPOLE_RECORD`).
        let d = prm.dipoles();
        let codes = d.tile_codes(prm.header().tile_size);
        for (k, t) in d.tiles.iter().enumerate() {
            by_tile[t.index as usize].push(TileRecord {
                scale: t.scale.to_array(),
                cluster: prm.pane_count() as u32 + t.cluster,
                data_offset: DIPOLE_RECORD | (prm.data().len() + k * codes) as u32,
                ..Default::default()
            });
        }
        let mut ranges = Vec::with_capacity(atlas_tiles);
        let mut records = Vec::with_capacity(prm.tiles().len() + d.tiles.len());
        for list in &by_tile {
            ranges.push([records.len() as u32, list.len() as u32]);
            records.extend_from_slice(list);
        }
        let stride = by_tile.iter().map(Vec::len).max().unwrap_or(0).max(1) as u32;
        Tables { slots, ranges, records, texels_per_cluster, stride }
    }
}

/// The indirect lightmap the compose writes and shading reads.
fn lightmap_texture(device: &wgpu::Device, w: u32, h: u32) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("indirect lightmap"),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
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

impl ComposePass {
    pub fn new(device: &wgpu::Device, prm: &Prm, selected: &wgpu::Buffer, near: &NearPass) -> ComposePass {
        let (w, h) = (prm.header().atlas_width, prm.header().atlas_height);
        let ts = prm.header().tile_size;
        let tiles_x = prm.tiles_x();
        let atlas_tiles = (tiles_x * prm.tiles_y()) as usize;
        let Tables { slots, ranges, records, texels_per_cluster, stride } = Tables::new(prm, atlas_tiles);
        let mut data: Vec<u8> = prm.data().to_vec();
        data.extend_from_slice(&prm.dipoles().data);
        data.resize(data.len().next_multiple_of(4).max(4), 0);
        let block = prm.dipoles().block.max(1);
        let params = ComposeParams {
            dipole_block: block,
            dipole_side: ts.div_ceil(block),
            atlas_width: w,
            atlas_height: h,
            tile_size: ts,
            tiles_x,
            tile_count: atlas_tiles as u32,
            active_stride: stride,
        };
        let texel_slots: Vec<[u32; 2]> = slots.iter().zip(&near.index).map(|(&s, &n)| [s, n]).collect();
        let params = {
            use wgpu::util::DeviceExt;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("compose params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            })
        };
        let none = wgpu::BufferUsages::empty();
        let ranges_buf = gpu::storage_buffer(device, "tile ranges", bytemuck::cast_slice(&ranges), none);
        let records_buf = gpu::storage_buffer(device, "tile records", bytemuck::cast_slice(&records), none);
        let slots_buf = gpu::storage_buffer(device, "texel slots", bytemuck::cast_slice(&texel_slots), none);
        let data_buf = gpu::storage_buffer(device, "pane data", &data, none);
        let active_buf = gpu::storage_buffer(
            device,
            "active records",
            &vec![0u8; atlas_tiles * stride as usize * std::mem::size_of::<ActiveRecord>()],
            none,
        );
        let count_buf = gpu::storage_buffer(device, "active counts", &vec![0u8; atlas_tiles * 4], none);
        let lightmap = lightmap_texture(device, w, h);
        let bgl = SHADER.layout(device, 0);
        let view = lightmap.create_view(&Default::default());
        let group = bind(
            device,
            "compose",
            &bgl,
            BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("selected", selected.as_entire_binding()),
                ("tile_ranges", ranges_buf.as_entire_binding()),
                ("records", records_buf.as_entire_binding()),
                ("slots", slots_buf.as_entire_binding()),
                ("data", data_buf.as_entire_binding()),
                ("lightmap", wgpu::BindingResource::TextureView(&view)),
                ("active_records", active_buf.as_entire_binding()),
                ("active_count", count_buf.as_entire_binding()),
                ("near_sum", near.sums.as_entire_binding()),
            ],
        );
        let source = SHADER.source();
        let pipeline = gpu::compute_pipeline(device, "compose.wgsl", &source, "compose_main", &[&bgl]);
        let gather = gpu::compute_pipeline(device, "compose.wgsl", &source, "gather_main", &[&bgl]);
        ComposePass {
            pipeline,
            gather,
            tiles: atlas_tiles as u32,
            group,
            size: (w, h),
            lightmap,
            records_per_tile: ranges.iter().map(|r| r[1]).collect(),
            texels_per_cluster,
            tiles_per_cluster: prm
                .clusters()
                .iter()
                .map(|c| c.tile_count as u64)
                .chain(prm.groups().iter().map(|g| g.tile_count as u64))
                .collect(),
            texels: slots.iter().filter(|s| **s != NO_SLOT).count() as u64,
        }
    }

    /// Records the compose.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("compose"),
            timestamp_writes: timestamps,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.gather);
        pass.dispatch_workgroups(self.tiles.div_ceil(WG_LINEAR), 1, 1);
        pass.set_pipeline(&self.pipeline);
        pass.dispatch_workgroups(self.size.0.div_ceil(WG_TILE), self.size.1.div_ceil(WG_TILE), 1);
    }

    /// Bytes one compose reads and writes for this set of selected clusters: the selected
    /// panes' f16 texels and their 32-byte records, a 4-byte pane id per stored tile (the
    /// gather), the slot table, the selection table, and the RGBA32F lightmap written.
    pub fn bytes(&self, selected: &[bool]) -> ComposeBytes {
        let pane: u64 =
            self.texels_per_cluster.iter().zip(selected).filter(|(_, s)| **s).map(|(t, _)| *t).sum();
        let (w, h) = self.size;
        let texels = (w * h) as u64;
        let headers: u64 = self.records_per_tile.iter().map(|&r| r as u64 * 4).sum::<u64>()
            + self
                .tiles_per_cluster
                .iter()
                .zip(selected)
                .filter(|(_, s)| **s)
                .map(|(t, _)| t * 32)
                .sum::<u64>();
        ComposeBytes {
            pane_data: pane,
            headers,
            tables: texels * 4 + selected.len() as u64 * 16,
            written: texels * 16,
            stored_texels: self.texels,
        }
    }
}

/// What one compose moves, in bytes (`Runtime::compose_bytes`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ComposeBytes {
    pub pane_data: u64,
    /// Cluster ids of every stored tile (gather) and full records of the selected ones.
    pub headers: u64,
    pub tables: u64,
    pub written: u64,
    pub stored_texels: u64,
}
