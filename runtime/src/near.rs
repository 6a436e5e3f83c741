//! The near field on the GPU (`shaders/near.wgsl`; `prm_precompute::near` says what the links
//! are): per texel with near-field links, `sum albedo_j factor (E_j - w_c(j) t_j)` over its links,
//! from this frame's entry irradiance and cluster weights, into `near_sum`, which the compose
//! adds to the panes (and clamps at zero). A link of a hot cell uses its own light instead of
//! `E_j` (`crate::concentrate`). Only the texels with links are visited; their echo follows,
//! then the relay (the links' own deviation from each cluster's mean, into `deviation`), then
//! the far field (`crate::far`) adds its light to the same sums. A frame composed from caller-chosen weights
//! has no entry irradiance, so the sums are cleared.

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Shader, LINEAR, NO_CELL, NO_SLOT, WG_LINEAR};
use crate::far::FarPass;
use crate::gpu;
use crate::layout::{GpuEchoLink, GpuNearLink, GpuStruct, IndirectParams, NearTexel};

pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    b("entry_irradiance", Res::Read("array<vec4f>"), COMPUTE),
    // Cluster weights (the weight pass's `weights`).
    b("weights", Res::Read("array<vec4f>"), COMPUTE),
    // Per entry: its cluster and its cell's area ratio t (f32 bits; `prm_runtime::cpu::NearTables`).
    b("entry_cluster", Res::Read("array<vec2u>"), COMPUTE),
    b("near_texels", Res::Read("array<NearTexel>"), COMPUTE),
    b("near_links", Res::Read("array<GpuNearLink>"), COMPUTE),
    // Per entry, this frame's `E_j - w_c t_j` (written by `deviation_main`; the relay
    // adds to it after the echo).
    b("deviation", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // One per linked texel, in near_texels order (the compose finds it through its slots).
    b("near_sum", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Per link: its own light when its cell is hot (`crate::concentrate`), stamped.
    b("link_light", Res::Read("array<vec4u>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "near",
    body: include_str!("../../shaders/near.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "deviation_main", workgroup: LINEAR },
        Compute { entry: "near_main", workgroup: LINEAR },
    ],
};

pub const ECHO_BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    // Per near point: its echo links `first .. first + count`, and its cell (`NO_CELL`: none;
    // `crate::cpu::NearTables::point_cell`).
    b("echo_runs", Res::Read("array<vec4u>"), COMPUTE),
    b("echo_links", Res::Read("array<GpuEchoLink>"), COMPUTE),
    b("near_sum", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Per near point, the echo's first bounce.
    b("echo_sum", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Per entry, its cell's points in `echo_cell_points`: those of texels `x .. y`, then its
    // crease points `y .. z` ([`echo_cells`]).
    b("echo_cells", Res::Read("array<vec4u>"), COMPUTE),
    b("echo_cell_points", Res::Read("array<u32>"), COMPUTE),
];

pub const ECHO: Shader = Shader {
    stem: "echo",
    body: include_str!("../../shaders/echo.wgsl"),
    libraries: &[],
    groups: &[ECHO_BINDINGS],
    compute: &[
        Compute { entry: "echo_cells_main", workgroup: LINEAR },
        Compute { entry: "echo_first_main", workgroup: LINEAR },
        Compute { entry: "echo_second_main", workgroup: LINEAR },
    ],
};

pub const RELAY_BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    // The weight pass's member ranges (clusters first) into `relay_members`.
    b("relay_ranges", Res::Read("array<vec2u>"), COMPUTE),
    // Per member: its cell's run of slots further on, t_j, its entry; then the runs
    // ([`cluster_members`]).
    b("relay_members", Res::Read("array<u32>"), COMPUTE),
    b("near_sum", Res::Read("array<vec4f>"), COMPUTE),
    b("deviation", Res::ReadWrite("array<vec4f>"), COMPUTE),
];

pub const RELAY: Shader = Shader {
    stem: "relay",
    body: include_str!("../../shaders/relay.wgsl"),
    libraries: &[],
    groups: &[RELAY_BINDINGS],
    compute: &[Compute { entry: "relay_main", workgroup: LINEAR }],
};

/// Per cluster member, clusters in order (the weight pass's `indices`, whose `ranges` index
/// it), four words: where its cell's texels' slots among the near sums lie further on in the
/// same table (first, end; equal for an entry no texel stands for:
/// [`crate::cpu::NearTables::cell_texels`]), its cell's area over A/N (f32 bits), its entry;
/// then those slots. The relay and the lift (`crate::lift`) read the near field's mean over
/// each cell from it (one table: the lift has no binding left for a second). None when no
/// member has a texel (a map without a far field).
fn cluster_members(prm: &Prm, tables: &crate::cpu::NearTables, index: &[u32]) -> Option<Vec<u32>> {
    let count: usize = prm.clusters().iter().map(|c| c.members.len()).sum();
    let mut words = Vec::with_capacity(4 * count + tables.cell_texels.len());
    let mut first = 4 * count as u32;
    for &m in prm.clusters().iter().flat_map(|c| c.members.iter()) {
        let j = m as usize;
        let end = first + tables.cell_first[j + 1] - tables.cell_first[j];
        words.extend([first, end, tables.area_ratio[j].to_bits(), m]);
        first = end;
    }
    if first as usize == 4 * count {
        return None;
    }
    for run in member_cell_runs(prm, tables) {
        words.extend(
            tables.cell_texels[run].iter().map(|&t| index.get(t as usize).copied().unwrap_or(NO_SLOT)),
        );
    }
    Some(words)
}

/// Each cluster member's run of its cell's texels in `NearTables::cell_texels`, members in
/// cluster order: the order the member table lists them in after its four words a member
/// ([`cluster_members`]; the lift's slot areas follow it, `crate::lift::slot_areas`).
pub(crate) fn member_cell_runs<'a>(
    prm: &'a Prm,
    tables: &'a crate::cpu::NearTables,
) -> impl Iterator<Item = std::ops::Range<usize>> + 'a {
    prm.clusters().iter().flat_map(|c| c.members.iter()).map(|&m| {
        let j = m as usize;
        tables.cell_first[j] as usize..tables.cell_first[j + 1] as usize
    })
}

/// The relay's pipeline (`shaders/relay.wgsl`): the near field's own deviation from each
/// cluster's mean, which the far field sends (`crate::cpu::near_deviation`).
struct RelayPass {
    pipeline: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    clusters: u32,
}

/// Per entry, where its cell's points lie in the list that follows (the texels' points, then
/// the crease points: `[first, texels' end, end, 0]`), and the list: the echo reads each
/// source against its cell's mean ([`crate::cpu::echo_input`]).
pub fn echo_cells(prm: &Prm, tables: &crate::cpu::NearTables) -> (Vec<[u32; 4]>, Vec<u32>) {
    let entries = tables.cell_point_first.len().saturating_sub(1);
    let points = tables.point_cell.len();
    // The crease points with a cell, by cell, in point order.
    let mut creases: Vec<(u32, u32)> = (prm.echo().first_crease(points)..points)
        .map(|x| (tables.point_cell[x], x as u32))
        .filter(|&(c, _)| (c as usize) < entries)
        .collect();
    creases.sort_unstable();
    let (mut cells, mut list) = (Vec::with_capacity(entries.max(1)), Vec::new());
    let mut k = 0;
    for j in 0..entries {
        let first = list.len() as u32;
        list.extend_from_slice(
            &tables.cell_points[tables.cell_point_first[j] as usize..tables.cell_point_first[j + 1] as usize],
        );
        let texels_end = list.len() as u32;
        while k < creases.len() && creases[k].0 as usize == j {
            list.push(creases[k].1);
            k += 1;
        }
        cells.push([first, texels_end, list.len() as u32, 0]);
    }
    (cells, list)
}

/// The echo's pipelines and tables (`shaders/echo.wgsl`); none when the map has no echo.
struct EchoPass {
    cells: wgpu::ComputePipeline,
    first: wgpu::ComputePipeline,
    second: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    entries: u32,
}

impl EchoPass {
    fn new(
        device: &wgpu::Device,
        prm: &Prm,
        tables: &crate::cpu::NearTables,
        params: &wgpu::Buffer,
        sums: &wgpu::Buffer,
    ) -> Option<EchoPass> {
        let echo = prm.echo();
        if echo.links.is_empty() {
            return None;
        }
        let points = prm.near_points().len();
        let mut runs = vec![[0u32, 0, NO_CELL, 0]; points.max(1)];
        for (k, l) in echo.links.iter().enumerate() {
            let r = &mut runs[l.receiver as usize];
            if r[1] == 0 {
                r[0] = k as u32;
            }
            r[1] += 1;
        }
        // A crease point's echo is its texel's (the third bounce goes on from there): its
        // texel's run of links.
        for x in echo.first_crease(points)..points {
            runs[x] = runs[echo.echo_of(x, points)];
        }
        for (r, &c) in runs.iter_mut().zip(&tables.point_cell) {
            r[2] = c;
        }
        let (mut cells, mut cell_points) = echo_cells(prm, tables);
        let entries = cells.len() as u32;
        // Storage bindings cannot be empty.
        if cells.is_empty() {
            cells.push([0; 4]);
        }
        if cell_points.is_empty() {
            cell_points.push(0);
        }
        let links: Vec<GpuEchoLink> = echo
            .links
            .iter()
            .map(|l| GpuEchoLink {
                factor: (echo.albedo[l.source as usize] * l.factor).to_array(),
                source: l.source,
            })
            .collect();
        let none = wgpu::BufferUsages::empty();
        let runs = gpu::storage_buffer(device, "echo runs", bytemuck::cast_slice(&runs), none);
        let links = gpu::storage_buffer(device, "echo links", bytemuck::cast_slice(&links), none);
        let echo_sum = gpu::storage_buffer(device, "echo sums", &vec![0u8; points.max(1) * 16], none);
        let cells = gpu::storage_buffer(device, "echo cells", bytemuck::cast_slice(&cells), none);
        let cell_points =
            gpu::storage_buffer(device, "echo cell points", bytemuck::cast_slice(&cell_points), none);
        let layout = ECHO.layout(device, 0);
        let group = bind(
            device,
            "near field echo",
            &layout,
            ECHO_BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("echo_runs", runs.as_entire_binding()),
                ("echo_links", links.as_entire_binding()),
                ("near_sum", sums.as_entire_binding()),
                ("echo_sum", echo_sum.as_entire_binding()),
                ("echo_cells", cells.as_entire_binding()),
                ("echo_cell_points", cell_points.as_entire_binding()),
            ],
        );
        let source = ECHO.source();
        let pipeline = |entry: &str| gpu::compute_pipeline(device, "echo.wgsl", &source, entry, &[&layout]);
        Some(EchoPass {
            cells: pipeline("echo_cells_main"),
            first: pipeline("echo_first_main"),
            second: pipeline("echo_second_main"),
            group,
            entries,
        })
    }
}

