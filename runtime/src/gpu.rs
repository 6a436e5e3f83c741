//! Getting a GPU: for tools and tests that do not bring their own `wgpu::Device`.
//!
//! A game creates its device itself and hands it to [`crate::Runtime`]; `prm` and the tests call
//! [`Gpu::new`], which takes the first high-performance adapter wgpu finds (on a machine without
//! a GPU, Mesa's software Vulkan driver, lavapipe). Timestamp queries are requested when the
//! adapter has them, so `prm bench` can time passes on the GPU itself.

/// A device and queue with what is known about the adapter behind them.
pub struct Gpu {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
}

#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found ({0}). Install a Vulkan driver (on Debian/Ubuntu: \
         apt-get install mesa-vulkan-drivers, a software driver) or use the CPU twin (--backend cpu)"
    )]
    NoAdapter(String),
    #[error("the GPU adapter '{adapter}' refused a device: {source}")]
    Device { adapter: String, source: wgpu::RequestDeviceError },
    #[error("reading results back from the GPU failed: {0}")]
    Readback(String),
    #[error("{what} needs {bytes} bytes in one buffer; this device binds at most {limit}")]
    TooLarge { what: &'static str, bytes: u64, limit: u64 },
}

impl Gpu {
    /// The first high-performance adapter, with timestamp queries where supported.
    pub fn new() -> Result<Gpu, GpuError> {
        Gpu::with_surface(&Gpu::instance(), None)
    }

    /// The instance [`Gpu::new`] uses: Vulkan/Metal/DX12 (GL's probing only adds noise on
    /// headless machines); `WGPU_BACKEND` still overrides.
    pub fn instance() -> wgpu::Instance {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::PRIMARY;
        wgpu::Instance::new(desc.with_env())
    }

    /// [`Gpu::new`] on `instance`, with an adapter that can present to `surface` if given.
    pub fn with_surface(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Gpu, GpuError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let wanted = wgpu::Features::TIMESTAMP_QUERY;
        let mut limits = wgpu::Limits::default();
        let have = adapter.limits();
        limits.max_texture_array_layers = have.max_texture_array_layers;
        limits.max_storage_buffer_binding_size = have.max_storage_buffer_binding_size;
        limits.max_buffer_size = have.max_buffer_size;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("prm"),
            required_features: adapter.features() & wanted,
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|source| GpuError::Device { adapter: info.name.clone(), source })?;
        Ok(Gpu { adapter, device, queue, info })
    }

    /// "name (backend, device type)", for reports.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            self.info.name, self.info.backend, self.info.device_type, self.info.driver, self.info.driver_info
        )
    }
}

/// A compute pipeline from WGSL `source`, entry point `entry`, with these bind group layouts.
pub fn compute_pipeline(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    entry: &str,
    groups: &[&wgpu::BindGroupLayout],
) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let groups: Vec<Option<&wgpu::BindGroupLayout>> = groups.iter().map(|g| Some(*g)).collect();
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &groups,
        immediate_size: 0,
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(&layout),
        module: &module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// A storage buffer holding `data`, padded to at least 256 bytes so an empty array (a level
/// whose panes are all black has no tiles) still binds as one element of any of our structs.
pub fn storage_buffer(
    device: &wgpu::Device,
    label: &str,
    data: &[u8],
    extra: wgpu::BufferUsages,
) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    let mut bytes = data.to_vec();
    bytes.resize(bytes.len().max(256).next_multiple_of(4), 0);
    crate::memory::record(label, bytes.len() as u64);
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: &bytes,
        usage: wgpu::BufferUsages::STORAGE | extra,
    })
}

/// A uniform buffer the size of `T`, written per frame (`queue.write_buffer`).
pub fn uniform_buffer<T>(device: &wgpu::Device, label: &str) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: std::mem::size_of::<T>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Copies `buffer` back to the CPU, waiting for the GPU (tests, exports, readbacks: not a
/// per-frame path).
pub fn read_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
) -> Result<Vec<u8>, GpuError> {
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: buffer.size(),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, buffer.size());
    queue.submit([enc.finish()]);
    map_read(device, &staging)
}

/// Maps a MAP_READ buffer and returns its bytes (an error if the device is lost meanwhile).
pub fn map_read(device: &wgpu::Device, staging: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
    let slice = staging.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    let bytes = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?.to_vec();
    staging.unmap();
    Ok(bytes)
}

/// Copies an RGBA32Float texture back as RGB rows (row padding removed).
pub fn read_rgba32f(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
) -> Result<Vec<glam::Vec3>, GpuError> {
    let (w, h, layers) = (texture.width(), texture.height(), texture.depth_or_array_layers());
    let row = (w * 16).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("texture readback"),
        size: (row * h) as u64 * layers as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&Default::default());
    enc.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &staging,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(h),
            },
        },
        texture.size(),
    );
    queue.submit([enc.finish()]);
    let bytes = map_read(device, &staging)?;
    // Layers follow each other, so the rows come out as the pages stack.
    let mut out = Vec::with_capacity(w as usize * h as usize * layers as usize);
    for j in 0..(h * layers) as usize {
        let r: &[[f32; 4]] =
            bytemuck::cast_slice(&bytes[j * row as usize..j * row as usize + w as usize * 16]);
        out.extend(r.iter().map(|v| glam::Vec3::new(v[0], v[1], v[2])));
    }
    Ok(out)
}
