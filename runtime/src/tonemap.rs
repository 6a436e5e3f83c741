//! Tone mapping for display (`shaders/tonemap.wgsl`): the renderer's HDR frame, times an
//! exposure, Reinhard, sRGB-encoded, drawn into any colour target (a window's surface in
//! `prm view`). The same curve as the PNGs `prm render` writes.

use crate::bindings::{b, bind, Binding, Res, FRAGMENT};
use crate::contract::Shader;
use crate::layout::{GpuStruct, TonemapParams};

/// The pass's one bind group.
pub const BINDINGS: &[Binding] = &[
    b("params", Res::Uniform(TonemapParams::NAME), FRAGMENT),
    // The renderer's HDR frame (`Rgba32Float`, read with textureLoad).
    b("frame", Res::Texture2d, FRAGMENT),
];

pub const SHADER: Shader = Shader {
    stem: "tonemap",
    body: include_str!("../../shaders/tonemap.wgsl"),
    libraries: &[],
    groups: &[BINDINGS],
    compute: &[],
};

pub struct Tonemap {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    encode: bool,
}

impl Tonemap {
    /// A tone mapper drawing into targets of `format`.
    pub fn new(device: &wgpu::Device, format: wgpu::TextureFormat) -> Tonemap {
        let layout = SHADER.layout(device, 0);
        let module = SHADER.module(device);
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("tonemap"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("tonemap"),
            layout: Some(&pl),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(format.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let params = crate::gpu::uniform_buffer::<TonemapParams>(device, "tonemap params");
        Tonemap { pipeline, layout, params, encode: !format.is_srgb() }
    }

    /// Records the tone-mapped `frame` into `target` (same size).
    pub fn draw(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        frame: &wgpu::Texture,
        target: &wgpu::TextureView,
        exposure: f32,
    ) {
        let p = TonemapParams { exposure, encode: self.encode as u32, ..Default::default() };
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&p));
        let view = frame.create_view(&Default::default());
        let group = bind(
            device,
            "tonemap",
            &self.layout,
            BINDINGS,
            &[
                ("params", self.params.as_entire_binding()),
                ("frame", wgpu::BindingResource::TextureView(&view)),
            ],
        );
        let mut enc =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("tonemap") });
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("tonemap"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                ..Default::default()
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.draw(0..3, 0..1);
        }
        queue.submit([enc.finish()]);
    }
}
