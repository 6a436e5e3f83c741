//! The far field on the GPU (`shaders/far.wgsl`; `prm_precompute::far` says what it is, and
//! `crate::cpu::far_sources` / `crate::cpu::far_field` are its twin). Two dispatches after the
//! near field and its echo:
//!
//! 1. `sources_main`, one workgroup: each entry's deviation flux `albedo_j (A/N) deviation_j`
//!    (the near pass's `deviation`, `E_j - w_c t_j + relay_j`: `crate::near`), the sum of the
//!    light the surfaces reflect onto the level (by stay share), the threshold
//!    (`crate::cpu::far_threshold`; past the cap, found by bisection over the magnitudes' bits),
//!    and the entries over it, ascending, listed by a prefix sum
//!    over the workgroup (the same list every time; the CPU twin's up to the rounding of the
//!    sums, which it adds in another order, at the threshold).
//! 2. `far_main`, one invocation per far texel: the sources' light at the texel, added to the
//!    texel's `near_sum` slot (written there when the texel has no near links of its own), which
//!    the compose adds to the panes. A source whose cell a light lights up close
//!    (`crate::cpu::LightSight`) is seen as the texel sees that light, in its own shadow maps:
//!    the pass binds the shadow group as group 0 and reads them with `shaders/lights.wgsl`.
//!
//! A stage may bind 8 storage buffers, and the shadow group takes 2 of them, so the sources'
//! list shares buffers with tables the pass already binds: their entries follow the rows of
//! `source_sees`, and their records (deviation flux; whole flux and the light that lights it
//! up close) follow the entries' irradiance in `deviation` ([`deviation_len`]).

use prm::prm_file::Prm;

use crate::bindings::{b, bind, Binding, Res, COMPUTE};
use crate::contract::{Compute, Library, Shader, LINEAR, WG_LINEAR};
use crate::cpu::{NearTables, FAR_SOURCES};
use crate::gpu;
use crate::layout::{FarEntry, GpuFarTexel, GpuStruct, IndirectParams};
use crate::shadow::SHADOW_GROUP;

/// Invocations of the one workgroup that lists the sources (`@workgroup_size(WG_FAR_SOURCES)`).
pub const WG_FAR_SOURCES: u32 = 256;

/// A source no light lights up close (`crate::cpu::FarSource::lit_by` None).
pub const NO_LIGHT: u32 = u32::MAX;

/// A source no light lights up close whose light lands apart from its cell's centroid or normal
/// (`crate::cpu::FarSource::apart`).
pub const APART: u32 = u32::MAX - 1;

/// Length in `vec4f` of the buffer the near pass leaves its deviations in, for `entries`
/// entries: the deviations, the entries' irradiance, two records a far-field source, then
/// where each entry's cell's light lands (w 0 where none does; `crate::cpu::LinkLight::landing`),
/// then which way it leaves (the same; `crate::cpu::LinkLight::landing_normal`).
pub fn deviation_len(entries: usize) -> usize {
    4 * entries + 2 * FAR_SOURCES
}

/// Group 1 (group 0 is the shadow maps' `SHADOW_GROUP`).
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(IndirectParams::NAME), COMPUTE),
    // Per entry, this update's `E_j - w_c t_j + relay_j` (the near pass's
    // `deviation_main` and relay),
    // then per entry E_j, then the sources' records, written here, then per entry where its
    // light lands and which way it leaves ([`deviation_len`]).
    b("deviation", Res::ReadWrite("array<vec4f>"), COMPUTE),
    b("far_entries", Res::Read("array<FarEntry>"), COMPUTE),
    // The entries' visibility by blocks ([`far_words`]).
    b("far_visible", Res::Read("array<u32>"), COMPUTE),
    b("far_texels", Res::Read("array<GpuFarTexel>"), COMPUTE),
    // The near field's per-texel sums (crate::near), where the compose reads both fields.
    b("near_sum", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Per source, which entries see it: a bit an entry; then the sources' entries and their
    // number ([`source_sees_words`]).
    b("source_sees", Res::ReadWrite("array<u32>"), COMPUTE),
];

