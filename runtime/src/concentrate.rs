//! The near field where a light is close, on the GPU (`shaders/concentrate.wgsl`;
//! [`crate::cpu::concentrate`] says what and why, and is the twin).
//!
//! After the entry pass: `hot_items_main` lists the hot cells' work items, and
//! `concentrate_main`, dispatched on that list, gives each near-field link of a hot cell its own
//! light (`E_j kappa`, stamped with the update's number; a workgroup per entry, whose links
//! that take kappa are gathered so that the group computes them side by side). The near pass
//! reads a link's light only when its stamp is this update's. A hot entry kept since its last
//! run (no changed light reaches its cell: `ENTRY_UNCHANGED`) is not listed: `hot_items_main`
//! stamps its links' light as this update's, as it was.

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Library, Shader, LINEAR, WG_LINEAR};
use crate::gpu;
use crate::layout::{GpuHotEntry, GpuStruct, IndirectParams};
use crate::shadow::SHADOW_GROUP;

/// In one buffer (the concentration has no storage binding to spare): each near-field link's
/// hidden triangles ([`prm::prm_file::NearLink::hidden`], two words, low first), then the
/// links' indices grouped by entry, then the hot cells' work list (zeros: [`hot_items_len`]
/// words, filled each update); and each entry's run of links (first index in the buffer,
/// count).
pub fn link_ids(prm: &Prm) -> (Vec<u32>, Vec<(u32, u32)>) {
    let n = prm.entries().len();
    let mut per_entry: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (k, l) in prm.near().iter().enumerate() {
        per_entry[l.entry as usize].push(k as u32);
    }
    let mut ids: Vec<u32> = Vec::with_capacity(link_ids_len(prm));
    for l in prm.near() {
        ids.extend_from_slice(&[l.hidden as u32, (l.hidden >> 32) as u32]);
    }
    let mut runs = Vec::with_capacity(n);
    for links in &per_entry {
        runs.push((ids.len() as u32, links.len() as u32));
        ids.extend_from_slice(links);
    }
    ids.resize(link_ids_len(prm), 0);
    (ids, runs)
}

/// The length of [`link_ids`]'s buffer, without making it.
pub fn link_ids_len(prm: &Prm) -> usize {
    work_list(prm.near().len()) + hot_items_len(prm)
}

/// Where the hot cells' work list starts in [`link_ids`]'s buffer, for `links` near-field
/// links (`shaders/concentrate.wgsl`: `work_list`).
pub fn work_list(links: usize) -> usize {
    3 * links
}

/// Words of the hot cells' work list (after the links in [`link_ids`]): their count, the
/// concentration's dispatch (three words), then two an item (the entry, the first of its
/// links within its run), an item at most [`WG_LINEAR`] links of one entry, as many as when
/// every cell is hot. A workgroup takes an item, so no invocation computes more than one
/// kappa: lavapipe cuts an invocation short once its loops have run long enough (a workgroup
/// an entry, looping over a large cell's links, left a fifth of them stale on the CLI's
/// budget test).
pub fn hot_items_len(prm: &Prm) -> usize {
    let mut per_entry = vec![0usize; prm.entries().len()];
    for l in prm.near() {
        per_entry[l.entry as usize] += 1;
    }
    4 + 2 * per_entry.iter().map(|&c| c.div_ceil(WG_LINEAR as usize)).sum::<usize>()
}

pub const CONCENTRATE_BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    b("near_texels", Res::Read("array<NearTexel>"), COMPUTE),
    b("hot_entries", Res::Read("array<GpuHotEntry>"), COMPUTE),
    // [`link_ids`]: the links' hidden triangles, the links by entry (each entry's run:
    // `GpuHotEntry::first_link`, `link_count`), then the hot cells' work list, made each update.
    b("link_ids", Res::ReadWrite("array<atomic<u32>>"), COMPUTE),
    // The entry pass's cell triangles, with their visibility.
    b("cells", Res::Read("array<GpuCellTriangle>"), COMPUTE),
    b("entry_irradiance", Res::Read("array<vec4f>"), COMPUTE),
    // Per link: (bits of E_j kappa, update number).
    b("link_light", Res::ReadWrite("array<vec4u>"), COMPUTE),
];

pub const CONCENTRATE: Shader = Shader {
    stem: "concentrate",
    body: include_str!("../../shaders/concentrate.wgsl"),
    libraries: &[Library::Lights, Library::FormFactor, Library::Spherical],
    groups: &[SHADOW_GROUP, CONCENTRATE_BINDINGS],
    compute: &[
        Compute { entry: "hot_items_main", workgroup: LINEAR },
        Compute { entry: "hot_args_main", workgroup: [1, 1, 1] },
        Compute { entry: "concentrate_main", workgroup: LINEAR },
    ],
};

