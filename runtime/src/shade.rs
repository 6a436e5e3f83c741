//! Shading a whole frame (DESIGN.md §5 step 5; `shaders/shade.wgsl`): the level's triangles
//! from a camera, `L = emission + albedo / pi x (E_direct + E_indirect)`, into an `Rgba32Float`
//! HDR target of linear radiance (W/(m² sr)).
//!
//! Direct light comes from the runtime's shadow maps (the same visibility as the entry
//! irradiance), indirect light from its composed lightmap at the vertex-interpolated UV1,
//! bilinearly. Geometry is drawn unindexed with the triangle's geometric normal (what the
//! lightmap texels use) and per-vertex albedo: `baseColorFactor x baseColorTexture` sampled at
//! each corner, so a textured material is shaded at vertex resolution.
//!
//! The camera is reverse-Z with an infinite far plane (depth 1 at the near plane).

use glam::{Mat4, Vec3};
use prm::{Camera, Scene};
use wgpu::util::DeviceExt;

use crate::bindings::{b, bind, Binding, Res, FRAGMENT, VERTEX_FRAGMENT};
use crate::contract::{Library, Shader};
use crate::layout::{mat, GpuStruct, ShadeParams, ShadeVertex};
use crate::runtime::Runtime;
use crate::shadow::SHADOW_GROUP;

const HDR: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;

/// Group 1 of the pass (group 0 is [`SHADOW_GROUP`]).
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(ShadeParams::NAME), VERTEX_FRAGMENT),
    // The runtime's indirect lightmap (`Rgba32Float`, read with textureLoad).
    b("lightmap", Res::Texture2dArray, FRAGMENT),
];

pub const SHADER: Shader = Shader {
    stem: "shade",
    body: include_str!("../../shaders/shade.wgsl"),
    libraries: &[Library::Lights],
    groups: &[SHADOW_GROUP, BINDINGS],
    compute: &[],
};

pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::RenderPipeline,
    vertices: wgpu::Buffer,
    vertex_count: u32,
    params_buf: wgpu::Buffer,
    group: wgpu::BindGroup,
    target: wgpu::Texture,
    depth: wgpu::Texture,
    view_proj: Mat4,
    /// Atlas width, height (all pages) and pages.
    atlas: (u32, u32, u32),
}

impl Renderer {
    /// A renderer of `scene` seen from `camera` at `width` x `height`, reading `runtime`'s
    /// lightmap.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &Scene,
        runtime: &Runtime,
        camera: &Camera,
        width: u32,
        height: u32,
    ) -> Result<Renderer, crate::RuntimeError> {
        let max = device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > max || height > max {
            return Err(crate::RuntimeError::Params(format!(
                "a {width}x{height} frame does not fit this device (1 to {max} pixels a side)"
            )));
        }
        let mut vertices = shade_vertices(scene);
        let vertex_count = vertices.len() as u32;
        if vertices.is_empty() {
            vertices.push(ShadeVertex::default()); // buffers cannot be empty; nothing is drawn
        }
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shade vertices"),
            contents: bytemuck::cast_slice(&vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let params_buf = crate::gpu::uniform_buffer::<ShadeParams>(device, "shade params");
        let layout = SHADER.layout(device, 1);
        let lightmap_view = runtime.lightmap().create_view(&crate::compose::array_view());
        let group = bind(
            device,
            "shade",
            &layout,
            BINDINGS,
            &[
                ("params", params_buf.as_entire_binding()),
                ("lightmap", wgpu::BindingResource::TextureView(&lightmap_view)),
            ],
        );
        let pipeline = pipeline(device, runtime.shadows().layout(), &layout);
        let (target, depth) = frame_textures(device, width, height);
        let size = runtime.lightmap().size();
        Ok(Renderer {
            device: device.clone(),
            queue: queue.clone(),
            pipeline,
            vertices,
            vertex_count,
            params_buf,
            group,
            target,
            depth,
            view_proj: view_projection(scene, camera, width, height),
            atlas: (size.width, size.height * size.depth_or_array_layers, size.depth_or_array_layers),
        })
    }

    /// Draws the frame with the runtime's current lights and lightmap (`indirect` false: a
    /// direct-only frame, as a game without PRM would draw it). `timer` gets pass 3.
    pub fn draw(&self, runtime: &Runtime, indirect: bool, timer: Option<&crate::timer::PassTimer>) {
        let Some(shadows) = runtime.shadows().group() else { return };
        let p = ShadeParams {
            view_proj: mat(self.view_proj),
            light_count: runtime.shadows().light_count(),
            indirect_scale: if indirect { 1.0 } else { 0.0 },
            atlas_width: self.atlas.0,
            atlas_height: self.atlas.1,
            pages: self.atlas.2,
            ..Default::default()
        };
        self.queue.write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&p));
        let color = self.target.create_view(&Default::default());
        let depth = self.depth.create_view(&Default::default());
        let mut enc =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shade"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &color,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: timer.map(|t| t.render_writes(3)),
                ..Default::default()
            });
            if self.vertex_count > 0 {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, shadows, &[]);
                pass.set_bind_group(1, &self.group, &[]);
                pass.set_vertex_buffer(0, self.vertices.slice(..));
                pass.draw(0..self.vertex_count, 0..1);
            }
        }
        self.queue.submit([enc.finish()]);
    }

    /// The HDR frame (`Rgba32Float`, linear radiance).
    pub fn target(&self) -> &wgpu::Texture {
        &self.target
    }

    /// Reads the frame back (row-major RGB). Waits for the GPU.
    pub fn read_frame(&self) -> Result<Vec<Vec3>, crate::RuntimeError> {
        Ok(crate::gpu::read_rgba32f(&self.device, &self.queue, &self.target)?)
    }

    /// Waits until the GPU has finished everything submitted.
    pub fn wait(&self) {
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
    }
}

