//! Compose on the GPU (DESIGN.md §5 step 4; `shaders/compose.wgsl`): the indirect lightmap
//! `sum_c selected_c x pane_c`, read from stored tiles only.
//!
//! The `.prm`'s tiles are regrouped once, at load, by the atlas tile they cover
//! (`tile_ranges[t]` = a run of [`TileRecord`]s), and every atlas texel gets its slot among its
//! atlas tile's stored texels (or `NO_SLOT`). The half-float texel data is uploaded as is, two
//! to a `u32`. Per compose, one invocation per atlas tile lists the stored tiles of selected
//! panes (reading a 4-byte pane id per tile) with their weight already applied to the tile's
//! colour scale; then each texel sums just those: a 16-byte entry and a half float each. A
//! compose reads `2 bytes x stored texels` of each selected pane, never a whole atlas per
//! cluster, and its work per texel is the number of selected panes stored there.
//!
//! The lightmap is `Rgba32Float` (irradiance in W/m² in RGB, A = 1), atlas-sized, row 0 at
//! v = 0: DESIGN.md §3's layout.

use prm::prm_file::Prm;

use crate::gpu::{self, buffer_entry, READ, UNIFORM};
use crate::layout::{ComposeParams, TileRecord};

pub const SOURCE: &str = include_str!("../../shaders/compose.wgsl");
const NO_SLOT: u32 = u32::MAX;

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

impl ComposePass {
    pub fn new(device: &wgpu::Device, prm: &Prm, selected: &wgpu::Buffer) -> ComposePass {
        let layout = prm.layout();
        let (w, h) = (prm.header().atlas_width, prm.header().atlas_height);
        let ts = prm.header().tile_size;
        let tiles_x = prm.tiles_x();
        let atlas_tiles = (tiles_x * prm.tiles_y()) as usize;
        // Slots: each stored texel's place in its atlas tile's list.
        let mut slots = vec![NO_SLOT; (w * h) as usize];
        for list in &layout.texels {
            for (k, &texel) in list.iter().enumerate() {
                slots[texel as usize] = k as u32;
            }
        }
        // Records grouped by atlas tile, clusters in order within each.
        let mut by_tile: Vec<Vec<TileRecord>> = vec![Vec::new(); atlas_tiles];
        let mut texels_per_cluster = vec![0u64; prm.clusters().len() + prm.groups().len()];
        for (k, t) in prm.tiles().iter().enumerate() {
            by_tile[t.index as usize].push(TileRecord {
                scale: t.scale.to_array(),
                cluster: t.cluster,
                data_offset: layout.offsets[k] as u32,
                _pad: [0; 3],
            });
            texels_per_cluster[t.cluster as usize] += layout.texels[t.index as usize].len() as u64;
        }
        let mut ranges = Vec::with_capacity(atlas_tiles);
        let mut records = Vec::with_capacity(prm.tiles().len());
        for list in &by_tile {
            ranges.push([records.len() as u32, list.len() as u32]);
            records.extend_from_slice(list);
        }
        let data: &[u8] = bytemuck::cast_slice(prm.data());
        let stride = by_tile.iter().map(Vec::len).max().unwrap_or(0).max(1) as u32;
        let params = ComposeParams {
            atlas_width: w,
            atlas_height: h,
            tile_size: ts,
            tiles_x,
            tile_count: atlas_tiles as u32,
            active_stride: stride,
            _pad: [0; 2],
        };
        let record_clusters: Vec<u32> = records.iter().map(|r| r.cluster).collect();
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
        let slots_buf = gpu::storage_buffer(device, "texel slots", bytemuck::cast_slice(&slots), none);
        let data_buf = gpu::storage_buffer(device, "pane data", data, none);
        let clusters_buf =
            gpu::storage_buffer(device, "record clusters", bytemuck::cast_slice(&record_clusters), none);
        let active_buf = gpu::storage_buffer(
            device,
            "active records",
            &vec![0u8; atlas_tiles * stride as usize * std::mem::size_of::<crate::layout::ActiveRecord>()],
            none,
        );
        let count_buf = gpu::storage_buffer(device, "active counts", &vec![0u8; atlas_tiles * 4], none);
        let lightmap = device.create_texture(&wgpu::TextureDescriptor {
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
        });
        let c = wgpu::ShaderStages::COMPUTE;
        let bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("compose"),
            entries: &[
                buffer_entry(0, c, UNIFORM),
                buffer_entry(1, c, READ),
                buffer_entry(2, c, READ),
                buffer_entry(3, c, READ),
                buffer_entry(4, c, READ),
                buffer_entry(5, c, READ),
                wgpu::BindGroupLayoutEntry {
                    binding: 6,
                    visibility: c,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: wgpu::TextureFormat::Rgba32Float,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
                buffer_entry(7, c, READ),
                buffer_entry(8, c, gpu::WRITE),
                buffer_entry(9, c, gpu::WRITE),
            ],
        });
        let view = lightmap.create_view(&Default::default());
        let buffers = [&params, selected, &ranges_buf, &records_buf, &slots_buf, &data_buf];
        let mut entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
            .collect();
        entries
            .push(wgpu::BindGroupEntry { binding: 6, resource: wgpu::BindingResource::TextureView(&view) });
        for (i, b) in [&clusters_buf, &active_buf, &count_buf].iter().enumerate() {
            entries.push(wgpu::BindGroupEntry { binding: 7 + i as u32, resource: b.as_entire_binding() });
        }
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("compose"),
            layout: &bgl,
            entries: &entries,
        });
        let pipeline = gpu::compute_pipeline(device, "compose.wgsl", SOURCE, "compose_main", &[&bgl]);
        let gather = gpu::compute_pipeline(device, "compose.wgsl", SOURCE, "gather_main", &[&bgl]);
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
        pass.dispatch_workgroups(self.tiles.div_ceil(64), 1, 1);
        pass.set_pipeline(&self.pipeline);
        pass.dispatch_workgroups(self.size.0.div_ceil(8), self.size.1.div_ceil(8), 1);
    }

    /// Bytes one compose reads and writes for this set of selected clusters: the selected
    /// panes' f16 texels and their 32-byte records, a 4-byte pane id per stored tile (the
    /// gather), the slot table, the selection table, and the RGBA32F lightmap written.
    pub fn bytes(&self, selected: &[bool]) -> ComposeBytes {
        let pane: u64 =
            self.texels_per_cluster.iter().zip(selected).filter(|(_, s)| **s).map(|(t, _)| t * 2).sum();
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

/// What one compose moves, in bytes (see [`ComposePass::bytes`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct ComposeBytes {
    pub pane_data: u64,
    /// Cluster ids of every stored tile (gather) and full records of the selected ones.
    pub headers: u64,
    pub tables: u64,
    pub written: u64,
    pub stored_texels: u64,
}
