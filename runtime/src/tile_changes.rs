//! Which atlas tiles the compose works again (`shaders/tile_changes.wgsl`): only those whose
//! light may have changed since the last compose.
//!
//! A lamp moving in one room of a level of many changes the weights of that room's clusters and
//! the near-field sums of that room's texels; the rest of the lightmap comes out as it was. A
//! tile's composed light reads only (a) the weights in `selected` of the panes stored in the
//! 3 x 3 tiles around it (a local budget's picks at each of its four corners read the four tiles
//! around that vertex; under a global budget only its own), and (b) its texels' near-field sums
//! (`crate::near`, the far field's included). So before the compose:
//!
//! 1. each atlas tile is marked `CHANGED_WEIGHT` when the weights of its records' panes moved
//!    from those the tile was last gathered with (kept per record): with no tolerance
//!    (`RuntimeParams::recompose_tolerance` 0, the default) when a bit differs; with one, when
//!    the light the moves make in the tile (the sum over its records of the luminance of the
//!    weight's move times the pane's energy there) is more than that share of the light the
//!    records gave it;
//! 2. each near-field sum is compared with what it was when it last counted as changed (with a
//!    tolerance: that share of its tile's mean light plus its own magnitude), its tile marked
//!    `CHANGED_SUM` when it moved;
//! 3. a tile is marked `REGATHER` when a tile of the 3 x 3 around it has `CHANGED_WEIGHT` (its
//!    records' weights are then kept as those it is gathered with; under a local budget only
//!    when it has `CHANGED_WEIGHT` itself, since only then are all four of its corners picked
//!    again), and listed when so or when it has `CHANGED_SUM`;
//! 4. the compose's indirect dispatch is made from the list's length.
//!
//! The compose then picks at the vertices beside a `CHANGED_WEIGHT` tile, gathers the
//! `REGATHER` tiles, and writes the listed tiles' texels; everything else (the words the picks
//! fill, the gathered records, the lightmap's texels) keeps what the last compose wrote. With
//! no tolerance that is what it would write again, every input it reads being the same to the
//! bit: the lightmap is the same bits as composing every tile (tested), and a frame where one
//! lamp moves pays for the tiles its light reaches.
//!
//! A tolerance is for levels whose rooms are joined (through doors), where one lamp moving
//! moves every weight of the level a little (the lift's `lambda`, `crate::cpu::lift_weights`,
//! is kept per room). It is measured against the tile's light, not each weight's own size: a
//! dim cluster's weight moves by much of itself and adds next to nothing to a tile (a share of
//! each weight, as first built, left the 4 x 4 halls composing 1,736 of 1,849 tiles at 1e-2).
//! A kept tile's panes then give it within about twice the tolerance of the light they would
//! give now (the moves add up against the weights it was gathered with, never frame by frame;
//! a near-field sum against the value last counted), and a local budget's picks there are the
//! top K of scores about that close to today's.
//!
//! Everything counts as changed (`ComposeParams::recompose_all`) on the first compose, when the
//! budget or the tolerance changes (picks are not a pane's weight), after `Runtime::invalidate`, and with
//! `RuntimeParams::recompose_changed_only` off. Kept: the weights each record was last gathered
//! with (16 bytes a record), a copy of the near-field sums (16 bytes a texel with one), and per
//! atlas tile its slot tile (4 bytes), its state, its place in the list and its mean light (12
//! bytes, in the compose's `counts`).

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, NO_SLOT, WG_LINEAR};
use crate::gpu;
use crate::layout::{ComposeParams, GpuStruct, TileRecord};

/// The weights each tile record was last gathered with, as the GPU memory estimate names them.
pub const LAST_RECORDS: &str = "last gathered weights";

pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(ComposeParams::NAME), COMPUTE),
    // The weights the compose reads (`crate::weights::WeightPass::selected`).
    b("selected", Res::Read("array<vec4f>"), COMPUTE),
    // Per tile record, the weight its tile was last gathered with.
    b("last_records", Res::ReadWrite("array<vec4f>"), COMPUTE),
    b("records", Res::Read("array<TileRecord>"), COMPUTE),
    // The compose's texel slots, then its tiles' ranges of records.
    b("slots", Res::Read("array<vec2u>"), COMPUTE),
    b("near_sum", Res::Read("array<vec4f>"), COMPUTE),
    // What the last compose read of the near-field sums.
    b("last_sum", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Per near-field sum, the atlas tile of its texel.
    b("sum_tiles", Res::Read("array<u32>"), COMPUTE),
    // The compose's `counts`: the tiles' states from `ComposeParams::state_offset`, then the list.
    b("state", Res::ReadWrite("array<atomic<u32>>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "tile_changes",
    body: include_str!("../../shaders/tile_changes.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "tiles_main", workgroup: LINEAR },
        Compute { entry: "sums_main", workgroup: LINEAR },
        Compute { entry: "list_main", workgroup: LINEAR },
        Compute { entry: "args_main", workgroup: [1, 1, 1] },
    ],
};

/// Words of the compose's `counts` this pass uses from `ComposeParams::state_offset`: a state
/// per atlas tile, the list's length, the dispatch's three words, the list, and a mean light
/// per atlas tile.
pub fn state_words(tiles: u32) -> u32 {
    3 * tiles + 4
}

/// The buffers the pass reads from the compose and the near field.
pub struct ComposeBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub selected: &'a wgpu::Buffer,
    pub records: &'a wgpu::Buffer,
    pub slots: &'a wgpu::Buffer,
    pub near_sum: &'a wgpu::Buffer,
    pub counts: &'a wgpu::Buffer,
}

pub struct TileChanges {
    tiles: wgpu::ComputePipeline,
    sums: wgpu::ComputePipeline,
    list: wgpu::ComputePipeline,
    args: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    /// The compose's indirect dispatch, copied from `counts`.
    pub dispatch: wgpu::Buffer,
    tile_count: u32,
    sum_count: u32,
    /// Where the list starts in `counts`, in bytes.
    list_bytes: u64,
}

impl TileChanges {
    /// `sum_tiles`: per near-field sum, its texel's atlas tile ([`sum_tiles`]); `state_offset`:
    /// `ComposeParams::state_offset`.
    pub fn new(
        device: &wgpu::Device,
        buffers: ComposeBuffers,
        sum_tiles: &[u32],
        tile_count: u32,
        state_offset: u32,
    ) -> TileChanges {
        let none = wgpu::BufferUsages::empty();
        let records = buffers.records.size() / std::mem::size_of::<TileRecord>() as u64;
        let last_records =
            gpu::storage_buffer(device, LAST_RECORDS, &vec![0u8; (records.max(1) * 16) as usize], none);
        let last_sum = gpu::storage_buffer(
            device,
            "last composed near sums",
            &vec![0u8; sum_tiles.len().max(1) * 16],
            none,
        );
        let tiles_buf =
            gpu::storage_buffer(device, "near sums' tiles", bytemuck::cast_slice(sum_tiles), none);
        let dispatch = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("compose dispatch"),
            size: 12,
            usage: wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let layout = SHADER.layout(device, 0);
        let group = bind(
            device,
            "tile changes",
            &layout,
            BINDINGS,
            &[
                ("params", buffers.params.as_entire_binding()),
                ("selected", buffers.selected.as_entire_binding()),
                ("last_records", last_records.as_entire_binding()),
                ("records", buffers.records.as_entire_binding()),
                ("slots", buffers.slots.as_entire_binding()),
                ("near_sum", buffers.near_sum.as_entire_binding()),
                ("last_sum", last_sum.as_entire_binding()),
                ("sum_tiles", tiles_buf.as_entire_binding()),
                ("state", buffers.counts.as_entire_binding()),
            ],
        );
        let source = SHADER.source();
        let pipeline =
            |entry: &str| gpu::compute_pipeline(device, "tile_changes.wgsl", &source, entry, &[&layout]);
        TileChanges {
            tiles: pipeline("tiles_main"),
            sums: pipeline("sums_main"),
            list: pipeline("list_main"),
            args: pipeline("args_main"),
            group,
            dispatch,
            tile_count,
            sum_count: sum_tiles.len() as u32,
            list_bytes: (state_offset as u64 + tile_count as u64) * 4,
        }
    }

    /// Records the pass (after the near field and the weights, before the compose), then the
    /// copy of the compose's dispatch from `counts` (the compose's), timed by `timestamps`.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        counts: &wgpu::Buffer,
        timestamps: Option<wgpu::ComputePassTimestampWrites>,
    ) {
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("tile changes"),
                timestamp_writes: timestamps,
            });
            pass.set_bind_group(0, &self.group, &[]);
            pass.set_pipeline(&self.tiles);
            pass.dispatch_workgroups(self.tile_count.div_ceil(WG_LINEAR), 1, 1);
            if self.sum_count > 0 {
                // In rows of at most 32768 workgroups.
                let groups = self.sum_count.div_ceil(WG_LINEAR);
                let x = groups.min(32768);
                pass.set_pipeline(&self.sums);
                pass.dispatch_workgroups(x, groups.div_ceil(x), 1);
            }
            pass.set_pipeline(&self.list);
            pass.dispatch_workgroups(self.tile_count.div_ceil(WG_LINEAR), 1, 1);
            pass.set_pipeline(&self.args);
            pass.dispatch_workgroups(1, 1, 1);
        }
        enc.copy_buffer_to_buffer(counts, self.list_bytes + 4, &self.dispatch, 0, 12);
    }

    /// The byte offset in `counts` of the number of tiles the last compose listed.
    pub fn list_bytes(&self) -> u64 {
        self.list_bytes
    }
}

/// Per near-field sum, the atlas tile of its texel: `index` gives each atlas texel's sum (or
/// `NO_SLOT`), texels row-major in an atlas `width` wide, tiles `tile_size` square, `tiles_x`
/// a row.
pub fn sum_tiles(index: &[u32], width: u32, tile_size: u32, tiles_x: u32) -> Vec<u32> {
    let count = index.iter().filter(|&&s| s != NO_SLOT).map(|&s| s as usize + 1).max().unwrap_or(0);
    let mut tiles = vec![0u32; count];
    for (texel, &s) in index.iter().enumerate() {
        if s != NO_SLOT {
            let (x, y) = (texel as u32 % width, texel as u32 / width);
            tiles[s as usize] = (y / tile_size) * tiles_x + x / tile_size;
        }
    }
    tiles
}
