//! Entry irradiance on the GPU (DESIGN.md §4-5; `shaders/irradiance.wgsl`): one invocation
//! per entry point sums, over the triangles of its cell and every light, the power the light
//! delivers to the triangle (`prm::Light::triangle_power`) times its visible share from the
//! shadow maps (four probes, and 36 fine points where they disagree: `prm::cell_light`; normal
//! offset + 3x3 PCF, `shaders/lights.wgsl`), and divides by the entry's area: the mean irradiance its cell stands for, however close the
//! light. Output: one `vec4f` per entry, W/m².
//!
//! A light the shadow maps' block minima show hidden from an entry's whole cell (its bounding
//! sphere: [`crate::shadow`]) is not probed there (`RuntimeParams::cull_hidden_lights`); the
//! pass counts those (entry, light) pairs in [`EntryPass::stats`].
//!
//! An entry every light that changed since the last update is hidden from (its whole cell,
//! now and at the last update that ran it) keeps its light: the other lights' shadow maps are
//! as they were, so the pass would find what it found then. With a few lights moving in a
//! level of many rooms, most entries are such (`IndirectParams::keep_unchanged`).

use prm::prm_file::Cells;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Library, Shader, LINEAR, WG_LINEAR};
use crate::gpu;
use crate::layout::{GpuCellTriangle, GpuEntry, GpuStruct, IndirectParams};
use crate::shadow::SHADOW_GROUP;

/// Group 1 of the pass (group 0 is [`SHADOW_GROUP`]).
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    b("entries", Res::Read("array<GpuEntry>"), COMPUTE),
    // Read-write: the pass writes each triangle's visible share (`GpuCellTriangle::visibility`).
    b("cells", Res::ReadWrite("array<GpuCellTriangle>"), COMPUTE),
    b("entry_irradiance", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // [0]: (entry, light) pairs whose probes were skipped this update (the light hidden);
    // [1]: entries that kept last update's light.
    b("entry_stats", Res::ReadWrite("array<atomic<u32>>"), COMPUTE),
    // Per entry, bits of the lights hidden from its whole cell at the last update that ran it.
    b("entry_hidden", Res::ReadWrite("array<vec2u>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "irradiance",
    body: include_str!("../../shaders/irradiance.wgsl"),
    libraries: &[Library::Lights, Library::Spherical],
    groups: &[SHADOW_GROUP, BINDINGS],
    compute: &[Compute { entry: "entry_main", workgroup: LINEAR }],
};

pub struct EntryPass {
    pipeline: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    count: u32,
    /// Per-entry irradiance, `vec4f` each (w: flags), then per entry where its cell's light
    /// lands (w 1; 0 where none arrives), then which way it leaves (the same).
    pub output: wgpu::Buffer,
    /// The cells' triangles, with this frame's visibility (`GpuCellTriangle`).
    pub cells: wgpu::Buffer,
    /// `entry_stats` (`u32` counters, cleared each update).
    pub stats: wgpu::Buffer,
    /// `entry_hidden` (bound, never read on the CPU).
    _hidden: wgpu::Buffer,
}

/// The name of the entries' hidden-light bits ([`crate::memory::GpuMemory`]).
pub const ENTRY_HIDDEN: &str = "hidden lights by entry";

/// The centre of the box around `triangles` and the distance from it to the farthest corner
/// (0 and 0 for none).
fn bounding_sphere(triangles: &[[glam::Vec3; 3]]) -> (glam::Vec3, f32) {
    let corners = || triangles.iter().flatten();
    let Some(&first) = corners().next() else { return (glam::Vec3::ZERO, 0.0) };
    let (lo, hi) = corners().fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    let centre = (lo + hi) * 0.5;
    (centre, corners().map(|&p| p.distance(centre)).fold(0.0, f32::max))
}

impl EntryPass {
    /// A pass over entry points with these cells and areas (an entry of zero area gets no
    /// light); `params` is the [`crate::layout::IndirectParams`] uniform.
    pub fn new(
        device: &wgpu::Device,
        shadow_layout: &wgpu::BindGroupLayout,
        params: &wgpu::Buffer,
        cells: &Cells,
        areas: &[f32],
    ) -> EntryPass {
        let entries: Vec<GpuEntry> = areas
            .iter()
            .enumerate()
            .map(|(j, &area)| {
                let (first, end) = (cells.first[j], cells.first[j + 1]);
                let (centre, radius) = bounding_sphere(&cells.triangles[first as usize..end as usize]);
                GpuEntry {
                    first_cell: first,
                    cell_count: end - first,
                    inv_area: if area > 0.0 { 1.0 / area } else { 0.0 },
                    // Rounding outward: every corner inside.
                    bound_centre: centre.to_array(),
                    bound_radius: radius * (1.0 + 1e-5) + 1e-7 * centre.abs().max_element(),
                    ..Default::default()
                }
            })
            .collect();
        let entries = gpu::storage_buffer(
            device,
            "entries",
            bytemuck::cast_slice(&entries),
            wgpu::BufferUsages::empty(),
        );
        let mut triangles: Vec<GpuCellTriangle> = cells
            .triangles
            .iter()
            .map(|t| GpuCellTriangle {
                a: t[0].to_array(),
                b: t[1].to_array(),
                c: t[2].to_array(),
                ..Default::default()
            })
            .collect();
        // A storage binding cannot be empty.
        if triangles.is_empty() {
            triangles.push(GpuCellTriangle::default());
        }
        // Read back by the tests that hold the visibility bits to the CPU twin's.
        let cells = gpu::storage_buffer(
            device,
            "entry cells",
            bytemuck::cast_slice(&triangles),
            wgpu::BufferUsages::COPY_SRC,
        );
        let output = gpu::storage_buffer(
            device,
            "entry irradiance",
            &vec![0u8; areas.len().max(1) * 48],
            wgpu::BufferUsages::COPY_SRC,
        );
        let stats = gpu::storage_buffer(
            device,
            "entry stats",
            &[0u8; 16],
            wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        );
        let hidden = gpu::storage_buffer(
            device,
            ENTRY_HIDDEN,
            &vec![0u8; areas.len().max(1) * 8],
            wgpu::BufferUsages::empty(),
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
                ("cells", cells.as_entire_binding()),
                ("entry_irradiance", output.as_entire_binding()),
                ("entry_stats", stats.as_entire_binding()),
                ("entry_hidden", hidden.as_entire_binding()),
            ],
        );
        let pipeline = gpu::compute_pipeline(
            device,
            "irradiance.wgsl",
            &SHADER.source(),
            "entry_main",
            &[shadow_layout, &layout],
        );
        EntryPass { pipeline, group, count: areas.len() as u32, output, cells, stats, _hidden: hidden }
    }

    /// Records the pass; `shadows` is the lights + shadow maps group.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        shadows: &wgpu::BindGroup,
        timestamps: Option<wgpu::ComputePassTimestampWrites>,
    ) {
        enc.clear_buffer(&self.stats, 0, None);
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

impl EntryPass {
    /// The last update's counts (waits for the GPU): the (entry, light) pairs it did not
    /// probe, the light's shadow maps hiding the entry's whole cell; and the entries that kept
    /// their light, no light that changed reaching them.
    pub fn stats(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<(u64, u64), gpu::GpuError> {
        let bytes = gpu::read_buffer(device, queue, &self.stats)?;
        let word = |k: usize| {
            u32::from_le_bytes([bytes[4 * k], bytes[4 * k + 1], bytes[4 * k + 2], bytes[4 * k + 3]])
        };
        Ok((word(0) as u64, word(1) as u64))
    }
}
