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
    // Per cluster, its pane's energy in each channel (its luminance's tinted by the cluster's
    // albedo, `NearTables::cluster_tint`), and in w its luminance's ([`cluster_energies`]).
    b("energy", Res::Read("array<vec4f>"), COMPUTE),
    b("weights", Res::ReadWrite("array<vec4f>"), COMPUTE),
    b("scores", Res::ReadWrite("array<f32>"), COMPUTE),
    // Per cluster u_c, then each room's lambda (C + R).
    b("lifted", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // The rooms ([`room_words`]).
    b("rooms", Res::Read("array<u32>"), COMPUTE),
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
}

pub struct LiftPass {
    lift: wgpu::ComputePipeline,
    lambda: wgpu::ComputePipeline,
    apply: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    clusters: u32,
    rooms: u32,
}

/// The length of [`room_words`] for `clusters` clusters in `rooms` rooms.
pub fn room_words_len(clusters: usize, rooms: usize) -> usize {
    2 + 2 * clusters + rooms
}

/// The lift's `rooms` buffer: R, each cluster's room (`NearTables::cluster_room`), where each
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

/// The lift's `energy` buffer: per cluster, `energy_c` times its tint in xyz (what
/// [`crate::cpu::lift_weights`] weighs each channel by) and `energy_c` in w (the score's).
pub fn cluster_energies(prm: &Prm, tables: &NearTables) -> Vec<[f32; 4]> {
    prm.clusters()
        .iter()
        .zip(&tables.cluster_tint)
        .map(|(c, t)| {
            let e = c.energy * *t;
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
        let lifted =
            gpu::storage_buffer(device, "lifted weights", &vec![0u8; (clusters + tables.rooms) * 16], none);
        let rooms = gpu::storage_buffer(device, "rooms", bytemuck::cast_slice(&room_words(tables)), none);
        let mut energies = cluster_energies(prm, tables);
        if energies.is_empty() {
            energies.push([0.0; 4]);
        }
        let energy = gpu::storage_buffer(device, "lift energies", bytemuck::cast_slice(&energies), none);
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
                ("energy", energy.as_entire_binding()),
                ("weights", buffers.weights.as_entire_binding()),
                ("scores", buffers.scores.as_entire_binding()),
                ("lifted", lifted.as_entire_binding()),
                ("rooms", rooms.as_entire_binding()),
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
