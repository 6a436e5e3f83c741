//! Entry irradiance on the GPU (DESIGN.md §5 step 2; `shaders/irradiance.wgsl`): one
//! invocation per entry point sums every light's `I(w) V cos / r²`, with V from the shadow
//! maps (normal offset + 3x3 PCF, `shaders/lights.wgsl`). Output: one `vec4f` per entry, W/m².

use glam::Vec3;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, WG_LINEAR};
use crate::gpu;
use crate::layout::{GpuEntry, GpuStruct, IndirectParams};
use crate::shadow::SHADOW_GROUP;

/// Group 1 of the pass (group 0 is [`SHADOW_GROUP`]).
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    b("entries", Res::Read("array<GpuEntry>"), COMPUTE),
    b("entry_irradiance", Res::ReadWrite("array<vec4f>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "irradiance",
    body: include_str!("../../shaders/irradiance.wgsl"),
    lights: true,
    groups: &[SHADOW_GROUP, BINDINGS],
    compute: &[Compute { entry: "entry_main", workgroup: LINEAR }],
};

pub struct EntryPass {
    pipeline: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    count: u32,
    /// Per-entry irradiance, `vec4f` each (w unused).
    pub output: wgpu::Buffer,
}

impl EntryPass {
    /// A pass over these entry points (position, unit normal); `params` is the
    /// [`crate::layout::IndirectParams`] uniform.
    pub fn new(
        device: &wgpu::Device,
        shadow_layout: &wgpu::BindGroupLayout,
        params: &wgpu::Buffer,
        points: &[(Vec3, Vec3)],
    ) -> EntryPass {
        let entries: Vec<GpuEntry> = points
            .iter()
            .map(|(p, n)| GpuEntry { position: p.to_array(), normal: n.to_array(), ..Default::default() })
            .collect();
        let entries = gpu::storage_buffer(
            device,
            "entries",
            bytemuck::cast_slice(&entries),
            wgpu::BufferUsages::empty(),
        );
        let output = gpu::storage_buffer(
            device,
            "entry irradiance",
            &vec![0u8; points.len() * 16],
            wgpu::BufferUsages::COPY_SRC,
        );
        let layout = SHADER.layout(device, 1);
        let group = bind(
            device,
            "entry irradiance",
            &layout,
            BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("entries", entries.as_entire_binding()),
                ("entry_irradiance", output.as_entire_binding()),
            ],
        );
        let pipeline = gpu::compute_pipeline(
            device,
            "irradiance.wgsl",
            &SHADER.source(),
            "entry_main",
            &[shadow_layout, &layout],
        );
        EntryPass { pipeline, group, count: points.len() as u32, output }
    }

    /// Records the pass; `shadows` is the lights + shadow maps group.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        shadows: &wgpu::BindGroup,
        timestamps: Option<wgpu::ComputePassTimestampWrites>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("entry irradiance"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, shadows, &[]);
        pass.set_bind_group(1, &self.group, &[]);
        pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
    }
}
