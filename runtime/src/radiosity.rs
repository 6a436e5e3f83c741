//! Hierarchical radiosity over precomputed visibility on the GPU (`shaders/radiosity.wgsl`),
//! twin of [`crate::cpu::radiosity`] (its module doc says what is computed; the shader follows
//! it step for step, and a test holds the two together).
//!
//! Per frame: the objects' poses and the texels' direct irradiance are uploaded, then per
//! bounce four dispatches (`flux_main` per node: the pull; `gather_main` per texel: refine and
//! gather; `got_main` per node: the power gathered; `next_main` per texel: conserve power, add
//! to the total, reflect), one submit per bounce since the uniform changes; then, with the tail on, one more pull and `tail_main`. The visibility's tables are
//! packed once into one `u32` buffer (`vdata`, [`pack_visibility`]): a stage has few storage
//! bindings.
//!
//! The direct light the radiosity starts from comes from either end:
//! [`RadiosityPass::light_texels`] renders shadow maps of the posed level (`crate::shadow`,
//! the PRM runtime's) and lights each texel from them (`shaders/texel_direct.wgsl`: the mean
//! over the texel's shape, as the CPU twin's ray-traced
//! [`crate::cpu::radiosity::sender_direct`]), so a frame never leaves the GPU until its
//! lightmap is read; [`RadiosityPass::indirect`] takes it from the CPU instead. Either way it
//! lands in the total's section of `values`, and `seed_main` makes it the first exitance.
//!
//! The pass needs the texel hierarchy, built from the level's texel set, so it comes with the
//! `cpu-twin` feature for now; the shaders and their tables are always built (the contract
//! test checks them).

use crate::bindings::{b, Binding, Res, COMPUTE};
use crate::contract::{Compute, Library, Shader, LINEAR};
use crate::shadow::SHADOW_GROUP;

/// Texel sizes within which a single texel sends by the exact form factor of its atlas square.
pub const NEAR: f32 = 3.0;

pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform("RadParams"), COMPUTE),
    b("nodes", Res::Read("array<RadNode>"), COMPUTE),
    b("texels", Res::Read("array<RadTexel>"), COMPUTE),
    b("leaves", Res::Read("array<u32>"), COMPUTE),
    b("objects", Res::Read("array<RadObject>"), COMPUTE),
    // The visibility's tables, packed ([`pack_visibility`]).
    b("vdata", Res::Read("array<u32>"), COMPUTE),
    // Per texel, its shape's vertices (xyz, 7 of them; w: the direct light's part from the
    // centroid to that vertex's edge, `SenderLight::parts`) and their number (the 8th's x).
    b("shapes", Res::Read("array<vec4f>"), COMPUTE),
    // Exitance | gathered | total, a section of `texels` each.
    b("values", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Node fluxes, two halves, then the nodes' gathered power.
    b("flux", Res::ReadWrite("array<vec4f>"), COMPUTE),
];

/// The largest factor power conservation scales a pass by.
pub const MAX_CONSERVE: f32 = 1.25;

pub const SHADER: Shader = Shader {
    stem: "radiosity",
    body: include_str!("../../shaders/radiosity.wgsl"),
    libraries: &[Library::FormFactor],
    groups: &[BINDINGS],
    compute: &[
        Compute { entry: "flux_main", workgroup: LINEAR },
        Compute { entry: "gather_main", workgroup: LINEAR },
        Compute { entry: "got_main", workgroup: LINEAR },
        Compute { entry: "next_main", workgroup: LINEAR },
        Compute { entry: "tail_main", workgroup: LINEAR },
        Compute { entry: "seed_main", workgroup: LINEAR },
    ],
};

/// Group 1 of `shaders/texel_direct.wgsl` (group 0 is the shadow maps' `SHADOW_GROUP`).
pub const DIRECT_BINDINGS: &[Binding] = &[
    b("params", Res::Uniform("DirectParams"), COMPUTE),
    b("texels", Res::Read("array<RadTexel>"), COMPUTE),
    b("objects", Res::Read("array<RadObject>"), COMPUTE),
    // Written: each part's share of the direct light, the w of its shape vertex.
    b("shapes", Res::ReadWrite("array<vec4f>"), COMPUTE),
    // Direct irradiance per texel (W/m², w unused).
    b("direct", Res::ReadWrite("array<vec4f>"), COMPUTE),
];

/// Direct light at the texels from the shadow maps (module doc).
pub const DIRECT: Shader = Shader {
    stem: "texel_direct",
    body: include_str!("../../shaders/texel_direct.wgsl"),
    libraries: &[Library::Lights],
    groups: &[SHADOW_GROUP, DIRECT_BINDINGS],
    compute: &[Compute { entry: "texel_direct_main", workgroup: LINEAR }],
};

