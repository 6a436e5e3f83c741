//! The per-frame indirect lightmap on the GPU (DESIGN.md §5 steps 1-4): what a game links.
//!
//! [`Runtime::update`] takes the frame's lights. When nothing changed it does nothing at all;
//! otherwise it re-renders the shadow maps of the lights that moved, then records the compute
//! passes in one submission: entry irradiance, cluster weights, the near field, the weights
//! lifted by it, top-K selection, compose.
//! The result stays on the GPU in [`Runtime::lightmap`].

use std::path::Path;

use glam::Vec3;
use prm::prm_file::{Prm, PrmError};
use prm::{Light, Scene};

use crate::compose::{ComposeBytes, ComposePass};
use crate::concentrate::{ConcentratePass, NearBuffers};
use crate::irradiance::EntryPass;
use crate::layout::IndirectParams;
use crate::lift::{LiftBuffers, LiftPass};
use crate::lights::LightError;
use crate::near::{NearData, NearPass};
use crate::shadow::ShadowMaps;
use crate::weights::WeightPass;

/// Where the runtime's pane budget applies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Budget {
    /// Local: at each vertex of the atlas tile grid, the `top_k` clusters that bring the tiles
    /// around it the most light, the groups standing in for the others, each pane's weight
    /// blended over a tile from its four corners (`cpu::compose_local`; the default).
    #[default]
    Local,
    /// One list for the whole map: the `top_k` clusters with the most light over all texels,
    /// the groups standing in for the others everywhere (`cpu::compose_selected`).
    Global,
}

/// Runtime settings.
#[derive(Clone, Copy, Debug)]
pub struct RuntimeParams {
    /// Panes composed per frame (default 32; >= the cluster count means all): picked at each
    /// vertex of the atlas tile grid or for the whole map, as `budget` says, the strongest by
    /// `|luminance(weight)| x energy` (a lifted weight may be negative, `cpu::lift_weights`).
    pub top_k: usize,
    /// Where `top_k` applies (default local: at each tile grid vertex).
    pub budget: Budget,
    /// Texels per side of each shadow-map layer (default 1024).
    pub shadow_size: u32,
    /// Tiles per side of a directional light's shadow map at most (default
    /// [`crate::memory::SUN_TILES_MAX`]; 1: one map over the whole level). A tile covers at
    /// most 4 m of the level (`SUN_TILE_SPAN`), so a room of 8 m gets 3 x 3.
    pub sun_tiles: u32,
    /// Compose each group's pane for the light of its clusters left out of the top K
    /// (default true; `prm::prm_file` module doc). No effect on a `.prm` without groups.
    pub residual: bool,
    /// Skip the entry pass's shadow probes of a light whose shadow maps hide an entry's whole
    /// cell (default true): the cell's blocks of the light's maps (`crate::shadow`) hold
    /// occluders nearer the light than any point of the cell. The lightmap is the same either
    /// way (the probes would read 0); only the work differs.
    pub cull_hidden_lights: bool,
    /// Compose again only the atlas tiles whose light may have changed since the last compose
    /// (default true; `crate::tile_changes`): the lightmap is the same bits either way, only
    /// the work differs.
    pub recompose_changed_only: bool,
    /// How far the light an atlas tile's panes give it, or one of its texels' near-field sums,
    /// may move, as a share of the tile's light, and still leave the tile as it is (default 0:
    /// only the same bits do; `crate::tile_changes`). A kept tile stays within about twice this
    /// of the light it would get now. Meant for levels whose rooms are joined, where one
    /// moving lamp moves every weight of the level a little through the lift's `lambda`
    /// (`cpu::lift_weights`, kept per room).
    pub recompose_tolerance: f32,
}

