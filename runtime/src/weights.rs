//! Cluster weights and top-K selection on the GPU (DESIGN.md §5 steps 2-3;
//! `shaders/weights.wgsl`). `weights_main` averages each cluster's member irradiance and scores
//! it by `luminance(w) x pane energy` (`lift.wgsl` rescores the lifted, signed, weights by
//! `|luminance(w)|`); `select_main` ranks every cluster against all others
//! (O(C²), a few hundred thousand comparisons at C = 256, no sort, no atomics) and writes the
//! weights of the kept ones, zero for the rest, into [`WeightPass::selected`]; `residual_main`
//! then gives each group of clusters the weight of its left-out clusters' light (after the C
//! cluster slots of `selected`).

use glam::Vec3;
use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, WG_LINEAR};
use crate::gpu;
use crate::layout::{GpuStruct, IndirectParams};

/// The pass's one bind group.
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    b("entry_irradiance", Res::Read("array<vec4f>"), COMPUTE),
    // Per cluster c: (first member, member count) into `indices` at ranges[c]; per group g:
    // (first child cluster, child count) into `indices` at ranges[C + g]. Each index comes with
    // the member's near-field energy (links and far field) and its cell's area over A/N (f32
    // bits, `prm_runtime::cpu::NearTables`; 0 for a group's children), then 0.
    b("ranges", Res::Read("array<vec2u>"), COMPUTE),
    b("indices", Res::Read("array<vec4u>"), COMPUTE),
    // Pane energy: C clusters, then G groups; then, in `indices` order, six floats per cluster
    // member: its bounce gain times its albedo (RGB, `prm_runtime::cpu::NearTables::reflect`)
    // and its links' tint (RGB, `NearTables::tint`).
    b("energy", Res::Read("array<f32>"), COMPUTE),
    b("weights", Res::ReadWrite("array<vec4f>"), COMPUTE),
    b("scores", Res::ReadWrite("array<f32>"), COMPUTE),
    b("selected", Res::ReadWrite("array<vec4f>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "weights",
    body: include_str!("../../shaders/weights.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "weights_main", workgroup: LINEAR },
        Compute { entry: "select_main", workgroup: LINEAR },
        Compute { entry: "residual_main", workgroup: LINEAR },
    ],
};

pub struct WeightPass {
    weights_pipeline: wgpu::ComputePipeline,
    select_pipeline: wgpu::ComputePipeline,
    residual_pipeline: wgpu::ComputePipeline,
    groups: u32,
    group: wgpu::BindGroup,
    count: u32,
    /// Cluster weights (`vec4f`), written by `weights_main` or uploaded.
    pub weights: wgpu::Buffer,
    /// Cluster scores (`f32`).
    pub scores: wgpu::Buffer,
    /// Weights of the selected clusters, 0 elsewhere, then the groups' weights (`vec4f`, C + G).
    pub selected: wgpu::Buffer,
    /// Per cluster, then per group: (first, count) into the members (`vec2u`).
    pub ranges: wgpu::Buffer,
}

impl WeightPass {
    pub fn new(
        device: &wgpu::Device,
        params: &wgpu::Buffer,
        entry_irradiance: &wgpu::Buffer,
        prm: &Prm,
        near: &crate::cpu::NearTables,
    ) -> WeightPass {
        // One ranges/indices/energy table for both levels: clusters (ranges into entries), then
        // groups (ranges into clusters), to stay within 8 storage buffers per stage.
        let n = prm.clusters().len();
        let g_count = prm.groups().len();
        let mut ranges = Vec::with_capacity(n + g_count);
        let mut indices: Vec<[u32; 4]> = Vec::new();
        for c in prm.clusters() {
            ranges.push([indices.len() as u32, c.members.len() as u32]);
            indices.extend(c.members.iter().map(|&m| {
                let m = m as usize;
                [m as u32, near.energy[m].to_bits(), near.area_ratio[m].to_bits(), 0]
            }));
        }
        let mut children = vec![Vec::new(); g_count];
        for (c, &g) in prm.group_of().iter().enumerate() {
            children[g as usize].push(c as u32);
        }
        for list in &children {
            ranges.push([indices.len() as u32, list.len() as u32]);
            indices.extend(list.iter().map(|&c| [c, 0, 0, 0]));
        }
        let mut energy: Vec<f32> =
            prm.clusters().iter().map(|c| c.energy).chain(prm.groups().iter().map(|g| g.energy)).collect();
        // Per member, by its slot in `indices` (clusters' members come first): its bounce gain
        // times albedo, then its links' tint (its albedo's).
        energy.extend(prm.clusters().iter().flat_map(|c| {
            c.members.iter().flat_map(|&m| {
                let (reflect, tint) = (near.reflect[m as usize], near.tint[m as usize]);
                reflect.to_array().into_iter().chain(tint.to_array())
            })
        }));
        let ranges = gpu::storage_buffer(
            device,
            "member ranges",
            bytemuck::cast_slice(&ranges),
            wgpu::BufferUsages::empty(),
        );
        let indices = gpu::storage_buffer(
            device,
            "members",
            bytemuck::cast_slice(&indices),
            wgpu::BufferUsages::empty(),
        );
        let energy = gpu::storage_buffer(
            device,
            "pane energy",
            bytemuck::cast_slice(&energy),
            wgpu::BufferUsages::empty(),
        );
        let rw = wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let weights = gpu::storage_buffer(device, "cluster weights", &vec![0u8; n.max(1) * 16], rw);
        let scores = gpu::storage_buffer(device, "cluster scores", &vec![0u8; n * 4], rw);
        let selected =
            gpu::storage_buffer(device, "selected weights", &vec![0u8; (n + g_count).max(1) * 16], rw);

        let layout = SHADER.layout(device, 0);
        let group = bind(
            device,
            "weights",
            &layout,
            BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("entry_irradiance", entry_irradiance.as_entire_binding()),
                ("ranges", ranges.as_entire_binding()),
                ("indices", indices.as_entire_binding()),
                ("energy", energy.as_entire_binding()),
                ("weights", weights.as_entire_binding()),
                ("scores", scores.as_entire_binding()),
                ("selected", selected.as_entire_binding()),
            ],
        );
        let source = SHADER.source();
        let pipeline = |entry| gpu::compute_pipeline(device, "weights.wgsl", &source, entry, &[&layout]);
        WeightPass {
            weights_pipeline: pipeline("weights_main"),
            select_pipeline: pipeline("select_main"),
            residual_pipeline: pipeline("residual_main"),
            groups: g_count as u32,
            group,
            count: n as u32,
            weights,
            scores,
            selected,
            ranges,
        }
    }

    /// Records `weights_main` (the balanced weights the near pass reads).
    pub fn encode_weights(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("weights"),
            timestamp_writes: timestamps,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.weights_pipeline);
        pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
    }

    /// Records the selection of the weights and scores as they stand (from `encode_weights`
    /// and the lift, or uploaded) and the groups' residual weights.
    pub fn encode_selection(&self, enc: &mut wgpu::CommandEncoder) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("selection"),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.select_pipeline);
        pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
        if self.groups > 0 {
            pass.set_pipeline(&self.residual_pipeline);
            pass.dispatch_workgroups(self.groups.div_ceil(WG_LINEAR), 1, 1);
        }
    }

    /// Uploads weights chosen by the caller (with their scores), in place of `weights_main`.
    pub fn upload(&self, queue: &wgpu::Queue, weights: &[Vec3], energies: &[f32]) {
        let w: Vec<[f32; 4]> = weights.iter().map(|v| crate::layout::vec4(*v)).collect();
        let s: Vec<f32> = weights.iter().zip(energies).map(|(w, e)| prm::luminance(*w) * e).collect();
        queue.write_buffer(&self.weights, 0, bytemuck::cast_slice(&w));
        queue.write_buffer(&self.scores, 0, bytemuck::cast_slice(&s));
    }
}