#[cfg(feature = "cpu-twin")]
pub use pass::{pack_visibility, RadiosityPass, TexelLightError};

#[cfg(feature = "cpu-twin")]
mod pass {
    use glam::{Mat4, Vec3};
    use prm::visibility::{Poses, Visibility};
    use prm::TexelSet;

    use super::{BINDINGS, DIRECT, DIRECT_BINDINGS, SHADER};
    use crate::bindings::bind;
    use crate::contract::WG_LINEAR;
    use crate::cpu::radiosity::{Hierarchy, RadiosityParams, SenderLight};
    use crate::gpu::{self, GpuError};
    use crate::layout::{mat, DirectParams, RadNode, RadObject, RadParams, RadTexel};
    use crate::lights::LightError;
    use crate::shadow::ShadowMaps;

    /// Where each object's tables start in the packed words.
    #[derive(Clone, Copy, Debug, Default)]
    struct Bases {
        origins: u32,
        offsets: u32,
        starts: u32,
        depths: u32,
        csm: u32,
    }

    /// The visibility's tables as one `u32` array (origins as f32 bits, run offsets, run
    /// starts, depth codes two a word, occluder maps' entry/exit pairs two a word), with each
    /// object's offsets into it.
    pub fn pack_visibility(vis: &Visibility) -> (Vec<u32>, Vec<[u32; 5]>) {
        let mut words = Vec::new();
        let mut bases = Vec::new();
        for o in &vis.objects {
            let c = &o.cssm;
            let mut base = Bases { origins: words.len() as u32, ..Default::default() };
            words.extend(c.origins.iter().flat_map(|v| v.to_array().map(f32::to_bits)));
            base.offsets = words.len() as u32;
            words.extend_from_slice(&c.offsets);
            base.starts = words.len() as u32;
            words.extend_from_slice(&c.run_start);
            base.depths = words.len() as u32;
            words.extend(c.run_depth.chunks(2).map(|p| p[0] as u32 | (*p.get(1).unwrap_or(&0) as u32) << 16));
            base.csm = match &o.occluder {
                Some(m) => {
                    let at = words.len() as u32;
                    let pairs: Vec<u32> =
                        m.depths.iter().map(|[e, x]| *e as u32 | (*x as u32) << 8).collect();
                    words.extend(pairs.chunks(2).map(|p| p[0] | p.get(1).unwrap_or(&0) << 16));
                    at
                }
                None => u32::MAX,
            };
            bases.push([base.origins, base.offsets, base.starts, base.depths, base.csm]);
        }
        (words, bases)
    }

