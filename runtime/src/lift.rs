//! The near field's later bounces on the GPU (`shaders/lift.wgsl`; twin:
//! [`crate::cpu::lift_weights`], whose doc says why). Three dispatches between the near pass
//! and the selection: each cluster's mean of the near field over its cells (each cell's mean
//! over its texels, [`crate::cpu::cell_means`]), the share `lambda` that keeps the
//! panes' energy in each room (`crate::cpu::rooms`), and the lifted weights with their scores.

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, WG_LINEAR};
use crate::cpu::NearTables;
use crate::gpu;
use crate::layout::{GpuStruct, IndirectParams};

pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    // The weight pass's member ranges (clusters first).
    b("ranges", Res::Read("array<vec2u>"), COMPUTE),
    // Per member, in the weight pass's `indices` order, four words: its cell's run of slots
    // among the near sums further on (first, end), its cell's area over A/N (f32 bits), its
    // entry; then the runs (the near pass's `members`).
    b("lift_members", Res::Read("array<u32>"), COMPUTE),
    // The near pass's sums: near links with their echo, and the far field.
    b("near_sum", Res::Read("array<vec4f>"), COMPUTE),
    b("weights", Res::ReadWrite("array<vec4f>"), COMPUTE),
    b("scores", Res::ReadWrite("array<f32>"), COMPUTE),
    // Per cluster u_c, each room's lambda, then per cluster what its cells send and the near
    // field's power over them ([`lifted_len`]).
    b("lifted", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // The entry pass's irradiance per entry.
    b("entry_irradiance", Res::Read("array<vec4f>"), COMPUTE),
    // [`lift_tables`]: the clusters' energies, the rooms, the entries' `(A/N) g rho`, the
    // slots' areas, in one buffer (WebGPU gives a stage 8 storage buffers).
    b("lift_tables", Res::Read("array<u32>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "lift",
    body: include_str!("../../shaders/lift.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "lift_main", workgroup: LINEAR },
        Compute { entry: "lambda_main", workgroup: LINEAR },
        Compute { entry: "apply_main", workgroup: LINEAR },
    ],
};

/// The buffers of the weight and near passes the lift reads and writes.
pub struct LiftBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    pub ranges: &'a wgpu::Buffer,
    pub weights: &'a wgpu::Buffer,
    pub scores: &'a wgpu::Buffer,
    pub near_sum: &'a wgpu::Buffer,
    pub entry_irradiance: &'a wgpu::Buffer,
}

pub struct LiftPass {
    lift: wgpu::ComputePipeline,
    lambda: wgpu::ComputePipeline,
    apply: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    clusters: u32,
    rooms: u32,
    /// The map has its far texels' areas: the lift keeps each room's power (`IndirectParams::
    /// lift_power`).
    pub(crate) power: bool,
}

/// The length of the lift's `lifted` buffer: per cluster `u_c`, per room `lambda`, then per
/// cluster what its cells send and the near and far fields' power over them.
pub fn lifted_len(clusters: usize, rooms: usize) -> usize {
    3 * clusters + rooms
}

/// Part of [`lift_tables`]: per entry `(A/N) g_j rho_j` (`NearTables::reflect`).
pub fn entry_reflect(prm: &Prm, tables: &NearTables) -> Vec<[f32; 4]> {
    prm.entries()
        .iter()
        .zip(&tables.reflect)
        .map(|(e, r)| {
            let x = e.area * *r;
            [x.x, x.y, x.z, 0.0]
        })
        .collect()
}

/// Part of [`lift_tables`]: aligned with the near pass's member table
/// (`crate::near::cluster_members`), 0 for each member's four words, then each listed far
/// texel's area (`NearTables::cell_areas`); one 0 for a map without them.
pub fn slot_areas(prm: &Prm, tables: &NearTables) -> Vec<f32> {
    if tables.cell_areas.is_empty() {
        return vec![0.0];
    }
    let count: usize = prm.clusters().iter().map(|c| c.members.len()).sum();
    let mut areas = vec![0.0f32; 4 * count];
    for run in crate::near::member_cell_runs(prm, tables) {
        areas.extend_from_slice(&tables.cell_areas[run]);
    }
    areas
}

/// The lift's `lift_tables` buffer (words): [`cluster_energies`] (four f32 a cluster), then
/// [`room_words`], [`entry_reflect`] (four f32 an entry) and [`slot_areas`].
pub fn lift_tables(prm: &Prm, tables: &NearTables) -> Vec<u32> {
    let mut words: Vec<u32> = cluster_energies(prm, tables).iter().flatten().map(|f| f.to_bits()).collect();
    words.extend(room_words(tables));
    words.extend(entry_reflect(prm, tables).iter().flatten().map(|f| f.to_bits()));
    words.extend(slot_areas(prm, tables).iter().map(|f| f.to_bits()));
    words
}

/// The length of [`room_words`] for `clusters` clusters in `rooms` rooms.
pub fn room_words_len(clusters: usize, rooms: usize) -> usize {
    2 + 2 * clusters + rooms
}

/// Part of [`lift_tables`]: R, each cluster's room (`NearTables::cluster_room`), where each
/// room's clusters start in the list (R + 1), and the list (ascending within each room).
pub fn room_words(tables: &NearTables) -> Vec<u32> {
    let (rooms, c) = (tables.rooms, tables.cluster_room.len());
    let mut words = Vec::with_capacity(room_words_len(c, rooms));
    words.push(rooms as u32);
    words.extend_from_slice(&tables.cluster_room);
    let mut count = vec![0u32; rooms];
    for &r in &tables.cluster_room {
        count[r as usize] += 1;
    }
    let mut start = 0;
    for n in &count {
        words.push(start);
        start += n;
    }
    words.push(start);
    let mut list: Vec<u32> = (0..c as u32).collect();
    list.sort_by_key(|&k| tables.cluster_room[k as usize]);
    words.extend(list);
    words
}

/// Part of [`lift_tables`]: per cluster, in xyz what [`crate::cpu::lift_weights`] weighs
/// each channel by: its pane's power `P_c` (`NearTables::power`) where the map has its far
/// texels' areas, else `energy_c` times its tint; and `energy_c` in w (the score's).
pub fn cluster_energies(prm: &Prm, tables: &NearTables) -> Vec<[f32; 4]> {
    let power = !tables.cell_areas.is_empty();
    prm.clusters()
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let e = if power { tables.power[k] } else { c.energy * tables.cluster_tint[k] };
            [e.x, e.y, e.z, c.energy]
        })
        .collect()
}