/// The near field's tables on the GPU: its linked texels (with their points) and links.
pub struct NearData {
    /// `NearTexel` per texel with links.
    pub texels: wgpu::Buffer,
    /// `GpuNearLink` per link.
    pub links: wgpu::Buffer,
    /// Texels with links.
    pub count: u32,
    /// Texels with a sum: those with links (`0 .. count`, in `texels` order), then those only
    /// the far field lights (`crate::far`).
    pub total: u32,
    /// Per atlas texel, its slot among the sums, or `NO_SLOT`.
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
                // A crease point (its texel past the atlas's) has a sum but no texel to compose.
                if let Some(slot) = index.get_mut(l.texel as usize) {
                    *slot = texels.len() as u32;
                }
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
        let mut total = count;
        for t in &prm.far().texels {
            if index[t.texel as usize] == NO_SLOT {
                index[t.texel as usize] = total;
                total += 1;
            }
        }
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
        NearData { texels, links, count, total, index }
    }
}

pub struct NearPass {
    deviation_pipeline: wgpu::ComputePipeline,
    pipeline: wgpu::ComputePipeline,
    entries: u32,
    group: wgpu::BindGroup,
    /// Texels with links.
    pub count: u32,
    /// Per texel with links or far field, its near- plus far-field irradiance (`vec4f`).
    pub sums: wgpu::Buffer,
    /// Per atlas texel, its index in `sums`, or `NO_SLOT`.
    pub index: Vec<u32>,
    /// Where the near points' expected light starts in `sums` (after every texel's sum).
    pub expected_at: u32,
    echo: Option<EchoPass>,
    /// The near field's own deviation, into `deviation` for the far field.
    relay: Option<RelayPass>,
    /// [`cluster_members`]' buffer, for the relay and the lift; None without a far field.
    pub members: Option<wgpu::Buffer>,
    /// The far field, added to the sums after the echo.
    pub far: Option<FarPass>,
}