pub const SHADER: Shader = Shader {
    stem: "far",
    body: include_str!("../../shaders/far.wgsl"),
    libraries: &[Library::Lights],
    groups: &[SHADOW_GROUP, BINDINGS],
    compute: &[
        Compute { entry: "sources_main", workgroup: [WG_FAR_SOURCES, 1, 1] },
        Compute { entry: "sees_main", workgroup: LINEAR },
        Compute { entry: "far_main", workgroup: LINEAR },
    ],
};

/// The far field's pipelines and tables; none when the map has no far field.
pub struct FarPass {
    sources: wgpu::ComputePipeline,
    sees: wgpu::ComputePipeline,
    /// Invocations of `sees_main`: a (source, block of 32 entries) each.
    sees_count: u32,
    texels: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    /// Texels the far field lights.
    pub count: u32,
    /// `prm::prm_file::Far::reach`.
    pub reach: f32,
}

/// The buffers the far field shares with the passes before it.
pub struct FarBuffers<'a> {
    pub params: &'a wgpu::Buffer,
    /// The near pass's deviations, [`deviation_len`] long.
    pub deviation: &'a wgpu::Buffer,
    /// The near field's per-texel sums.
    pub sums: &'a wgpu::Buffer,
}

impl FarPass {
    /// `slot_of(texel)`: the texel's place in `sums` (`crate::near::NearData::index`).
    pub fn new(
        device: &wgpu::Device,
        shadow_layout: &wgpu::BindGroupLayout,
        prm: &Prm,
        tables: &NearTables,
        buffers: FarBuffers,
        slot_of: &[u32],
    ) -> Option<FarPass> {
        let FarBuffers { params, deviation, sums } = buffers;
        let far = prm.far();
        if far.texels.is_empty() {
            return None;
        }
        let entries: Vec<FarEntry> = prm
            .entries()
            .iter()
            .enumerate()
            .map(|(j, e)| FarEntry {
                size: tables.size[j],
                normal: e.normal.to_array(),
                centroid: tables.centroid[j].to_array(),
                flux: (e.albedo * e.area).to_array(),
                stay: tables.stay[j],
                ..Default::default()
            })
            .collect();
        let texels: Vec<GpuFarTexel> = far
            .texels
            .iter()
            .map(|t| GpuFarTexel {
                position: t.position.to_array(),
                slot: slot_of[t.texel as usize],
                normal: t.normal.to_array(),
                entries: t.entries,
                weights: t.weights,
                ..Default::default()
            })
            .collect();
        let none = wgpu::BufferUsages::empty();
        let entries = gpu::storage_buffer(device, "far entries", bytemuck::cast_slice(&entries), none);
        let visible =
            gpu::storage_buffer(device, "far visibility", bytemuck::cast_slice(&far_words(far)), none);
        let texel_buf = gpu::storage_buffer(device, "far texels", bytemuck::cast_slice(&texels), none);
        let sees_words = source_sees_words(prm.entries().len());
        let source_sees = gpu::storage_buffer(device, SOURCE_SEES, &vec![0u8; sees_words * 4], none);
        let layout = SHADER.layout(device, 1);
        let group = bind(
            device,
            "far field",
            &layout,
            BINDINGS,
            &[
                ("params", params.as_entire_binding()),
                ("deviation", deviation.as_entire_binding()),
                ("far_entries", entries.as_entire_binding()),
                ("far_visible", visible.as_entire_binding()),
                ("far_texels", texel_buf.as_entire_binding()),
                ("near_sum", sums.as_entire_binding()),
                ("source_sees", source_sees.as_entire_binding()),
            ],
        );
        let source = SHADER.source();
        let layouts = [shadow_layout, &layout];
        let sources = gpu::compute_pipeline(device, "far.wgsl", &source, "sources_main", &layouts);
        let sees = gpu::compute_pipeline(device, "far.wgsl", &source, "sees_main", &layouts);
        let texels_pipeline = gpu::compute_pipeline(device, "far.wgsl", &source, "far_main", &layouts);
        Some(FarPass {
            sources,
            sees,
            sees_count: (FAR_SOURCES * prm.entries().len().div_ceil(32)) as u32,
            texels: texels_pipeline,
            group,
            count: texels.len() as u32,
            reach: far.reach,
        })
    }

