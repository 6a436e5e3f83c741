//! The near field on the GPU (`shaders/near.wgsl`; `prm_precompute::near` says what the links
//! are): per texel with near-field links, `sum albedo_j factor (E_j - w_c(j) t_j)` over its links,
//! from this frame's entry irradiance and cluster weights, into `near_sum`, which the compose
//! adds to the panes (and clamps at zero). A link of a hot cell uses its own light instead of
//! `E_j` (`crate::concentrate`). Only the texels with links are visited; a frame composed from
//! caller-chosen weights has no entry irradiance, so the sums are cleared.

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, NO_SLOT, WG_LINEAR};
use crate::gpu;
use crate::layout::{GpuNearLink, GpuStruct, IndirectParams, NearTexel};

pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    b("entry_irradiance", Res::Read("array<vec4f>"), COMPUTE),
    // Cluster weights (the weight pass's `weights`).
    b("weights", Res::Read("array<vec4f>"), COMPUTE),
    // Per entry: its cluster and its cell's area ratio t (f32 bits; `prm_runtime::cpu::NearTables`).
    b("entry_cluster", Res::Read("array<vec2u>"), COMPUTE),
    b("near_texels", Res::Read("array<NearTexel>"), COMPUTE),
    b("near_links", Res::Read("array<GpuNearLink>"), COMPUTE),
    // Per entry, this frame's `E_j - w_c t_j` (written by `deviation_main`).
    b("deviation", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // One per linked texel, in near_texels order (the compose finds it through its slots).
    b("near_sum", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Per link: its own light when its cell is hot (`crate::concentrate`), stamped.
    b("link_light", Res::Read("array<vec4u>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "near",
    body: include_str!("../../shaders/near.wgsl"),
    lights: false,
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "deviation_main", workgroup: LINEAR },
        Compute { entry: "near_main", workgroup: LINEAR },
    ],
};

/// The near field's tables on the GPU: its linked texels (with their points) and links.
pub struct NearData {
    /// `NearTexel` per texel with links.
    pub texels: wgpu::Buffer,
    /// `GpuNearLink` per link.
    pub links: wgpu::Buffer,
    /// Texels with links.
    pub count: u32,
    /// Per atlas texel, its index in `texels`, or `NO_SLOT`.
    pub index: Vec<u32>,
}

impl NearData {
    pub fn new(device: &wgpu::Device, prm: &Prm) -> NearData {
        let mut index = vec![NO_SLOT; prm.texel_count()];
        let mut texels: Vec<NearTexel> = Vec::new();
        let mut links: Vec<GpuNearLink> = Vec::with_capacity(prm.near().len().max(1));
        let mut points = prm.near_points().iter();
        for l in prm.near() {
            if texels.last().is_none_or(|t| t.texel != l.texel) {
                index[l.texel as usize] = texels.len() as u32;
                // One point per run of links (an invariant of every `Prm`).
                let p = points.next().copied().unwrap_or(prm::prm_file::NearPoint {
                    texel: l.texel,
                    position: glam::Vec3::ZERO,
                    normal: glam::Vec3::Z,
                });
                texels.push(NearTexel {
                    texel: l.texel,
                    first: links.len() as u32,
                    position: p.position.to_array(),
                    normal: p.normal.to_array(),
                    ..Default::default()
                });
            }
            if let Some(t) = texels.last_mut() {
                t.count += 1;
            }
            let albedo = prm.entries()[l.entry as usize].albedo;
            links.push(GpuNearLink { factor: (albedo * l.factor).to_array(), entry: l.entry });
        }
        let count = texels.len() as u32;
        // Storage bindings cannot be empty.
        if texels.is_empty() {
            texels.push(NearTexel::default());
        }
        if links.is_empty() {
            links.push(GpuNearLink::default());
        }
        let none = wgpu::BufferUsages::empty();
        let texels = gpu::storage_buffer(device, "near texels", bytemuck::cast_slice(&texels), none);
        let links = gpu::storage_buffer(device, "near links", bytemuck::cast_slice(&links), none);
        NearData { texels, links, count, index }
    }
}

pub struct NearPass {
    deviation_pipeline: wgpu::ComputePipeline,
    pipeline: wgpu::ComputePipeline,
    entries: u32,
    group: wgpu::BindGroup,
    /// Texels with links.
    pub count: u32,
    /// Per linked texel, its near-field irradiance (`vec4f`).
    pub sums: wgpu::Buffer,
    /// Per atlas texel, its index in `sums`, or `NO_SLOT`.
    pub index: Vec<u32>,
}

impl NearPass {
    pub fn new(
        device: &wgpu::Device,
        prm: &Prm,
        params: &wgpu::Buffer,
        entry_irradiance: &wgpu::Buffer,
        weights: &wgpu::Buffer,
        data: &NearData,
        link_light: &wgpu::Buffer,
    ) -> NearPass {
        let tables = crate::cpu::NearTables::new(prm);
        let mut entry_cluster: Vec<[u32; 2]> =
            tables.cluster.iter().zip(&tables.area_ratio).map(|(&c, t)| [c, t.to_bits()]).collect();
        if entry_cluster.is_empty() {
            entry_cluster.push([0, 0]);
        }
        let (count, index) = (data.count, data.index.clone());
        let none = wgpu::BufferUsages::empty();
        let cluster_buf =
            gpu::storage_buffer(device, "entry clusters", bytemuck::cast_slice(&entry_cluster), none);
        let deviation = gpu::storage_buffer(
            device,
            "entry deviations",
            &vec![0u8; prm.entries().len().max(1) * 16],
            wgpu::BufferUsages::empty(),
        );
        let sums = gpu::storage_buffer(
            device,
            "near sums",
            &vec![0u8; count.max(1) as usize * 16],
            wgpu::BufferUsages::COPY_DST,
        );
        let layout = SHADER.layout(device, 0);
        let group = bind(
            device,
            "near field",
            &layout,
            BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("entry_irradiance", entry_irradiance.as_entire_binding()),
                ("weights", weights.as_entire_binding()),
                ("entry_cluster", cluster_buf.as_entire_binding()),
                ("near_texels", data.texels.as_entire_binding()),
                ("near_links", data.links.as_entire_binding()),
                ("deviation", deviation.as_entire_binding()),
                ("near_sum", sums.as_entire_binding()),
                ("link_light", link_light.as_entire_binding()),
            ],
        );
        let source = SHADER.source();
        let pipeline = gpu::compute_pipeline(device, "near.wgsl", &source, "near_main", &[&layout]);
        let deviation_pipeline =
            gpu::compute_pipeline(device, "near.wgsl", &source, "deviation_main", &[&layout]);
        let entries = prm.entries().len() as u32;
        NearPass { deviation_pipeline, pipeline, entries, group, count, sums, index }
    }

    /// Records the pass (after the weights, before the compose).
    pub fn encode(&self, enc: &mut wgpu::CommandEncoder) {
        if self.count == 0 {
            return;
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("near field"),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.deviation_pipeline);
        pass.dispatch_workgroups(self.entries.div_ceil(WG_LINEAR), 1, 1);
        pass.set_pipeline(&self.pipeline);
        pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
    }

    /// Records clearing the sums (a compose from caller-chosen weights has no near field).
    pub fn clear(&self, enc: &mut wgpu::CommandEncoder) {
        enc.clear_buffer(&self.sums, 0, None);
    }
}
