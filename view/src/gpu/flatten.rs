//! Flattening on the GPU (section 4.1; the paper notes that the CPU stages "could potentially
//! be implemented on the GPU"): the precomputed sparse operator of
//! `mlt_relight::flatten_op` uploaded once, applied per relit frame by a compute pass that
//! writes the flat coefficients straight into the buffer the splatting pass reads, after the
//! sharpening step `c' = 2 c - W c` when the relighter sharpens. Each row is summed in its
//! stored order, as on the CPU.

use mlt_format::links::LINK_DIM;
use mlt_relight::flatten_op::{FlattenOp, SharpenOp, BLOCK_ROWS, QUANTUM};
use wgpu::util::DeviceExt;

use super::context::{Gpu, GpuError};

const WORKGROUP: u32 = 64;

/// The operator on the GPU, bound to an output buffer, and optionally the sharpening step
/// after it.
pub struct GpuFlatten {
    pipeline: wgpu::ComputePipeline,
    /// The flattening pass, then the sharpening pass if any.
    stages: Vec<Stage>,
    hier: wgpu::Buffer,
    /// Hierarchical points read (`LINK_DIM` coefficients each).
    hier_points: usize,
    /// Bytes uploaded for the operators.
    pub bytes: u64,
}

/// One dispatch of the shader: an operator's bind group and grid.
struct Stage {
    bind_group: wgpu::BindGroup,
    groups: (u32, u32),
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

/// A read-write buffer of `floats` floats (at least one).
fn float_buffer(gpu: &Gpu, label: &str, floats: usize, usage: wgpu::BufferUsages) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (floats.max(1) * 4) as u64,
        usage: wgpu::BufferUsages::STORAGE | usage,
        mapped_at_creation: false,
    })
}

/// Uploads `op` and binds it to read `input` and write `output`; `mode` 1 makes it the
/// sharpening step. Returns the stage and the bytes uploaded.
fn stage(
    gpu: &Gpu,
    pipeline: &wgpu::ComputePipeline,
    op: &FlattenOp,
    input: &wgpu::Buffer,
    output: &wgpu::Buffer,
    mode: u32,
) -> Result<(Stage, u64), GpuError> {
    let device = &gpu.device;
    let parts = op.parts();
    let points = op.points();
    let max_binding = device.limits().max_storage_buffer_binding_size as usize;
    let largest = 4 * parts
        .entries
        .len()
        .max(points.max(op.hier_points()) * LINK_DIM);
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
            mode,
            0,
            0,
            0,
        ]),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let layout = pipeline.get_bind_group_layout(0);
    let buffers = [
        &offsets,
        &packed,
        &block_offsets,
        &cols,
        &order,
        input,
        output,
        &params,
    ];
    let resources = buffers.map(|b| b.as_entire_binding());
    let bind_group = super::pipeline::bind_group(device, "flatten", &layout, &resources);
    let bytes = [&offsets, &packed, &block_offsets, &cols, &order]
        .iter()
        .map(|b| b.size())
        .sum();
    Ok((Stage { bind_group, groups }, bytes))
}

impl GpuFlatten {
    /// Uploads `op` (and `sharpen`, the sharpening step after it); the passes write
    /// `LINK_DIM` floats per flat point into `output` (a storage buffer of at least that
    /// size).
    pub fn new(
        gpu: &Gpu,
        op: &FlattenOp,
        sharpen: Option<&SharpenOp>,
        output: &wgpu::Buffer,
    ) -> Result<GpuFlatten, GpuError> {
        let device = &gpu.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let hier_points = op.hier_points();
        let hier = float_buffer(
            gpu,
            "hierarchical coefficients",
            hier_points * LINK_DIM,
            wgpu::BufferUsages::COPY_DST,
        );
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
        let mut bytes = hier.size();
        let mut stages = Vec::with_capacity(2);
        match sharpen {
            Some(sharpen) if sharpen.points() == op.points() => {
                let unsharpened = float_buffer(
                    gpu,
                    "unsharpened flat coefficients",
                    op.points() * LINK_DIM,
                    wgpu::BufferUsages::empty(),
                );
                let (first, b0) = stage(gpu, &pipeline, op, &hier, &unsharpened, 0)?;
                let (second, b1) =
                    stage(gpu, &pipeline, sharpen.smoothing(), &unsharpened, output, 1)?;
                bytes += b0 + b1 + unsharpened.size();
                stages.extend([first, second]);
            }
            Some(sharpen) => {
                return Err(GpuError::Validation(format!(
                    "sharpening for {} flat points, flattening to {}",
                    sharpen.points(),
                    op.points()
                )))
            }
            None => {
                let (first, b0) = stage(gpu, &pipeline, op, &hier, output, 0)?;
                bytes += b0;
                stages.push(first);
            }
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        Ok(GpuFlatten {
            pipeline,
            stages,
            hier,
            hier_points,
            bytes,
        })
    }

    /// Uploads the hierarchical coefficients `i` (`LINK_DIM` per hierarchical point) and
    /// records the passes into `encoder`.
    pub fn encode(&self, gpu: &Gpu, i: &[f32], encoder: &mut wgpu::CommandEncoder) {
        let n = self.hier_points * LINK_DIM;
        if n == 0 || i.len() < n {
            return;
        }
        gpu.queue
            .write_buffer(&self.hier, 0, bytemuck::cast_slice(&i[..n]));
        // One compute pass per stage: the second reads what the first wrote.
        for stage in &self.stages {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("flatten"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &stage.bind_group, &[]);
            pass.dispatch_workgroups(stage.groups.0, stage.groups.1, 1);
        }
    }
}
