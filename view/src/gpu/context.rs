//! The wgpu device. Headless rendering needs no display; on machines without a GPU, Mesa's
//! software Vulkan driver (lavapipe; Debian packages `mesa-vulkan-drivers` and `libvulkan1`)
//! serves.

use serde::Serialize;

/// Why the GPU could not be used.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no GPU adapter found ({0}); install a Vulkan driver (on Debian: apt-get install mesa-vulkan-drivers libvulkan1)")]
    NoAdapter(String),
    #[error("the GPU adapter {adapter} refused a device: {msg}")]
    Device { adapter: String, msg: String },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("GPU error: {0}")]
    Validation(String),
}

/// What the renderer ran on, for timings reports.
#[derive(Clone, Debug, Serialize)]
pub struct AdapterReport {
    /// Whether the device writes timestamps between commands (the relighting's stage times
    /// then come from them, not from the wall clock).
    pub timestamps: bool,
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
    pub driver_info: String,
    /// True when 32-bit float render targets can be blended, so the splat sums are
    /// accumulated in f32 (otherwise f16).
    pub float32_blend: bool,
}

/// A device and its queue.
pub struct Gpu {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub report: AdapterReport,
}

impl Gpu {
    /// A device for offscreen rendering (no window, no display).
    pub fn headless() -> Result<Gpu, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Gpu::with_instance(instance, None)
    }

    /// A device able to present to `surface` (created from `instance`).
    pub fn with_instance(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Gpu, GpuError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            apply_limit_buckets: false,
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let float32_blend = adapter
            .features()
            .contains(wgpu::Features::FLOAT32_BLENDABLE);
        let mut required_features = wgpu::Features::empty();
        if float32_blend {
            required_features |= wgpu::Features::FLOAT32_BLENDABLE;
        }
        // Timestamps between commands, for the relighting's per-stage GPU times.
        let stamps =
            wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS;
        let timestamps = adapter.features().contains(stamps);
        if timestamps {
            required_features |= stamps;
        }
        let limits = adapter.limits();
        let required_limits = wgpu::Limits {
            max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
            max_buffer_size: limits.max_buffer_size,
            max_texture_dimension_2d: limits.max_texture_dimension_2d,
            max_color_attachment_bytes_per_sample: limits
                .max_color_attachment_bytes_per_sample
                .max(48),
            ..wgpu::Limits::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("mlt-view"),
            required_features,
            required_limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            msg: e.to_string(),
        })?;
        let report = AdapterReport {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
            float32_blend,
            timestamps,
        };
        Ok(Gpu {
            instance,
            adapter,
            device,
            queue,
            report,
        })
    }

    /// True for a software rasteriser (Mesa's llvmpipe and the like), which runs on the CPU.
    pub fn is_software(&self) -> bool {
        self.adapter.get_info().device_type == wgpu::DeviceType::Cpu
    }

    /// Waits until the GPU has finished all submitted work.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Readback(e.to_string()))
    }
}
