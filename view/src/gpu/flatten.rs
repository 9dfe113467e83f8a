//! Flattening on the GPU (section 4.1; the paper notes that the CPU stages "could potentially
//! be implemented on the GPU"): the precomputed sparse operator of
//! `mlt_relight::flatten_op` uploaded once, applied per relit frame by a compute pass that
//! writes the flat coefficients straight into the buffer the splatting pass reads. Each row is
//! summed in its stored order, as on the CPU.

use mlt_format::links::LINK_DIM;
use mlt_relight::flatten_op::{FlattenOp, BLOCK_ROWS, QUANTUM};
use wgpu::util::DeviceExt;

use super::context::{Gpu, GpuError};

const WORKGROUP: u32 = 64;

/// The operator on the GPU, bound to an output buffer.
pub struct GpuFlatten {
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    hier: wgpu::Buffer,
    /// Hierarchical points read (`LINK_DIM` coefficients each).
    hier_points: usize,
    groups: (u32, u32),
    /// Bytes uploaded for the operator.
    pub bytes: u64,
}

fn storage(gpu: &Gpu, label: &str, data: &[u8]) -> wgpu::Buffer {
    // Buffers may not be empty: pad with one word.
    let padded;
    let contents = if data.is_empty() {
        padded = [0u8; 4];
        &padded[..]
    } else {
        data
    };
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE,
        })
}

impl GpuFlatten {
    /// Uploads `op`; the pass writes `LINK_DIM` floats per flat point into `output` (a
    /// storage buffer of at least that size).
    pub fn new(gpu: &Gpu, op: &FlattenOp, output: &wgpu::Buffer) -> Result<GpuFlatten, GpuError> {
        let device = &gpu.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let parts = op.parts();
        let points = op.points();
        let max_binding = device.limits().max_storage_buffer_binding_size as usize;
        let hier_points = op.hier_points();
        let largest = 4 * parts.entries.len().max(points.max(hier_points) * LINK_DIM);
        if largest > max_binding {
            return Err(GpuError::Validation(format!(
                "the flattening operator needs a {largest}-byte storage buffer; the adapter allows {max_binding}"
            )));
        }
        let offsets = storage(
            gpu,
            "flatten offsets",
            bytemuck::cast_slice(parts.row_offsets),
        );
        let packed = storage(gpu, "flatten entries", bytemuck::cast_slice(parts.entries));
        let block_offsets = storage(
            gpu,
            "flatten block offsets",
            bytemuck::cast_slice(parts.block_offsets),
        );
        let cols = storage(
            gpu,
            "flatten columns",
            bytemuck::cast_slice(parts.block_cols),
        );
        let order = storage(gpu, "flatten order", bytemuck::cast_slice(parts.order));
        let hier = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hierarchical coefficients"),
            size: (hier_points.max(1) * LINK_DIM * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let total_groups = (points as u32).div_ceil(WORKGROUP).max(1);
        let max_x = device.limits().max_compute_workgroups_per_dimension.max(1);
        let groups = (total_groups.min(max_x), total_groups.div_ceil(max_x));
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("flatten params"),
            contents: bytemuck::cast_slice(&[
                points as u32,
                groups.0 * WORKGROUP,
                BLOCK_ROWS as u32,
                QUANTUM,
            ]),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("flatten"),
            source: wgpu::ShaderSource::Wgsl(include_str!("shaders/flatten.wgsl").into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("flatten"),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        let layout = pipeline.get_bind_group_layout(0);
        let buffers = [
            &offsets,
            &packed,
            &block_offsets,
            &cols,
            &order,
            &hier,
            output,
            &params,
        ];
        let resources = buffers.map(|b| b.as_entire_binding());
        let bind_group = super::pipeline::bind_group(device, "flatten", &layout, &resources);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        let bytes = [&offsets, &packed, &block_offsets, &cols, &order, &hier]
            .iter()
            .map(|b| b.size())
            .sum();
        Ok(GpuFlatten {
            pipeline,
            bind_group,
            hier,
            hier_points,
            groups,
            bytes,
        })
    }

    /// Uploads the hierarchical coefficients `i` (`LINK_DIM` per hierarchical point) and
    /// records the pass into `encoder`.
    pub fn encode(&self, gpu: &Gpu, i: &[f32], encoder: &mut wgpu::CommandEncoder) {
        let n = self.hier_points * LINK_DIM;
        if n == 0 || i.len() < n {
            return;
        }
        gpu.queue
            .write_buffer(&self.hier, 0, bytemuck::cast_slice(&i[..n]));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("flatten"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.dispatch_workgroups(self.groups.0, self.groups.1, 1);
    }
}
