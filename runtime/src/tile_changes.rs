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
//! 1. each pane's weight is compared with what it was when it last counted as changed; it
//!    counts as changed when a channel moved by more than `RuntimeParams::recompose_tolerance`
//!    of its magnitude (0: when the bits differ), and is then kept;
//! 2. each atlas tile is marked `CHANGED_WEIGHT` when one of its records is of a changed pane;
//! 3. each near-field sum is compared likewise, its tile marked `CHANGED_SUM` when it moved;
//! 4. a tile is marked `REGATHER` when a tile of the 3 x 3 around it has `CHANGED_WEIGHT`, and
//!    listed when so or when it has `CHANGED_SUM`;
//! 5. the compose's indirect dispatch is made from the list's length.
//!
//! The compose then picks at the vertices beside a `CHANGED_WEIGHT` tile, gathers the
//! `REGATHER` tiles, and writes the listed tiles' texels; everything else (the words the picks
//! fill, the gathered records, the lightmap's texels) keeps what the last compose wrote. With
//! no tolerance that is what it would write again, every input it reads being the same to the
//! bit: the lightmap is the same bits as composing every tile (tested), and a frame where one
//! lamp moves pays for the tiles its light reaches. With a tolerance, each pane's share of a
//! kept tile is within twice the tolerance of its weight now (the moves add up against the
//! value last counted, never frame by frame), and a local budget's picks there are the top K
//! of scores that close to today's. It is off by default: meant for levels whose rooms are
//! joined, where the lift's level-wide `lambda` (`crate::cpu::lift_weights`) moves every
//! weight a little when one lamp moves, it did not help on the 4 x 4 halls at 1e-3.
//!
//! Everything counts as changed (`ComposeParams::recompose_all`) on the first compose, when the
//! budget or the tolerance changes (picks are not a pane's weight), after `Runtime::invalidate`, and with
//! `RuntimeParams::recompose_changed_only` off. Kept: a copy of `selected` (16 bytes a pane)
//! and of the near-field sums (16 bytes a texel with one), and per atlas tile its slot tile
//! (4 bytes), its state and its place in the list (8 bytes, in the compose's `counts`).

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, NO_SLOT, WG_LINEAR};
use crate::gpu;
use crate::layout::{ComposeParams, GpuStruct};

pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(ComposeParams::NAME), COMPUTE),
    // The weights the compose reads (`crate::weights::WeightPass::selected`).
    b("selected", Res::Read("array<vec4f>"), COMPUTE),
    // What the last compose read of them (xyz), and whether they changed since (w: 1).
    b("last_selected", Res::ReadWrite("array<vec4f>"), COMPUTE),
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
    lights: false,
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "panes_main", workgroup: LINEAR },
        Compute { entry: "tiles_main", workgroup: LINEAR },
        Compute { entry: "sums_main", workgroup: LINEAR },
        Compute { entry: "list_main", workgroup: LINEAR },
        Compute { entry: "args_main", workgroup: [1, 1, 1] },
    ],
};

/// Words of the compose's `counts` this pass uses from `ComposeParams::state_offset`: a state
/// per atlas tile, the list's length, the dispatch's three words, and the list.
pub fn state_words(tiles: u32) -> u32 {
    2 * tiles + 4
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
    panes: wgpu::ComputePipeline,
    tiles: wgpu::ComputePipeline,
    sums: wgpu::ComputePipeline,
    list: wgpu::ComputePipeline,
    args: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    /// The compose's indirect dispatch, copied from `counts`.
    pub dispatch: wgpu::Buffer,
    pane_count: u32,
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
        let panes = (buffers.selected.size() / 16) as u32;
        let last_selected = gpu::storage_buffer(
            device,
            "last composed weights",
            &vec![0u8; buffers.selected.size() as usize],
            none,
        );
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
                ("last_selected", last_selected.as_entire_binding()),
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
            panes: pipeline("panes_main"),
            tiles: pipeline("tiles_main"),
            sums: pipeline("sums_main"),
            list: pipeline("list_main"),
            args: pipeline("args_main"),
            group,
            dispatch,
            pane_count: panes,
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
            pass.set_pipeline(&self.panes);
            pass.dispatch_workgroups(self.pane_count.div_ceil(WG_LINEAR), 1, 1);
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
