//! Shadow maps (DESIGN.md §5 step 1): one `Depth32Float` 2D-array texture holding every
//! light's layers (see [`crate::lights`] for the frusta), rendered by `shaders/shadow.wgsl`.
//!
//! Only the layers of lights whose frusta changed (position, direction, kind, cone) are
//! re-rendered; a change of colour or intensity only rewrites the light buffer.
//! [`ShadowMaps::layers_rendered`] counts layer renders so tests can check that.
//!
//! The bind group this module owns ([`SHADOW_GROUP`], group 0 of `irradiance.wgsl` and
//! `shade.wgsl`): lights, layer matrices, the depth array, a comparison sampler
//! (GreaterEqual, linear: each tap of the PCF is itself a bilinear blend of four comparisons)
//! and the layers' *block minima*: each layer cut into [`SHADOW_BLOCKS`]² blocks, the least
//! depth of each (its farthest occluder; `shaders/shadow_blocks.wgsl`, made again for the
//! layers drawn). A receiver whose depth is below every block its lookups could read is in
//! shadow at every one of them, so the entry pass can skip a light hidden from a whole cell
//! after a few block reads instead of probing each triangle (`shaders/irradiance.wgsl`).

use glam::Vec3;
use prm::{Light, LightKind, Scene};
use wgpu::util::DeviceExt;

use crate::bindings::{b, bind, Binding, Res, COMPUTE, LIT, VERTEX};
use crate::contract::{Compute, Shader, CUBE_LAYERS, LINEAR, SHADOW_BLOCKS, WG_LINEAR};
use crate::layout::{mat, GpuLight};
use crate::lights::{self, Bounds, LightError};

/// How far, in shadow texels (at the receiver's distance from a point or spot light), the entry
/// pass's shadow lookups near a cell triangle's edge are pulled into it for a second lookup
/// (`shaders/irradiance.wgsl` `entry_visibility`, which keeps the lesser): 3 x 3 PCF of bilinear
/// taps reaches 2 texels along an axis of the map (2.8 on the diagonal), and the normal offset
/// moves the lookup up to 1.5 more. A directional light's offset is [`SUN_NORMAL_OFFSET`], so
/// for it the pulled lookup may not wholly clear the footprint; the sunlit room was measured so.
/// Near a receiver's edge the footprint reads what the map holds beyond it (past a wall's top
/// edge under a ceiling, nothing), and a slope-scaled depth bias draws an occluder that meets
/// the receiver there at a grazing angle pushed away (a ceiling under a low sun; the reason a
/// directional light's map has none, [`SUN_NORMAL_OFFSET`]): both let light in.
pub const FOOTPRINT_TEXELS: f32 = 3.5;

/// How many shadow texels a lookup of a directional light's map stands off its receiver along
/// the normal (`shaders/lights.wgsl` `visibility`; other lights: 1.5 with a slope-scaled depth
/// bias). The map is drawn without a depth bias: a low sun grazes a ceiling, and the slope bias
/// drew it pushed away by several texels (23 cm at the 3.3 cm texels of a 256² map over a
/// 6 x 5 m room), lighting the walls' tops under it. Without the bias, a receiver at angle t to
/// the light is clear of its own depth at every tap of the footprint (2 texels along an axis of
/// the map, 2.8 on the diagonal) when the offset exceeds 2.8 sin t.
pub const SUN_NORMAL_OFFSET: f32 = 3.0;

/// A shadow-map pipeline: depth only, both faces, reverse-Z, with a slope-scaled depth bias
/// `slope` (negative pushes occluders away from the light).
fn shadow_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    slope: f32,
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("shadow"),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: 12,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &wgpu::vertex_attr_array![0 => Float32x3],
            })],
        },
        primitive: wgpu::PrimitiveState { cull_mode: None, ..Default::default() },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Greater),
            stencil: Default::default(),
            bias: wgpu::DepthBiasState { constant: 0, slope_scale: slope, clamp: 0.0 },
        }),
        multisample: Default::default(),
        fragment: None,
        multiview_mask: None,
        cache: None,
    })
}