impl RuntimeParams {
    /// What is wrong with these parameters on any device, if anything (the GPU runtime also
    /// holds the shadow maps to its device's largest texture). The CPU twin's callers check
    /// them here too: it takes what it uses of them without complaint.
    pub fn check(&self) -> Result<(), String> {
        if self.top_k == 0 {
            return Err("top_k must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.recompose_tolerance) {
            return Err(format!("the recompose tolerance {} must be in 0..=1", self.recompose_tolerance));
        }
        if self.shadow_size < 16 {
            return Err(format!("shadow map size {} must be at least 16", self.shadow_size));
        }
        if !(1..=16).contains(&self.sun_tiles) {
            return Err(format!(
                "{} tiles a side for a directional light's shadow map: give 1 to 16",
                self.sun_tiles
            ));
        }
        Ok(())
    }
}

impl Default for RuntimeParams {
    fn default() -> Self {
        RuntimeParams {
            top_k: 32,
            budget: Budget::Local,
            shadow_size: 1024,
            sun_tiles: crate::lights::SUN_TILES_MAX,
            residual: true,
            cull_hidden_lights: true,
            recompose_changed_only: true,
            recompose_tolerance: 0.0,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    #[error(transparent)]
    Light(#[from] LightError),
    #[error(transparent)]
    Prm(#[from] PrmError),
    #[error("{0}")]
    Params(String),
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}

/// What one [`Runtime::update`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Update {
    /// The lightmap was recomposed (false: lights unchanged, no GPU work at all).
    pub composed: bool,
}

pub struct Runtime {
    device: wgpu::Device,
    queue: wgpu::Queue,
    params: RuntimeParams,
    params_buf: wgpu::Buffer,
    shadows: ShadowMaps,
    entries: EntryPass,
    concentrate: ConcentratePass,
    weights: WeightPass,
    near: NearPass,
    /// The near field's later bounces (`crate::cpu::lift_weights`); none without a far field.
    lift: Option<LiftPass>,
    compose: ComposePass,
    energies: Vec<f32>,
    clusters: usize,
    groups: usize,
    entry_count: u32,
    /// What `new` allocated for the map (`gpu_memory`).
    memory: crate::memory::GpuMemory,
    stale: bool,
    composes: u64,
    /// Updates that ran the indirect passes (`IndirectParams::frame`).
    frame: u32,
    /// Whether the last update's lights may make a cell hot (any light may: a shadow edge
    /// across a cell is found on the GPU).
    any_hot: bool,
    /// The lights of the last update's entry pass (`None`: none yet, or it must run every
    /// entry again).
    entry_lights: Option<Vec<Light>>,
    /// This update's [`IndirectParams`] `changed_lo` and `changed_hi`, and whether it runs
    /// every entry (`keep_unchanged` 0).
    changed: [u32; 2],
    redo_entries: bool,
    /// Whether the next compose works every atlas tile (after [`Runtime::invalidate`]).
    recompose_all: bool,
}

impl Runtime {
    /// A runtime for `prm`, baked for `scene`, on the caller's device and queue.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &Scene,
        prm: &Prm,
        params: RuntimeParams,
    ) -> Result<Runtime, RuntimeError> {
        prm.check_scene(Path::new("the .prm"), scene)?;
        params.check().map_err(RuntimeError::Params)?;
        let max_2d = device.limits().max_texture_dimension_2d;
        if !(16..=max_2d).contains(&params.shadow_size) {
            return Err(RuntimeError::Params(format!(
                "shadow map size {} must be in 16..={max_2d}",
                params.shadow_size
            )));
        }
        check_limits(device, prm)?;
        // Every table the map needs, its allocations recorded (`gpu_memory`).
        let recording = crate::memory::Recording::start();
        let params_buf = crate::gpu::uniform_buffer::<IndirectParams>(device, "indirect params");
        let mut shadows =
            ShadowMaps::with_sun_tiles(device, queue, scene, params.shadow_size, params.sun_tiles);
        let areas: Vec<f32> = prm.entries().iter().map(|e| e.area).collect();
        let entries = EntryPass::new(device, shadows.layout(), &params_buf, prm.cells(), &areas);
        let near_data = NearData::new(device, prm);
        // Built once: the concentration, weight and near passes all read it.
        let tables = crate::cpu::NearTables::new(prm);
        // A spot that lights a cell up close gets a cube for the far field (`crate::far`), at
        // its eye: where its axis meets the level (`crate::cpu::sight_eye`).
        if !prm.far().texels.is_empty() {
            shadows.set_up_close(crate::cpu::UpClose::new(prm, &tables), crate::axis::AxisCaster::new(scene));
        }
        let concentrate = ConcentratePass::new(
            device,
            shadows.layout(),
            prm,
            &tables,
            &params_buf,
            &entries.cells,
            &entries.output,
            NearBuffers { texels: &near_data.texels, texel_count: near_data.count },
        );
        let weights = WeightPass::new(device, &params_buf, &entries.output, prm, &tables);
        let near = NearPass::new(
            device,
            shadows.layout(),
            prm,
            &tables,
            &params_buf,
            &entries.output,
            &weights.weights,
            &weights.ranges,
            &near_data,
            &concentrate.link_light,
        );
        let lift = LiftPass::new(
            device,
            prm,
            &tables,
            near.members.as_ref(),
            LiftBuffers {
                params: &params_buf,
                ranges: &weights.ranges,
                weights: &weights.weights,
                scores: &weights.scores,
                near_sum: &near.sums,
                entry_irradiance: &entries.output,
            },
        );
        let compose = ComposePass::new(device, prm, &weights.selected, &near);
        let memory = recording.finish();
        let entry_count = areas.len() as u32;
        Ok(Runtime {
            device: device.clone(),
            queue: queue.clone(),
            params,
            params_buf,
            shadows,
            entries,
            concentrate,
            weights,
            near,
            lift,
            compose,
            energies: prm.clusters().iter().map(|c| c.energy).collect(),
            clusters: prm.clusters().len(),
            groups: prm.groups().len(),
            entry_count,
            memory,
            stale: true,
            composes: 0,
            frame: 0,
            any_hot: false,
            entry_lights: None,
            changed: [0; 2],
            redo_entries: true,
            recompose_all: true,
        })
    }

    /// Brings the lightmap up to date with `lights` (at most [`prm::rig::MAX_LIGHTS`]).
    pub fn update(&mut self, lights: &[Light]) -> Result<Update, RuntimeError> {
        self.update_timed(lights, None)
    }

    /// [`Runtime::update`], writing GPU timestamps around each pass when `timer` is given
    /// (passes 0, 1, 2, 4, 5, 6, 7: irradiance, weights + selection, compose, concentration, near
    /// field and echo, far field, the compose's tile changes;
    /// see [`crate::timer::PassTimer`]).
    pub fn update_timed(
        &mut self,
        lights: &[Light],
        timer: Option<&crate::timer::PassTimer>,
    ) -> Result<Update, RuntimeError> {
        let changed = self.shadows.update(lights)?;
        if !changed && !self.stale {
            return Ok(Update { composed: false });
        }
        // From 1, and never 0 again: buffers start zeroed, so 0 would read as this update's.
        self.frame = self.frame.checked_add(1).unwrap_or(1);
        // The concentration only matters (and only runs) where a cell may be hot: a light near
        // it, or a shadow edge across it, which only the entry pass finds (any light may cast
        // one).
        self.any_hot = !lights.is_empty();
        self.note_changed_lights(lights);
        self.write_params();
        let Some(shadows) = self.shadows.group() else { return Ok(Update { composed: false }) };
        let mut enc =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("indirect") });
        self.entries.encode(&mut enc, shadows, timer.map(|t| t.writes(0)));
        if self.any_hot {
            self.concentrate.encode(&mut enc, shadows, timer.map(|t| t.writes(4)));
        }
        self.weights.encode_weights(&mut enc, timer.map(|t| t.writes(1)));
        self.near.encode(&mut enc, shadows, timer);
        if let Some(lift) = &self.lift {
            lift.encode(&mut enc);
        }
        self.weights.encode_selection(&mut enc);
        let all = self.take_recompose_all();
        self.compose.encode(&self.queue, &mut enc, all, timer);
        self.queue.submit([enc.finish()]);
        self.composes += 1;
        self.stale = false;
        Ok(Update { composed: true })
    }