/// The listing and the concentration, and the per-link light they fill.
pub struct ConcentratePass {
    items: wgpu::ComputePipeline,
    args: wgpu::ComputePipeline,
    concentrate: wgpu::ComputePipeline,
    concentrate_group: wgpu::BindGroup,
    texels: u32,
    entries: u32,
    /// Near-field links (`IndirectParams::link_count`).
    pub links: u32,
    /// [`link_ids`]'s buffer, and the concentration's dispatch copied out of its work list (a
    /// buffer read as a dispatch's arguments cannot be bound for writing in that dispatch).
    link_ids: wgpu::Buffer,
    hot_args: wgpu::Buffer,
    /// Per link: `vec4u` (bits of E_j kappa, update number).
    pub link_light: wgpu::Buffer,
}

/// The buffers the near pass already holds, shared here.
pub struct NearBuffers<'a> {
    pub texels: &'a wgpu::Buffer,
    pub texel_count: u32,
}

impl ConcentratePass {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        device: &wgpu::Device,
        shadow_layout: &wgpu::BindGroupLayout,
        prm: &Prm,
        tables: &crate::cpu::NearTables,
        params: &wgpu::Buffer,
        cells: &wgpu::Buffer,
        entry_irradiance: &wgpu::Buffer,
        near: NearBuffers,
    ) -> ConcentratePass {
        let n = prm.entries().len();
        let (link_ids, runs) = link_ids(prm);
        let cells_of = &prm.cells().first;
        let mut hot: Vec<GpuHotEntry> = (0..n)
            .map(|j| GpuHotEntry {
                centroid: tables.centroid[j].to_array(),
                size: tables.size[j],
                first_cell: cells_of[j],
                cell_count: cells_of[j + 1] - cells_of[j],
                first_link: runs[j].0,
                link_count: runs[j].1,
            })
            .collect();
        // Storage bindings cannot be empty.
        if hot.is_empty() {
            hot.push(GpuHotEntry::default());
        }
        let none = wgpu::BufferUsages::empty();
        let hot_buf = gpu::storage_buffer(device, "hot entries", bytemuck::cast_slice(&hot), none);
        let ids_buf = gpu::storage_buffer(
            device,
            "link ids by entry",
            bytemuck::cast_slice(&link_ids),
            wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        );
        let link_light =
            gpu::storage_buffer(device, "link light", &vec![0u8; prm.near().len().max(1) * 16], none);
        let hot_args = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hot work dispatch"),
            size: 12,
            usage: wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let layout = CONCENTRATE.layout(device, 1);
        let concentrate_group = bind(
            device,
            "concentrate",
            &layout,
            CONCENTRATE_BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("near_texels", near.texels.as_entire_binding()),
                ("hot_entries", hot_buf.as_entire_binding()),
                ("link_ids", ids_buf.as_entire_binding()),
                ("cells", cells.as_entire_binding()),
                ("entry_irradiance", entry_irradiance.as_entire_binding()),
                ("link_light", link_light.as_entire_binding()),
            ],
        );
        let source = CONCENTRATE.source();
        let pipeline = |entry: &str| {
            gpu::compute_pipeline(device, "concentrate.wgsl", &source, entry, &[shadow_layout, &layout])
        };
        let (items, args, concentrate) =
            (pipeline("hot_items_main"), pipeline("hot_args_main"), pipeline("concentrate_main"));
        ConcentratePass {
            items,
            args,
            concentrate,
            concentrate_group,
            texels: near.texel_count,
            entries: n as u32,
            links: prm.near().len() as u32,
            link_ids: ids_buf,
            hot_args,
            link_light,
        }
    }

    /// Records both passes (after the entry pass, before the weights); `shadows` is the lights
    /// group.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        shadows: &wgpu::BindGroup,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        if self.texels == 0 {
            return;
        }
        // The work list starts after the links' bits and indices.
        let list = work_list(self.links as usize) as u64 * 4;
        enc.clear_buffer(&self.link_ids, list, Some(16));
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("hot work items"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, shadows, &[]);
            pass.set_bind_group(1, &self.concentrate_group, &[]);
            pass.set_pipeline(&self.items);
            pass.dispatch_workgroups(self.entries.div_ceil(WG_LINEAR), 1, 1);
            pass.set_pipeline(&self.args);
            pass.dispatch_workgroups(1, 1, 1);
        }
        enc.copy_buffer_to_buffer(&self.link_ids, list + 4, &self.hot_args, 0, 12);
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("concentrate"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.concentrate);
        pass.set_bind_group(0, shadows, &[]);
        pass.set_bind_group(1, &self.concentrate_group, &[]);
        // A workgroup a hot cell's work item, in rows of at most 32768 (`hot_args_main`).
        pass.dispatch_workgroups_indirect(&self.hot_args, 0);
    }
}