/// Unindexed vertices of every triangle: corners, geometric normal, UV1, albedo, emission.
pub fn shade_vertices(scene: &Scene) -> Vec<ShadeVertex> {
    let mut out = Vec::with_capacity(scene.triangles.len() * 3);
    for t in 0..scene.triangles.len() {
        let n = scene.face_normal(t);
        let m = scene.material(t);
        let corners = scene.corners(t);
        let uv = scene.uv1_corners(t);
        for k in 0..3 {
            let mut b = Vec3::ZERO;
            b[k] = 1.0;
            out.push(ShadeVertex {
                position: corners[k].to_array(),
                normal: n.to_array(),
                uv1: uv[k].to_array(),
                albedo: scene.albedo(t, b).to_array(),
                emissive: m.emissive.to_array(),
                double_sided: m.double_sided as u32,
            });
        }
    }
    out
}

/// The shading pipeline: group 0 the shadow maps and lights, group 1 the shading parameters
/// and the lightmap; reverse-Z depth.
fn pipeline(
    device: &wgpu::Device,
    shadows: &wgpu::BindGroupLayout,
    layout: &wgpu::BindGroupLayout,
) -> wgpu::RenderPipeline {
    let module = SHADER.module(device);
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("shade"),
        bind_group_layouts: &[Some(shadows), Some(layout)],
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("shade"),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<ShadeVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &ShadeVertex::ATTRIBUTES,
            })],
        },
        primitive: wgpu::PrimitiveState {
            front_face: wgpu::FrontFace::Ccw,
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Greater),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(HDR.into())],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// The HDR colour target and its depth buffer.
fn frame_textures(device: &wgpu::Device, width: u32, height: u32) -> (wgpu::Texture, wgpu::Texture) {
    let tex = |label, format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let target = tex(
        "hdr frame",
        HDR,
        wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let depth = tex("frame depth", wgpu::TextureFormat::Depth32Float, wgpu::TextureUsages::RENDER_ATTACHMENT);
    (target, depth)
}

/// The camera's reverse-Z infinite perspective times its view, near plane scaled to the level.
fn view_projection(scene: &Scene, camera: &Camera, width: u32, height: u32) -> glam::Mat4 {
    let (lo, hi) = scene.bounds();
    let diag = if lo.is_finite() && hi.is_finite() { (hi - lo).length().max(1e-30) } else { 1.0 };
    let proj = glam::camera::rh::proj::directx::perspective_infinite_reverse(
        camera.yfov,
        width as f32 / height as f32,
        diag * 1e-5,
    );
    proj * camera.to_world.inverse()
}