/// Lights and shadow maps: group 0 of every shader that lights surfaces (with
/// `shaders/lights.wgsl`).
pub const SHADOW_GROUP: &[Binding] = &[
    b("lights", Res::Read("array<GpuLight>"), LIT),
    // One view-projection per shadow layer.
    b("shadow_mats", Res::Read("array<mat4x4f>"), LIT),
    b("shadow_tex", Res::DepthArray, LIT),
    b("shadow_sampler", Res::ComparisonSampler, LIT),
    // Per layer, SHADOW_BLOCKS² block minima (R32Float; a texture, since a pass that lights
    // surfaces may already bind the 8 storage buffers WebGPU allows a stage).
    b("shadow_blocks", Res::Texture2dArray, LIT),
];

/// The most shadow layers the lights may own: a cube and a frustum each (a spot that lights a
/// cell up close, [`lights::layers`]).
pub const MAX_LAYERS: u32 = (CUBE_LAYERS + 1) * prm::rig::MAX_LIGHTS as u32;

/// The bind group of `shaders/shadow.wgsl`.
pub const BINDINGS: &[Binding] = &[
    // One view-projection per shadow layer, picked by the instance index.
    b("layer_mats", Res::Read("array<mat4x4f>"), VERTEX),
];

pub const SHADER: Shader = Shader {
    stem: "shadow",
    body: include_str!("../../shaders/shadow.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[],
};

/// The bind group of `shaders/shadow_blocks.wgsl`.
pub const BLOCK_BINDINGS: &[Binding] = &[
    b("shadow_depth", Res::DepthArray, COMPUTE),
    // The layers whose block minima are made, one invocation row each.
    b("block_layers", Res::Read("array<u32>"), COMPUTE),
    b("block_minima", Res::WriteTexture2dArray(BLOCK_FORMAT), COMPUTE),
];

pub const BLOCKS: Shader = Shader {
    stem: "shadow_blocks",
    body: include_str!("../../shaders/shadow_blocks.wgsl"),
    libraries: &[],
    groups: &[BLOCK_BINDINGS],
    compute: &[Compute { entry: "blocks_main", workgroup: LINEAR }],
};

const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const BLOCK_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;

/// Bytes of one layer's block minima.
pub(crate) const BLOCK_BYTES_PER_LAYER: u64 = SHADOW_BLOCKS as u64 * SHADOW_BLOCKS as u64 * 4;

/// The box and sphere the directional lights' frusta cover.
pub fn scene_bounds(scene: &Scene) -> Bounds {
    let (lo, hi) = scene.bounds();
    Bounds::of_box(lo, hi)
}

/// The lights' shadow maps in one depth array, with the light buffer: bind group 0 of the
/// lighting shaders (`bindings` `SHADOW_GROUP`). A game shading with the same shadows binds
/// [`ShadowMaps::group`] with [`ShadowMaps::layout`].
pub struct ShadowMaps {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::RenderPipeline,
    /// The same without a depth bias, for directional lights' layers.
    unbiased: wgpu::RenderPipeline,
    /// Per layer: a directional light's (drawn by `unbiased`).
    directional: Vec<bool>,
    vertices: wgpu::Buffer,
    vertex_count: u32,
    size: u32,
    bounds: Bounds,
    /// Tiles per side of each directional light's map, and the most allowed.
    sun_tiles: u32,
    sun_tiles_max: u32,
    max_layers: u32,
    lights_buf: wgpu::Buffer,
    mats_buf: wgpu::Buffer,
    mats_group: wgpu::BindGroup,
    texture: Option<(wgpu::Texture, u32)>,
    sampler: wgpu::Sampler,
    blocks_pipeline: wgpu::ComputePipeline,
    blocks_layout: wgpu::BindGroupLayout,
    /// The layers drawn in an update, for the block pass.
    block_layers: wgpu::Buffer,
    /// The block minima (made with the depth array) and the block pass's group.
    blocks: Option<(wgpu::Texture, wgpu::BindGroup)>,
    /// Group 0 of the lighting shaders.
    layout: wgpu::BindGroupLayout,
    group: Option<wgpu::BindGroup>,
    last: Option<Vec<Light>>,
    /// Per light of `last`: its eye (`crate::cpu::sight_eye`).
    last_eyes: Vec<Vec3>,
    /// Per light of `last`: whether the far field sees its spots (`crate::cpu::sighted`: it
    /// lights a cell up close, among the first that do; a spot among them has a cube besides
    /// its frustum, [`lights::layers`]).
    last_sighted: Vec<bool>,
    /// Whether the last update drew the spots' cubes ([`ShadowMaps::update_direct`] does not).
    last_cubes: bool,
    /// The level's cells, to tell those spots, and the level, to find the eyes (none: no spot
    /// has a cube, every eye is its light).
    up_close: Option<(crate::cpu::UpClose, crate::axis::AxisCaster)>,
    light_count: u32,
    /// Shadow layers rendered so far.
    layers_rendered: u64,
}

impl ShadowMaps {
    /// Shadow maps of `size` x `size` texels per layer for the level's triangles, a directional
    /// light's in at most [`lights::SUN_TILES_MAX`] tiles a side.
    #[cfg_attr(not(test), allow(dead_code, reason = "the runtime and radiosity pass give the tiles"))]
    pub(crate) fn new(device: &wgpu::Device, queue: &wgpu::Queue, scene: &Scene, size: u32) -> ShadowMaps {
        ShadowMaps::with_sun_tiles(device, queue, scene, size, lights::SUN_TILES_MAX)
    }

    /// The same with at most `sun_tiles_max` tiles a side for a directional light's map
    /// ([`lights::sun_tiles`]).
    pub(crate) fn with_sun_tiles(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &Scene,
        size: u32,
        sun_tiles_max: u32,
    ) -> ShadowMaps {
        let positions: Vec<[f32; 3]> =
            (0..scene.triangles.len()).flat_map(|t| scene.corners(t)).map(|p| p.to_array()).collect();
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadow vertices"),
            contents: bytemuck::cast_slice(if positions.is_empty() {
                &[[0.0f32; 3]]
            } else {
                &positions[..]
            }),
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        });
        let bounds = scene_bounds(scene);
        let max_layers = device.limits().max_texture_array_layers;
        let layout = crate::bindings::layout(device, "lights + shadow maps", SHADOW_GROUP);
        let mats_group_layout = SHADER.layout(device, 0);
        let module = SHADER.module(device);
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow"),
            bind_group_layouts: &[Some(&mats_group_layout)],
            immediate_size: 0,
        });
        // Reverse-Z: a negative slope bias pushes occluders away from the light, so a lit
        // surface at a slant does not shadow itself (the normal offset does the rest). Not for
        // a directional light: see SUN_NORMAL_OFFSET.
        let pipeline = shadow_pipeline(device, &pipeline_layout, &module, -1.5);
        let unbiased = shadow_pipeline(device, &pipeline_layout, &module, 0.0);
        let lights_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lights"),
            size: (prm::rig::MAX_LIGHTS * std::mem::size_of::<GpuLight>()) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mats_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow matrices"),
            size: (max_layers.min(MAX_LAYERS) as u64) * 64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mats_group = bind(
            device,
            "shadow layer matrices",
            &mats_group_layout,
            BINDINGS,
            &[("layer_mats", mats_buf.as_entire_binding())],
        );
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow comparison"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::GreaterEqual),
            ..Default::default()
        });
        let blocks_layout = BLOCKS.layout(device, 0);
        let blocks_pipeline = crate::gpu::compute_pipeline(
            device,
            &BLOCKS.label(),
            &BLOCKS.source(),
            "blocks_main",
            &[&blocks_layout],
        );
        let block_layers = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow block layers"),
            size: (max_layers.min(MAX_LAYERS) as u64) * 4,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ShadowMaps {
            device: device.clone(),
            queue: queue.clone(),
            pipeline,
            unbiased,
            directional: Vec::new(),
            vertex_count: positions.len() as u32,
            vertices,
            size,
            bounds,
            sun_tiles: lights::sun_tiles(bounds, sun_tiles_max),
            sun_tiles_max,
            max_layers,
            lights_buf,
            mats_buf,
            mats_group,
            texture: None,
            sampler,
            blocks_pipeline,
            blocks_layout,
            block_layers,
            blocks: None,
            layout,
            group: None,
            last: None,
            last_eyes: Vec::new(),
            last_sighted: Vec::new(),
            last_cubes: true,
            up_close: None,
            light_count: 0,
            layers_rendered: 0,
        }
    }

    /// Gives a spot that lights one of these cells up close a cube besides its frustum, at its
    /// eye in this level (`axis`: `crate::cpu::sight_eye`), from the next update on (the
    /// runtime's far field reads it: [`lights::layers`]).
    pub(crate) fn set_up_close(&mut self, cells: crate::cpu::UpClose, axis: crate::axis::AxisCaster) {
        self.up_close = Some((cells, axis));
        self.last = None;
    }

    /// Brings the maps and light buffer up to date with `lights`. Returns whether anything the
    /// lighting depends on changed (false: the last frame's light is still right).
    pub(crate) fn update(&mut self, lights: &[Light]) -> Result<bool, LightError> {
        self.update_with(lights, true)
    }

    /// [`ShadowMaps::update`] with only the maps direct light needs: no spot gets the cube the
    /// far field reads (a direct-only frame, the benchmark's baseline, does not draw it).
    pub(crate) fn update_direct(&mut self, lights: &[Light]) -> Result<bool, LightError> {
        self.update_with(lights, false)
    }

    fn update_with(&mut self, lights: &[Light], cubes: bool) -> Result<bool, LightError> {
        lights::validate(lights)?;
        if self.last.as_deref() == Some(lights) && self.last_cubes == cubes {
            return Ok(false);
        }
        self.last_cubes = cubes;
        let n = self.sun_tiles;
        let (close, eyes) = match self.up_close.as_ref().filter(|_| cubes) {
            Some((cells, axis)) => {
                let first_hit = |o: Vec3, d: Vec3, tmax: f32| axis.first_hit(o, d, tmax);
                let eyes: Vec<Vec3> =
                    lights.iter().map(|l| crate::cpu::sight_eye(l, first_hit, cells.spacing())).collect();
                (cells.lights(lights, &eyes), eyes)
            }
            None => (vec![false; lights.len()], lights.iter().map(|l| l.position).collect()),
        };
        // Only the spots whose spots the far field sees (the first CLOSE_SIGHTS lights up
        // close) read their cubes: a spot after them draws none.
        let cubes = crate::cpu::sighted(&close);
        let needed: u32 = lights.iter().zip(&cubes).map(|(l, &c)| lights::layers(l, n, c)).sum();
        if needed > self.max_layers.min(MAX_LAYERS) {
            return Err(LightError::TooManyLayers { needed, max: self.max_layers.min(MAX_LAYERS) });
        }
        let (gpu, mats) = lights::pack(lights, self.size, self.bounds, n, &cubes, &eyes);
        let realloc = self.texture.as_ref().is_none_or(|(_, n)| *n != needed.max(1));
        if realloc {
            self.allocate(needed.max(1));
        }
        // Layers to render: all after a reallocation, else those of lights whose frusta moved
        // (or that now sit at other layers).
        let mut dirty = Vec::new();
        let last_cubes = &self.last_sighted;
        let old_layers = |k: usize| {
            let o = self.last.as_ref().and_then(|v| v.get(k));
            o.map(|o| lights::layers(o, n, last_cubes.get(k).copied().unwrap_or(false)))
        };
        for (i, l) in lights.iter().enumerate() {
            let old = self.last.as_ref().and_then(|v| v.get(i));
            let old_first = self
                .last
                .as_ref()
                .map(|v| (0..i.min(v.len())).map(|k| old_layers(k).unwrap_or(0)).sum::<u32>());
            let same = !realloc
                && old.is_some_and(|o| lights::same_shadow(o, l) && old_layers(i) == Some(gpu[i].layers))
                && old_first == Some(gpu[i].first_layer);
            if !same {
                dirty.extend(gpu[i].first_layer..gpu[i].first_layer + gpu[i].layers);
            }
        }
        if !gpu.is_empty() {
            self.queue.write_buffer(&self.lights_buf, 0, bytemuck::cast_slice(&gpu));
        }
        if !mats.is_empty() {
            let m: Vec<[[f32; 4]; 4]> = mats.iter().map(|m| mat(*m)).collect();
            self.queue.write_buffer(&self.mats_buf, 0, bytemuck::cast_slice(&m));
        }
        self.directional = lights
            .iter()
            .zip(&gpu)
            .flat_map(|(l, g)| {
                std::iter::repeat_n(matches!(l.kind, LightKind::Directional), g.layers as usize)
            })
            .collect();
        self.render(&dirty);
        self.light_count = lights.len() as u32;
        self.last = Some(lights.to_vec());
        self.last_eyes = eyes;
        self.last_sighted = cubes;
        Ok(true)
    }

    /// Moves the level's triangles to where `posed` has them (the same level with its movable
    /// objects posed, `prm::Scene::moved`): the next [`ShadowMaps::update`] renders every layer
    /// again. Returns false (and changes nothing) when `posed` has another triangle count.
    #[cfg_attr(not(feature = "cpu-twin"), allow(dead_code, reason = "the radiosity pass needs the twin"))]
    pub(crate) fn set_geometry(&mut self, posed: &Scene) -> bool {
        if posed.triangles.len() as u32 * 3 != self.vertex_count {
            return false;
        }
        if self.vertex_count > 0 {
            let positions: Vec<[f32; 3]> =
                (0..posed.triangles.len()).flat_map(|t| posed.corners(t)).map(|p| p.to_array()).collect();
            self.queue.write_buffer(&self.vertices, 0, bytemuck::cast_slice(&positions));
        }
        self.bounds = scene_bounds(posed);
        self.sun_tiles = lights::sun_tiles(self.bounds, self.sun_tiles_max);
        self.last = None;
        true
    }

    /// Bytes of the shadow-map layers allocated now (with their block minima).
    pub fn bytes(&self) -> u64 {
        self.texture
            .as_ref()
            .map_or(0, |(_, layers)| *layers as u64 * crate::memory::shadow_bytes_per_layer(self.size))
    }

    fn allocate(&mut self, layers: u32) {
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d { width: self.size, height: self.size, depth_or_array_layers: layers },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            // Copied out by the test that holds the block minima to the texels.
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let blocks = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow block minima"),
            size: wgpu::Extent3d {
                width: SHADOW_BLOCKS,
                height: SHADOW_BLOCKS,
                depth_or_array_layers: layers,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: BLOCK_FORMAT,
            usage: wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let blocks_view = blocks.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        self.group = Some(bind(
            &self.device,
            "lights + shadow maps",
            &self.layout,
            SHADOW_GROUP,
            &[
                ("lights", self.lights_buf.as_entire_binding()),
                ("shadow_mats", self.mats_buf.as_entire_binding()),
                ("shadow_tex", wgpu::BindingResource::TextureView(&view)),
                ("shadow_sampler", wgpu::BindingResource::Sampler(&self.sampler)),
                ("shadow_blocks", wgpu::BindingResource::TextureView(&blocks_view)),
            ],
        ));
        let blocks_group = bind(
            &self.device,
            "shadow block minima",
            &self.blocks_layout,
            BLOCK_BINDINGS,
            &[
                ("shadow_depth", wgpu::BindingResource::TextureView(&view)),
                ("block_layers", self.block_layers.as_entire_binding()),
                ("block_minima", wgpu::BindingResource::TextureView(&blocks_view)),
            ],
        );
        self.blocks = Some((blocks, blocks_group));
        self.texture = Some((texture, layers));
    }

    fn render(&mut self, layers: &[u32]) {
        let Some((texture, _)) = &self.texture else { return };
        if layers.is_empty() {
            return;
        }
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("shadow maps") });
        for &layer in layers {
            let view = texture.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: layer,
                array_layer_count: Some(1),
                ..Default::default()
            });
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow layer"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            if self.vertex_count > 0 {
                let directional = self.directional.get(layer as usize).copied().unwrap_or(false);
                pass.set_pipeline(if directional { &self.unbiased } else { &self.pipeline });
                pass.set_bind_group(0, &self.mats_group, &[]);
                pass.set_vertex_buffer(0, self.vertices.slice(..));
                pass.draw(0..self.vertex_count, layer..layer + 1);
            }
        }
        if let Some((_, group)) = &self.blocks {
            self.queue.write_buffer(&self.block_layers, 0, bytemuck::cast_slice(layers));
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("shadow block minima"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.blocks_pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(
                (SHADOW_BLOCKS * SHADOW_BLOCKS).div_ceil(WG_LINEAR),
                layers.len() as u32,
                1,
            );
        }
        self.queue.submit([enc.finish()]);
        self.layers_rendered += layers.len() as u64;
    }

    /// The depth array and the block minima (tests).
    #[cfg(test)]
    pub(crate) fn texture_and_blocks(&self) -> Option<(&wgpu::Texture, &wgpu::Texture)> {
        Some((&self.texture.as_ref()?.0, &self.blocks.as_ref()?.0))
    }

    /// The layout of [`ShadowMaps::group`].
    pub fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// Shadow layers rendered so far (a frame whose lights did not move renders none).
    pub fn layers_rendered(&self) -> u64 {
        self.layers_rendered
    }

    /// Group 0 of the lighting shaders (lights, matrices, maps, sampler); `None` before the
    /// runtime's first update.
    pub fn group(&self) -> Option<&wgpu::BindGroup> {
        self.group.as_ref()
    }

    /// Lights in the buffer.
    pub fn light_count(&self) -> u32 {
        self.light_count
    }

    /// Bits of the lights whose spots the far field sees (lights 0-31, 32-63):
    /// [`crate::cpu::sighted`] of those that light a cell up close.
    pub fn sighted_bits(&self) -> [u32; 2] {
        let mut bits = [0u32; 2];
        for (i, &s) in self.last_sighted.iter().enumerate().take(64) {
            if s {
                bits[i / 32] |= 1 << (i % 32);
            }
        }
        bits
    }

    /// The eyes of the lights whose spots the far field sees (`crate::cpu::sight_eye`), in
    /// their slots (the order of [`ShadowMaps::sighted_bits`]' lights), as the columns of
    /// `IndirectParams::sight_eyes`; zero past the last.
    pub fn sight_eyes(&self) -> [[f32; 4]; 4] {
        let mut eyes = [[0.0; 4]; 4];
        let seen = self.last_sighted.iter().zip(&self.last_eyes).filter(|(&s, _)| s).map(|(_, e)| e);
        for (slot, e) in eyes.iter_mut().zip(seen) {
            *slot = [e.x, e.y, e.z, 1.0];
        }
        eyes
    }

    /// Texels per side of one layer.
    pub fn size(&self) -> u32 {
        self.size
    }
}