    /// Records the three dispatches into an open compute pass (after the near field's).
    pub fn encode(&self, pass: &mut wgpu::ComputePass, shadows: &wgpu::BindGroup) {
        pass.set_bind_group(0, shadows, &[]);
        pass.set_bind_group(1, &self.group, &[]);
        pass.set_pipeline(&self.sources);
        pass.dispatch_workgroups(1, 1, 1);
        // A (source, block) an invocation, in rows of at most 32768 workgroups (the limit is
        // 65535).
        pass.set_pipeline(&self.sees);
        let groups = self.sees_count.div_ceil(WG_LINEAR);
        let x = groups.clamp(1, 32768);
        pass.dispatch_workgroups(x, groups.div_ceil(x), 1);
        pass.set_pipeline(&self.texels);
        pass.dispatch_workgroups(self.count.div_ceil(WG_LINEAR), 1, 1);
    }
}

/// The per-frame table of which entries see each far-field source (`shaders/far.wgsl`'s
/// `sees_main`), as the GPU memory estimate names it.
pub const SOURCE_SEES: &str = "far source visibility";

/// Words of that table for `entries` entries: [`FAR_SOURCES`] rows of a bit an entry, then the
/// sources' entries, their number, the number of those lit up close and theirs. Made once a
/// frame from the pairs' bits, the rows spare the far field's texels the search for their
/// neighbours' pairs at every source (on lavapipe, most of the far field's time).
pub fn source_sees_words(entries: usize) -> usize {
    FAR_SOURCES * entries.div_ceil(32) + 2 * FAR_SOURCES + 2
}

/// The far field's visibility as the shader reads it, in one buffer (a stage has few storage
/// bindings): the blocks' offsets, the pairs' other blocks, the pairs' bits, then
/// [`group_words`].
pub fn far_words(far: &prm::prm_file::Far) -> Vec<u32> {
    [&far.block_first[..], &far.pair_block, &far.visible, &group_words(far)].concat()
}

/// The length of [`far_words`], counted without building [`group_words`].
pub fn far_words_len(far: &prm::prm_file::Far) -> usize {
    let groups: usize = if far.texels.is_empty() {
        0
    } else {
        group_blocks(far).map(|bits| 1 + 2 * bits.len()).sum::<usize>() + 1
    };
    far.block_first.len() + far.pair_block.len() + far.visible.len() + groups
}

/// Per workgroup of `far_main` (`WG_LINEAR` consecutive far texels), the blocks of entries its
/// texels' neighbours (those with a weight) are in, each with a bit per such neighbour: G + 1
/// offsets (in pairs), then the pairs (block, bits). The workgroup passes over a source none of
/// them sees (in a level of many rooms, most) together, testing a word a pair. Empty without a
/// far field.
pub fn group_words(far: &prm::prm_file::Far) -> Vec<u32> {
    if far.texels.is_empty() {
        return Vec::new();
    }
    let mut offsets = Vec::new();
    let mut pairs = Vec::new();
    for bits in group_blocks(far) {
        offsets.push((pairs.len() / 2) as u32);
        for (block, mask) in bits {
            pairs.extend([block, mask]);
        }
    }
    offsets.push((pairs.len() / 2) as u32);
    [offsets, pairs].concat()
}

/// Per workgroup of far texels, the blocks its texels' weighted neighbours are in, with a bit
/// per neighbour.
fn group_blocks(far: &prm::prm_file::Far) -> impl Iterator<Item = std::collections::BTreeMap<u32, u32>> + '_ {
    far.texels.chunks(WG_LINEAR as usize).map(|group| {
        let mut bits = std::collections::BTreeMap::<u32, u32>::new();
        for t in group {
            for (&m, &w) in t.entries.iter().zip(&t.weights) {
                if w > 0.0 {
                    *bits.entry(m / 32).or_default() |= 1 << (m % 32);
                }
            }
        }
        bits
    })
}