    /// Why [`RadiosityPass::light_texels`] could not light the texels, or
    /// [`RadiosityPass::indirect`] take the direct light it was given.
    #[derive(Debug, thiserror::Error)]
    pub enum TexelLightError {
        #[error(transparent)]
        Lights(#[from] LightError),
        #[error("the posed level has {posed} triangles, the pass was built for {built}")]
        Geometry { posed: usize, built: usize },
        #[error(transparent)]
        Gpu(#[from] GpuError),
        #[error("direct light for {given} texels, the pass has {texels}")]
        Texels { given: usize, texels: usize },
        #[error("shadow maps of {size} texels: between 16 and {max}")]
        ShadowSize { size: u32, max: u32 },
    }

    /// Shadow maps of the posed level and the pass lighting the texels from them.
    struct TexelLight {
        shadows: ShadowMaps,
        pipeline: wgpu::ComputePipeline,
        group: wgpu::BindGroup,
        params: wgpu::Buffer,
    }

    /// The GPU radiosity of one level (module doc).
    pub struct RadiosityPass {
        flux: wgpu::ComputePipeline,
        gather: wgpu::ComputePipeline,
        got: wgpu::ComputePipeline,
        next: wgpu::ComputePipeline,
        tail: wgpu::ComputePipeline,
        seed: wgpu::ComputePipeline,
        group: wgpu::BindGroup,
        params: wgpu::Buffer,
        objects: wgpu::Buffer,
        values: wgpu::Buffer,
        texel_buf: wgpu::Buffer,
        shape_buf: wgpu::Buffer,
        /// The shapes' rows as uploaded (their w rewritten from a CPU [`SenderLight`]).
        shape_rows: Vec<[f32; 4]>,
        /// Direct irradiance per texel, `vec4f` each: from [`RadiosityPass::light_texels`] or
        /// the CPU.
        direct: wgpu::Buffer,
        light: Option<TexelLight>,
        /// The level's triangles (a posed level must have as many).
        triangles: usize,
        object_rows: Vec<RadObject>,
        texels: u32,
        nodes: u32,
        total_area: f32,
    }

    impl RadiosityPass {
        pub fn new(
            device: &wgpu::Device,
            scene: &prm::Scene,
            texels: &TexelSet,
            hierarchy: &Hierarchy,
            vis: &Visibility,
        ) -> Result<RadiosityPass, GpuError> {
            let nodes: Vec<RadNode> = hierarchy
                .nodes
                .iter()
                .map(|n| RadNode {
                    centre: n.centre.to_array(),
                    radius: n.radius,
                    normal: n.normal.to_array(),
                    area: n.area,
                    object: n.object,
                    first: n.first,
                    end: n.end,
                    skip: n.skip,
                })
                .collect();
            let rows: Vec<RadTexel> = texels
                .texels
                .iter()
                .enumerate()
                .map(|(k, t)| RadTexel {
                    position: t.position.to_array(),
                    area: hierarchy.area[k],
                    normal: t.normal.to_array(),
                    object: scene.object(t.triangle as usize),
                    albedo: hierarchy.albedo[k].to_array(),
                    seq: vis.slots[k].1,
                    escape: vis.escape[k],
                    shape_area: hierarchy.shapes[k].area,
                    ..Default::default()
                })
                .collect();
            let (words, bases) = pack_visibility(vis);
            let shapes: Vec<[f32; 4]> = hierarchy
                .shapes
                .iter()
                .flat_map(|sh| {
                    // w: the direct light's parts, even until a frame says otherwise.
                    let mut v = sh.points.map(|p| [p.x, p.y, p.z, 1.0]).to_vec();
                    v.push([sh.len as f32, 0.0, 0.0, 0.0]);
                    v
                })
                .collect();
            let object_rows: Vec<RadObject> = vis
                .objects
                .iter()
                .zip(&bases)
                .enumerate()
                .map(|(o, (ov, b))| {
                    let (centre, radius, dirs, res) = ov
                        .occluder
                        .as_ref()
                        .map_or((Vec3::ZERO, 1.0, 0, 0), |m| (m.centre, m.radius, m.dirs, m.res));
                    RadObject {
                        to_world: mat(Mat4::IDENTITY),
                        to_rest: mat(Mat4::IDENTITY),
                        csm_centre: centre.to_array(),
                        csm_radius: radius,
                        origins: b[0],
                        offsets: b[1],
                        starts: b[2],
                        depths: b[3],
                        res: ov.cssm.res,
                        far: ov.cssm.far,
                        csm: b[4],
                        csm_dirs: dirs,
                        csm_res: res,
                        root: hierarchy
                            .nodes
                            .iter()
                            .position(|n| n.object == o as u32)
                            .map_or(u32::MAX, |k| k as u32),
                        ..Default::default()
                    }
                })
                .collect();
            let limit = device.limits().max_storage_buffer_binding_size;
            for (what, bytes) in [
                ("the packed visibility", words.len() as u64 * 4),
                ("the texel shapes", shapes.len() as u64 * 16),
                ("the radiosity's texel values", rows.len() as u64 * 3 * 16),
                ("the radiosity's node fluxes", nodes.len() as u64 * 3 * 16),
            ] {
                if bytes > limit {
                    return Err(GpuError::TooLarge { what, bytes, limit });
                }
            }
            let none = wgpu::BufferUsages::empty();
            let copy = wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC;
            let node_buf = gpu::storage_buffer(device, "radiosity nodes", bytemuck::cast_slice(&nodes), none);
            let texel_buf =
                gpu::storage_buffer(device, "radiosity texels", bytemuck::cast_slice(&rows), none);
            let leaves = gpu::storage_buffer(
                device,
                "radiosity leaves",
                bytemuck::cast_slice(&hierarchy.leaves),
                none,
            );
            let objects =
                gpu::storage_buffer(device, "radiosity objects", bytemuck::cast_slice(&object_rows), copy);
            let vdata = gpu::storage_buffer(device, "visibility", bytemuck::cast_slice(&words), none);
            let shape_buf =
                gpu::storage_buffer(device, "radiosity shapes", bytemuck::cast_slice(&shapes), copy);
            let values =
                gpu::storage_buffer(device, "radiosity values", &vec![0u8; rows.len() * 3 * 16], copy);
            let flux = gpu::storage_buffer(device, "radiosity flux", &vec![0u8; nodes.len() * 3 * 16], none);
            let direct =
                gpu::storage_buffer(device, "texels' direct light", &vec![0u8; rows.len().max(1) * 16], copy);
            let params = gpu::uniform_buffer::<RadParams>(device, "radiosity params");
            let layout = SHADER.layout(device, 0);
            let group = bind(
                device,
                "radiosity",
                &layout,
                BINDINGS,
                &[
                    ("params", params.as_entire_binding()),
                    ("nodes", node_buf.as_entire_binding()),
                    ("texels", texel_buf.as_entire_binding()),
                    ("leaves", leaves.as_entire_binding()),
                    ("objects", objects.as_entire_binding()),
                    ("vdata", vdata.as_entire_binding()),
                    ("shapes", shape_buf.as_entire_binding()),
                    ("values", values.as_entire_binding()),
                    ("flux", flux.as_entire_binding()),
                ],
            );
            let source = SHADER.source();
            let pipeline =
                |entry| gpu::compute_pipeline(device, "radiosity.wgsl", &source, entry, &[&layout]);
            Ok(RadiosityPass {
                flux: pipeline("flux_main"),
                gather: pipeline("gather_main"),
                got: pipeline("got_main"),
                next: pipeline("next_main"),
                tail: pipeline("tail_main"),
                seed: pipeline("seed_main"),
                group,
                params,
                objects,
                values,
                texel_buf,
                shape_buf,
                shape_rows: shapes,
                direct,
                light: None,
                triangles: scene.triangles.len(),
                object_rows,
                texels: rows.len() as u32,
                nodes: nodes.len() as u32,
                total_area: hierarchy.area.iter().sum(),
            })
        }

        /// The indirect irradiance at every texel under `poses` from the direct light `light`
        /// (e.g. the CPU twin's), read back.
        pub fn indirect(
            &mut self,
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            poses: &Poses,
            light: &SenderLight,
            params: &RadiosityParams,
        ) -> Result<Vec<Vec3>, TexelLightError> {
            let texels = self.texels as usize;
            if light.mean.len() != texels || light.parts.len() != texels {
                return Err(TexelLightError::Texels {
                    given: light.mean.len().min(light.parts.len()),
                    texels,
                });
            }
            self.set_poses(queue, poses);
            let rows: Vec<[f32; 4]> = light.mean.iter().map(|e| [e.x, e.y, e.z, 0.0]).collect();
            queue.write_buffer(&self.direct, 0, bytemuck::cast_slice(&rows));
            for (k, parts) in light.parts.iter().enumerate() {
                for (i, &part) in parts.iter().enumerate() {
                    self.shape_rows[8 * k + i][3] = part;
                }
            }
            queue.write_buffer(&self.shape_buf, 0, bytemuck::cast_slice(&self.shape_rows));
            Ok(self.indirect_lit(device, queue, params)?)
        }

        fn set_poses(&mut self, queue: &wgpu::Queue, poses: &Poses) {
            for (row, (w, r)) in self.object_rows.iter_mut().zip(poses.to_world.iter().zip(&poses.to_rest)) {
                row.to_world = mat(*w);
                row.to_rest = mat(*r);
            }
            queue.write_buffer(&self.objects, 0, bytemuck::cast_slice(&self.object_rows));
        }

        /// Lights the texels under `poses` with `lights` from shadow maps of `posed` (the
        /// level with its objects where `poses` put them, `prm::Scene::moved`), `shadow_size`
        /// texels a side: the direct light [`RadiosityPass::indirect_lit`] starts from.
        pub fn light_texels(
            &mut self,
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            posed: &prm::Scene,
            poses: &Poses,
            lights: &[prm::Light],
            shadow_size: u32,
        ) -> Result<(), TexelLightError> {
            let max = device.limits().max_texture_dimension_2d;
            if !(16..=max).contains(&shadow_size) {
                return Err(TexelLightError::ShadowSize { size: shadow_size, max });
            }
            if posed.triangles.len() != self.triangles {
                return Err(TexelLightError::Geometry {
                    posed: posed.triangles.len(),
                    built: self.triangles,
                });
            }
            crate::lights::validate(lights)?;
            self.set_poses(queue, poses);
            let light = match self.light.take() {
                Some(l) if l.shadows.size() == shadow_size => self.light.insert(l),
                _ => {
                    let made = self.texel_light(device, queue, posed, shadow_size);
                    self.light.insert(made)
                }
            };
            let moved = light.shadows.set_geometry(posed);
            debug_assert!(moved, "the triangle count is checked above");
            light.shadows.update(lights)?;
            let p =
                DirectParams { texels: self.texels, light_count: lights.len() as u32, ..Default::default() };
            queue.write_buffer(&light.params, 0, bytemuck::bytes_of(&p));
            let mut enc = device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&light.pipeline);
                pass.set_bind_group(0, light.shadows.group().expect("update allocates the maps"), &[]);
                pass.set_bind_group(1, &light.group, &[]);
                pass.dispatch_workgroups(self.texels.div_ceil(WG_LINEAR), 1, 1);
            }
            queue.submit([enc.finish()]);
            Ok(())
        }