    /// Makes the next [`Runtime::update`] recompose even if no light moved, running every
    /// entry again (a benchmark's worst case: every frame pays for the indirect light).
    pub fn invalidate(&mut self) {
        self.stale = true;
        self.entry_lights = None;
        self.recompose_all = true;
    }

    /// Whether this compose works every atlas tile, and from now on only the changed ones.
    fn take_recompose_all(&mut self) -> bool {
        let all = self.recompose_all || !self.params.recompose_changed_only;
        self.recompose_all = false;
        all
    }

    /// Which lights changed since the last update's entry pass (`changed`), or that it must
    /// run every entry (`redo_entries`, which `keep_unchanged` 0 tells the pass): the first update, after [`Runtime::invalidate`],
    /// without the culling (which is what tells an entry a light is hidden from it), when the
    /// lights are not the same list (count, or a light's kind: its shadow maps move to other
    /// layers), or past the 64 lights the bits name. Then remembers `lights`.
    fn note_changed_lights(&mut self, lights: &[Light]) {
        let same_list = |old: &[Light]| {
            old.len() == lights.len() && old.iter().zip(lights).all(|(a, b)| a.kind == b.kind)
        };
        self.changed = [0; 2];
        self.redo_entries = match &self.entry_lights {
            Some(old) if same_list(old) && self.params.cull_hidden_lights && lights.len() <= 64 => {
                for (i, (a, b)) in old.iter().zip(lights).enumerate() {
                    if a != b {
                        self.changed[i / 32] |= 1 << (i % 32);
                    }
                }
                false
            }
            _ => true,
        };
        self.entry_lights = Some(lights.to_vec());
    }

