//! GPU pass timing with timestamp queries, for `prm bench` (absent where the adapter lacks
//! `TIMESTAMP_QUERY`; callers then fall back to wall-clock time around a waited submission).

/// Timestamps around up to [`PassTimer::PASSES`] passes of one submission.
pub struct PassTimer {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    staging: wgpu::Buffer,
    period_ns: f32,
}

impl PassTimer {
    pub const PASSES: u32 = 8;

    /// A timer, or `None` when the device cannot write timestamps.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Option<PassTimer> {
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let n = 2 * Self::PASSES;
        let set = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("pass timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: n,
        });
        let size = n as u64 * 8;
        let resolve = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamps"),
            size,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamps readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Some(PassTimer { set, resolve, staging, period_ns: queue.get_timestamp_period() })
    }

    /// Timestamp writes for pass `i` (0-based).
    pub fn writes(&self, i: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(2 * i),
            end_of_pass_write_index: Some(2 * i + 1),
        }
    }

    /// Timestamp writes for a render pass `i`.
    pub fn render_writes(&self, i: u32) -> wgpu::RenderPassTimestampWrites<'_> {
        wgpu::RenderPassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(2 * i),
            end_of_pass_write_index: Some(2 * i + 1),
        }
    }

    /// Durations of passes 0..PASSES in milliseconds, from the passes submitted since the
    /// last read (0 for passes not written). Waits for the GPU.
    pub fn read_ms(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<f64>, crate::gpu::GpuError> {
        let mut enc = device.create_command_encoder(&Default::default());
        enc.resolve_query_set(&self.set, 0..2 * Self::PASSES, &self.resolve, 0);
        enc.copy_buffer_to_buffer(&self.resolve, 0, &self.staging, 0, self.resolve.size());
        queue.submit([enc.finish()]);
        let bytes = crate::gpu::map_read(device, &self.staging)?;
        let t: &[u64] = bytemuck::cast_slice(&bytes);
        Ok((0..Self::PASSES as usize)
            .map(|i| t[2 * i + 1].saturating_sub(t[2 * i]) as f64 * self.period_ns as f64 * 1e-6)
            .collect())
    }
}