        fn texel_light(
            &self,
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            posed: &prm::Scene,
            size: u32,
        ) -> TexelLight {
            let shadows =
                ShadowMaps::with_sun_tiles(device, queue, posed, size, crate::lights::SUN_TILES_MAX);
            let params = gpu::uniform_buffer::<DirectParams>(device, "texel direct params");
            let layout = DIRECT.layout(device, 1);
            let group = bind(
                device,
                "texel direct",
                &layout,
                DIRECT_BINDINGS,
                &[
                    ("params", params.as_entire_binding()),
                    ("texels", self.texel_buf.as_entire_binding()),
                    ("objects", self.objects.as_entire_binding()),
                    ("shapes", self.shape_buf.as_entire_binding()),
                    ("direct", self.direct.as_entire_binding()),
                ],
            );
            let pipeline = gpu::compute_pipeline(
                device,
                "texel_direct.wgsl",
                &DIRECT.source(),
                "texel_direct_main",
                &[shadows.layout(), &layout],
            );
            TexelLight { shadows, pipeline, group, params }
        }

        /// The texels' direct light as the pass holds it now, read back: what
        /// [`RadiosityPass::light_texels`] or [`RadiosityPass::indirect`] put there.
        pub fn direct(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<SenderLight, GpuError> {
            let bytes = gpu::read_buffer(device, queue, &self.direct)?;
            let all: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
            let mean = all[..self.texels as usize].iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect();
            let bytes = gpu::read_buffer(device, queue, &self.shape_buf)?;
            let rows: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
            let parts =
                rows.chunks(8).take(self.texels as usize).map(|r| std::array::from_fn(|i| r[i][3])).collect();
            Ok(SenderLight { mean, parts })
        }

        /// The indirect irradiance at every texel from the direct light the pass holds
        /// ([`RadiosityPass::light_texels`]), read back.
        pub fn indirect_lit(
            &mut self,
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            params: &RadiosityParams,
        ) -> Result<Vec<Vec3>, GpuError> {
            let t = self.texels as usize;
            let texel_groups = self.texels.div_ceil(WG_LINEAR);
            {
                let mut enc = device.create_command_encoder(&Default::default());
                enc.copy_buffer_to_buffer(&self.direct, 0, &self.values, 2 * t as u64 * 16, t as u64 * 16);
                queue.submit([enc.finish()]);
            }
            let node_groups = self.nodes.div_ceil(WG_LINEAR);
            let run = |half: u32, jitter: bool, first: bool, steps: &[(&wgpu::ComputePipeline, u32)]| {
                let p = RadParams {
                    texels: self.texels,
                    nodes: self.nodes,
                    objects: self.object_rows.len() as u32,
                    jitter: jitter as u32,
                    threshold: params.threshold,
                    flux_half: half,
                    total_area: self.total_area,
                    conserve: params.conserve as u32,
                    parts: first as u32,
                    ..Default::default()
                };
                queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&p));
                let mut enc = device.create_command_encoder(&Default::default());
                {
                    let mut pass = enc.begin_compute_pass(&Default::default());
                    pass.set_bind_group(0, &self.group, &[]);
                    for (pipeline, groups) in steps {
                        pass.set_pipeline(pipeline);
                        pass.dispatch_workgroups(*groups, 1, 1);
                    }
                }
                queue.submit([enc.finish()]);
            };
            if params.bounces == 0 {
                // Nothing gathered: the seed only clears the total.
                run(0, false, false, &[(&self.seed, texel_groups)]);
            }
            for pass in 0..params.bounces {
                let jitter = params.jitter && pass + 1 == params.bounces;
                let steps = [
                    (&self.seed, texel_groups),
                    (&self.flux, node_groups),
                    (&self.gather, texel_groups),
                    (&self.got, node_groups),
                    (&self.next, texel_groups),
                ];
                run(pass % 2, jitter, pass == 0, &steps[if pass == 0 { 0 } else { 1 }..]);
            }
            if params.tail && params.bounces > 1 {
                run(
                    params.bounces % 2,
                    false,
                    false,
                    &[(&self.flux, node_groups), (&self.tail, texel_groups)],
                );
            }
            let bytes = gpu::read_buffer(device, queue, &self.values)?;
            let all: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
            Ok(all[2 * t..3 * t].iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect())
        }
    }
}