    /// Updates only the shadow maps and light buffer: what a direct-only frame needs (no spot's
    /// cube for the far field). The next [`Runtime::update`] recomposes.
    pub fn update_direct(&mut self, lights: &[Light]) -> Result<(), RuntimeError> {
        if self.shadows.update_direct(lights)? {
            self.stale = true;
        }
        Ok(())
    }

    /// Composes the lightmap for weights chosen by the caller (one per cluster), keeping the
    /// `top_k` strongest: the compose alone, for tests and benchmarks.
    pub fn compose_weights(&mut self, weights: &[Vec3]) -> Result<(), RuntimeError> {
        if weights.len() != self.clusters {
            return Err(RuntimeError::Params(format!(
                "{} weights for {} clusters",
                weights.len(),
                self.clusters
            )));
        }
        self.write_params();
        self.weights.upload(&self.queue, weights, &self.energies);
        let mut enc =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("compose") });
        self.weights.encode_selection(&mut enc);
        self.near.clear(&mut enc);
        let all = self.take_recompose_all();
        self.compose.encode(&self.queue, &mut enc, all, None);
        self.queue.submit([enc.finish()]);
        self.composes += 1;
        // The next update must recompose from lights even if they did not change.
        self.stale = true;
        Ok(())
    }

    /// Changes how many panes are composed; the next update recomposes.
    pub fn set_top_k(&mut self, k: usize) -> Result<(), RuntimeError> {
        if k == 0 {
            return Err(RuntimeError::Params("top_k must be at least 1".into()));
        }
        self.params.top_k = k;
        self.stale = true;
        Ok(())
    }

    fn write_params(&mut self) {
        let k = self.params.top_k.min(u32::MAX as usize) as u32;
        // A local budget: the weight pass keeps every cluster and the compose picks per vertex.
        let (global_k, local_k) = match self.params.budget {
            Budget::Local => (u32::MAX, k),
            Budget::Global => (k, 0),
        };
        self.compose.set_budget(&self.queue, local_k, self.params.residual, self.params.recompose_tolerance);
        let p = IndirectParams {
            entry_count: self.entry_count,
            light_count: self.shadows.light_count(),
            cluster_count: self.clusters as u32,
            top_k: global_k,
            group_count: self.groups as u32,
            residual: (self.params.residual && local_k == 0) as u32,
            near_texel_count: self.near.count,
            near_expected_at: self.near.expected_at,
            lift_power: self.lift.as_ref().is_some_and(|l| l.power) as u32,
            frame: self.frame,
            any_hot: self.any_hot as u32,
            far_texel_count: self.near.far.as_ref().map_or(0, |f| f.count),
            far_reach: self.near.far.as_ref().map_or(0.0, |f| f.reach),
            link_count: self.concentrate.links,
            cull_hidden: self.params.cull_hidden_lights as u32,
            changed_lo: self.changed[0],
            changed_hi: self.changed[1],
            keep_unchanged: !self.redo_entries as u32,
            sighted_lo: self.shadows.sighted_bits()[0],
            sighted_hi: self.shadows.sighted_bits()[1],
            sight_eyes: self.shadows.sight_eyes(),
        };
        self.queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&p));
    }

    /// The indirect lightmap (`Rgba32Float`, atlas-sized, W/m²).
    pub fn lightmap(&self) -> &wgpu::Texture {
        &self.compose.lightmap
    }

    /// The (entry, light) pairs the last update's entry pass did not probe because the
    /// light's shadow maps hide the entry's whole cell (`RuntimeParams::cull_hidden_lights`;
    /// waits for the GPU: for reports, not every frame).
    pub fn hidden_pairs(&self) -> Result<u64, RuntimeError> {
        Ok(self.entries.stats(&self.device, &self.queue)?.0)
    }

    /// The entries the last update's entry pass did not run again: every light that changed
    /// since the update before is hidden from their whole cells, then and now, so they kept
    /// their light (waits for the GPU: for reports, not every frame).
    pub fn unchanged_entries(&self) -> Result<u64, RuntimeError> {
        Ok(self.entries.stats(&self.device, &self.queue)?.1)
    }

    /// The shadow maps and light buffer (shared with the shading pass).
    pub fn shadows(&self) -> &ShadowMaps {
        &self.shadows
    }

    /// Reads the lightmap back (row-major RGB, W/m²). Waits for the GPU.
    pub fn read_lightmap(&self) -> Result<Vec<Vec3>, RuntimeError> {
        Ok(crate::gpu::read_rgba32f(&self.device, &self.queue, &self.compose.lightmap)?)
    }

    /// Reads back where the last update found each entry's cell's light to land
    /// (`crate::cpu::LinkLight::landing`); None where no light arrives.
    pub fn read_landing(&self) -> Result<Vec<Option<Vec3>>, RuntimeError> {
        let bytes = crate::gpu::read_buffer(&self.device, &self.queue, &self.entries.output)?;
        let n = self.entry_count as usize;
        let v: &[[f32; 4]] = bytemuck::cast_slice(&bytes[n * 16..2 * n * 16]);
        Ok(v.iter().map(|a| (a[3] > 0.0).then(|| Vec3::new(a[0], a[1], a[2]))).collect())
    }

    /// Reads back which way the last update found each entry's cell's light to leave
    /// (`crate::cpu::LinkLight::landing_normal`); None where no light arrives.
    pub fn read_landing_normal(&self) -> Result<Vec<Option<Vec3>>, RuntimeError> {
        let bytes = crate::gpu::read_buffer(&self.device, &self.queue, &self.entries.output)?;
        let n = self.entry_count as usize;
        let v: &[[f32; 4]] = bytemuck::cast_slice(&bytes[2 * n * 16..3 * n * 16]);
        Ok(v.iter().map(|a| (a[3] > 0.0).then(|| Vec3::new(a[0], a[1], a[2]))).collect())
    }

    /// Reads the last entry irradiance back (W/m² per entry).
    pub fn read_entry_irradiance(&self) -> Result<Vec<Vec3>, RuntimeError> {
        Ok(read_vec4(
            &crate::gpu::read_buffer(&self.device, &self.queue, &self.entries.output)?,
            self.entry_count as usize,
        ))
    }

    /// Reads the last cluster weights back (mean member irradiance, W/m², per cluster).
    pub fn read_weights(&self) -> Result<Vec<Vec3>, RuntimeError> {
        Ok(read_vec4(
            &crate::gpu::read_buffer(&self.device, &self.queue, &self.weights.weights)?,
            self.clusters,
        ))
    }

    /// Reads back which panes the weight pass kept: C clusters, then G groups (under a local
    /// budget every lit cluster and no group: the compose picks per tile grid vertex, and
    /// [`Runtime::compose_bytes`] counts what it summed).
    pub fn read_selected(&self) -> Result<Vec<bool>, RuntimeError> {
        let w = read_vec4(
            &crate::gpu::read_buffer(&self.device, &self.queue, &self.weights.selected)?,
            self.clusters + self.groups,
        );
        Ok(w.iter().map(|w| *w != Vec3::ZERO).collect())
    }

    /// Where the budget of `top_k` panes applies; the next update recomposes.
    pub fn set_budget(&mut self, budget: Budget) {
        self.params.budget = budget;
        self.stale = true;
    }

    /// Whether groups stand in for left-out clusters; the next update recomposes.
    pub fn set_residual(&mut self, on: bool) {
        self.params.residual = on;
        self.stale = true;
    }

    /// Bytes the last compose moved, from the records each atlas tile summed (read back:
    /// waits for the GPU).
    pub fn compose_bytes(&self) -> Result<ComposeBytes, RuntimeError> {
        Ok(self.compose.bytes(&self.compose.read_active_counts(&self.device, &self.queue)?))
    }

    /// The atlas tiles the last compose wrote, of all the atlas tiles (`crate::tile_changes`;
    /// read back: waits for the GPU).
    pub fn composed_tiles(&self) -> Result<(u32, u32), RuntimeError> {
        Ok((self.compose.composed_tiles(&self.device, &self.queue)?, self.compose.tile_count()))
    }

    /// The records each atlas tile's last compose summed: panes and groups
    /// (read back: waits for the GPU).
    pub fn read_active_counts(&self) -> Result<Vec<u32>, RuntimeError> {
        Ok(self.compose.read_active_counts(&self.device, &self.queue)?)
    }

    pub fn params(&self) -> RuntimeParams {
        self.params
    }

    /// The device memory the runtime holds: every table it allocated for the map, as
    /// allocated, and the shadow maps of the lights it has now.
    pub fn gpu_memory(&self) -> crate::memory::GpuMemory {
        let mut m = self.memory.clone();
        m.items.push(("shadow maps".into(), self.shadows.bytes()));
        m
    }

    /// Composes recorded so far (an update with unchanged lights adds none).
    pub fn composes(&self) -> u64 {
        self.composes
    }
}