impl NearPass {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        device: &wgpu::Device,
        shadow_layout: &wgpu::BindGroupLayout,
        prm: &Prm,
        tables: &crate::cpu::NearTables,
        params: &wgpu::Buffer,
        entry_irradiance: &wgpu::Buffer,
        weights: &wgpu::Buffer,
        ranges: &wgpu::Buffer,
        data: &NearData,
        link_light: &wgpu::Buffer,
    ) -> NearPass {
        let mut entry_cluster: Vec<[u32; 2]> =
            tables.cluster.iter().zip(&tables.area_ratio).map(|(&c, t)| [c, t.to_bits()]).collect();
        if entry_cluster.is_empty() {
            entry_cluster.push([0, 0]);
        }
        let (count, index) = (data.count, data.index.clone());
        let none = wgpu::BufferUsages::empty();
        let cluster_buf =
            gpu::storage_buffer(device, "entry clusters", bytemuck::cast_slice(&entry_cluster), none);
        // Per entry, this update's deviation `E_j - w_c t_j` (`vec4f`), then the far field's
        // tables (`crate::far::deviation_len`); the bind groups hold it.
        let deviation_buffer = gpu::storage_buffer(
            device,
            "entry deviations",
            &vec![0u8; crate::far::deviation_len(prm.entries().len()) * 16],
            none,
        );
        let deviation = &deviation_buffer;
        // The sums, then the near points' expected light (`shaders/near.wgsl`).
        let sums = gpu::storage_buffer(
            device,
            "near sums",
            &vec![0u8; (data.total + count).max(1) as usize * 16],
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
        let echo = EchoPass::new(device, prm, tables, params, &sums);
        let far = FarPass::new(
            device,
            shadow_layout,
            prm,
            tables,
            crate::far::FarBuffers { params, deviation, sums: &sums },
            &index,
        );
        let members = far
            .as_ref()
            .and_then(|_| cluster_members(prm, tables, &index))
            .map(|words| gpu::storage_buffer(device, "cluster members", bytemuck::cast_slice(&words), none));
        let relay = match (&members, count) {
            (Some(members), 1..) => {
                let layout = RELAY.layout(device, 0);
                let group = bind(
                    device,
                    "relay",
                    &layout,
                    RELAY_BINDINGS,
                    &[
                        ("params", params.as_entire_binding()),
                        ("relay_ranges", ranges.as_entire_binding()),
                        ("relay_members", members.as_entire_binding()),
                        ("near_sum", sums.as_entire_binding()),
                        ("deviation", deviation.as_entire_binding()),
                    ],
                );
                let pipeline =
                    gpu::compute_pipeline(device, "relay.wgsl", &RELAY.source(), "relay_main", &[&layout]);
                Some(RelayPass { pipeline, group, clusters: prm.clusters().len() as u32 })
            }
            _ => None,
        };
        NearPass {
            deviation_pipeline,
            pipeline,
            entries,
            group,
            count,
            sums,
            index,
            expected_at: data.total,
            echo,
            relay,
            members,
            far,
        }
    }

    /// Records the pass (after the weights, before the compose).
    /// With `timer`, the near field with its echo and relay is pass 5 and the far field pass 6.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        shadows: &wgpu::BindGroup,
        timer: Option<&crate::timer::PassTimer>,
    ) {
        if self.count == 0 && self.far.is_none() {
            return;
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("near field"),
            timestamp_writes: timer.map(|t| t.writes(5)),
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.deviation_pipeline);
        pass.dispatch_workgroups(self.entries.div_ceil(WG_LINEAR), 1, 1);
        if self.count > 0 {
            pass.set_pipeline(&self.pipeline);
            pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
        }
        if let Some(echo) = &self.echo {
            // Each source against its cell's mean, then two bounces (`crate::cpu::ECHO_BOUNCES`).
            pass.set_bind_group(0, &echo.group, &[]);
            pass.set_pipeline(&echo.cells);
            pass.dispatch_workgroups(echo.entries.div_ceil(WG_LINEAR), 1, 1);
            pass.set_pipeline(&echo.first);
            pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
            pass.set_pipeline(&echo.second);
            pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
        }
        if let Some(relay) = &self.relay {
            pass.set_bind_group(0, &relay.group, &[]);
            pass.set_pipeline(&relay.pipeline);
            pass.dispatch_workgroups(relay.clusters.div_ceil(WG_LINEAR), 1, 1);
        }
        drop(pass);
        if let Some(far) = &self.far {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("far field"),
                timestamp_writes: timer.map(|t| t.writes(6)),
            });
            far.encode(&mut pass, shadows);
        }
    }

    /// Records clearing the sums (a compose from caller-chosen weights has no near field).
    pub fn clear(&self, enc: &mut wgpu::CommandEncoder) {
        enc.clear_buffer(&self.sums, 0, None);
    }
}