impl LiftPass {
    /// None without the near pass's member table (no member has a texel to read: a map without
    /// a far field): the weights stay.
    pub fn new(
        device: &wgpu::Device,
        prm: &Prm,
        tables: &NearTables,
        members: Option<&wgpu::Buffer>,
        buffers: LiftBuffers,
    ) -> Option<LiftPass> {
        let members = members?;
        let clusters = prm.clusters().len();
        let none = wgpu::BufferUsages::empty();
        let lifted = gpu::storage_buffer(
            device,
            "lifted weights",
            &vec![0u8; lifted_len(clusters, tables.rooms) * 16],
            none,
        );
        let lift_tables =
            gpu::storage_buffer(device, "lift tables", bytemuck::cast_slice(&lift_tables(prm, tables)), none);
        let layout = SHADER.layout(device, 0);
        let group = bind(
            device,
            "lift",
            &layout,
            BINDINGS,
            &[
                ("params", buffers.params.as_entire_binding()),
                ("ranges", buffers.ranges.as_entire_binding()),
                ("lift_members", members.as_entire_binding()),
                ("near_sum", buffers.near_sum.as_entire_binding()),
                ("weights", buffers.weights.as_entire_binding()),
                ("scores", buffers.scores.as_entire_binding()),
                ("lifted", lifted.as_entire_binding()),
                ("entry_irradiance", buffers.entry_irradiance.as_entire_binding()),
                ("lift_tables", lift_tables.as_entire_binding()),
            ],
        );
        let source = SHADER.source();
        let pipeline = |entry| gpu::compute_pipeline(device, "lift.wgsl", &source, entry, &[&layout]);
        Some(LiftPass {
            lift: pipeline("lift_main"),
            lambda: pipeline("lambda_main"),
            apply: pipeline("apply_main"),
            group,
            clusters: clusters as u32,
            rooms: tables.rooms as u32,
            power: !tables.cell_areas.is_empty(),
        })
    }

    /// Records the pass (after the near pass, before the selection).
    pub fn encode(&self, enc: &mut wgpu::CommandEncoder) {
        let mut pass = enc
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("lift"), timestamp_writes: None });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.lift);
        pass.dispatch_workgroups(self.clusters.div_ceil(WG_LINEAR), 1, 1);
        pass.set_pipeline(&self.lambda);
        // A workgroup per room, in rows of at most 32768.
        let x = self.rooms.min(32768);
        pass.dispatch_workgroups(x, self.rooms.div_ceil(x), 1);
        pass.set_pipeline(&self.apply);
        pass.dispatch_workgroups(self.clusters.div_ceil(WG_LINEAR), 1, 1);
    }
}