/// Refuses a `.prm` whose GPU tables would not fit this device, before allocating any.
fn check_limits(device: &wgpu::Device, prm: &Prm) -> Result<(), RuntimeError> {
    let limits = device.limits();
    let atlas = prm.header().atlas();
    let (w, rows) = (atlas.width(), prm.header().atlas_height / atlas.pages);
    if w > limits.max_texture_dimension_2d || rows > limits.max_texture_dimension_2d {
        return Err(RuntimeError::Params(format!(
            "the .prm's {w}x{rows} lightmap pages exceed this device's largest texture ({})",
            limits.max_texture_dimension_2d
        )));
    }
    if atlas.pages > limits.max_texture_array_layers {
        return Err(RuntimeError::Params(format!(
            "the .prm's {} lightmap pages exceed this device's texture array layers ({})",
            atlas.pages, limits.max_texture_array_layers
        )));
    }
    let max_buf = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
    let tables = crate::memory::GpuMemory::estimate(prm);
    // A record's data offset is a u32 of bytes.
    let data = prm.data().len() as u64;
    if data > u32::MAX as u64 {
        return Err(RuntimeError::Params(format!("the .prm's pane data ({data} bytes) exceed 4 GiB")));
    }
    for (what, bytes) in tables.items.iter().filter(|(what, _)| what != crate::memory::LIGHTMAP) {
        if *bytes > max_buf {
            return Err(RuntimeError::Params(format!(
                "the .prm's {what} ({bytes} bytes) exceed this device's \
                storage-buffer limit ({max_buf} bytes)"
            )));
        }
    }
    Ok(())
}

fn read_vec4(bytes: &[u8], n: usize) -> Vec<Vec3> {
    let v: &[[f32; 4]] = bytemuck::cast_slice(&bytes[..n * 16]);
    v.iter().map(|a| Vec3::new(a[0], a[1], a[2])).collect()
}
