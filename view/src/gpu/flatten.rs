//! Flattening on the GPU (section 4.1; the paper notes that the CPU stages "could potentially
//! be implemented on the GPU"): the precomputed sparse operator of
//! `mlt_relight::flatten_op` uploaded once, applied per relit frame by a compute pass that
//! writes the flat coefficients straight into the buffer the splatting pass reads, after the
//! sharpening steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` when the relighter sharpens (one pass
//! each, its relaxation weight `w_k` in its parameters). Each row is summed in its stored
//! order, as on the CPU.

use mlt_format::links::LINK_DIM;
use mlt_relight::flatten_op::{step_weight, FlattenOp, SharpenOp, BLOCK_ROWS, QUANTUM};
use wgpu::util::DeviceExt;

use super::context::{Gpu, GpuError};

const WORKGROUP: u32 = 64;

/// The operator on the GPU, bound to an output buffer, and optionally the sharpening steps
/// after it.
pub struct GpuFlatten {
    pipeline: wgpu::ComputePipeline,
    /// The flattening pass, then the sharpening passes if any.
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

/// An operator's arrays on the GPU, with its dispatch grid and parameters.
struct OpBuffers {
    offsets: wgpu::Buffer,
    packed: wgpu::Buffer,
    block_offsets: wgpu::Buffer,
    cols: wgpu::Buffer,
    order: wgpu::Buffer,
    /// Rows (points) of the operator.
    points: u32,
    groups: (u32, u32),
}

impl OpBuffers {
    /// Uploads `op`.
    fn upload(gpu: &Gpu, op: &FlattenOp) -> Result<OpBuffers, GpuError> {
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
        let total_groups = (points as u32).div_ceil(WORKGROUP).max(1);
        let max_x = device.limits().max_compute_workgroups_per_dimension.max(1);
        let groups = (total_groups.min(max_x), total_groups.div_ceil(max_x));
        Ok(OpBuffers {
            offsets: storage(
                gpu,
                "flatten offsets",
                bytemuck::cast_slice(parts.row_offsets),
            ),
            packed: storage(gpu, "flatten entries", bytemuck::cast_slice(parts.entries)),
            block_offsets: storage(
                gpu,
                "flatten block offsets",
                bytemuck::cast_slice(parts.block_offsets),
            ),
            cols: storage(
                gpu,
                "flatten columns",
                bytemuck::cast_slice(parts.block_cols),
            ),
            order: storage(gpu, "flatten order", bytemuck::cast_slice(parts.order)),
            points: points as u32,
            groups,
        })
    }

    /// Bytes uploaded for the operator's arrays.
    fn bytes(&self) -> u64 {
        [
            &self.offsets,
            &self.packed,
            &self.block_offsets,
            &self.cols,
            &self.order,
        ]
        .iter()
        .map(|b| b.size())
        .sum()
    }

    /// A pass of the operator that reads `input` and writes `output`: the product, or with
    /// `sharpen` a sharpening step of that relaxation weight, which also reads the
    /// unsharpened coefficients `original`.
    fn stage(
        &self,
        gpu: &Gpu,
        pipeline: &wgpu::ComputePipeline,
        input: &wgpu::Buffer,
        original: &wgpu::Buffer,
        output: &wgpu::Buffer,
        sharpen: Option<f32>,
    ) -> Stage {
        let (mode, weight) = sharpen.map_or((0, 0), |w| (1, w.to_bits()));
        let params = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("flatten params"),
                contents: bytemuck::cast_slice(&[
                    self.points,
                    self.groups.0 * WORKGROUP,
                    BLOCK_ROWS as u32,
                    QUANTUM,
                    mode,
                    weight,
                    0,
                    0,
                ]),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let layout = pipeline.get_bind_group_layout(0);
        let buffers = [
            &self.offsets,
            &self.packed,
            &self.block_offsets,
            &self.cols,
            &self.order,
            input,
            output,
            &params,
            original,
        ];
        let resources = buffers.map(|b| b.as_entire_binding());
        let bind_group = super::pipeline::bind_group(&gpu.device, "flatten", &layout, &resources);
        Stage {
            bind_group,
            groups: self.groups,
        }
    }
}

impl GpuFlatten {
    /// Uploads `op` (and `sharpen`, the sharpening steps after it); the passes write
    /// `LINK_DIM` floats per flat point into `output` (a storage buffer of at least that
    /// size) from the hierarchical coefficients [`GpuFlatten::encode`] uploads.
    pub fn new(
        gpu: &Gpu,
        op: &FlattenOp,
        sharpen: Option<&SharpenOp>,
        output: &wgpu::Buffer,
    ) -> Result<GpuFlatten, GpuError> {
        Self::with_input(gpu, op, sharpen, None, output)
    }

    /// [`GpuFlatten::new`] reading the hierarchical coefficients from `input` (a storage
    /// buffer of `LINK_DIM` floats per hierarchical point that other passes fill; then
    /// [`GpuFlatten::encode_resident`] records the passes) instead of from an upload.
    pub fn with_input(
        gpu: &Gpu,
        op: &FlattenOp,
        sharpen: Option<&SharpenOp>,
        input: Option<&wgpu::Buffer>,
        output: &wgpu::Buffer,
    ) -> Result<GpuFlatten, GpuError> {
        let device = &gpu.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let hier_points = op.hier_points();
        let hier = match input {
            Some(b) if b.size() >= (hier_points * LINK_DIM * 4) as u64 => b.clone(),
            Some(b) => {
                return Err(GpuError::Validation(format!(
                    "the flattening input holds {} bytes, {} points need {}",
                    b.size(),
                    hier_points,
                    hier_points * LINK_DIM * 4
                )))
            }
            None => float_buffer(
                gpu,
                "hierarchical coefficients",
                hier_points * LINK_DIM,
                wgpu::BufferUsages::COPY_DST,
            ),
        };
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
        let mut bytes = if input.is_some() { 0 } else { hier.size() };
        let mut stages = Vec::new();
        let flatten = OpBuffers::upload(gpu, op)?;
        bytes += flatten.bytes();
        match sharpen {
            Some(sharpen) if sharpen.points() == op.points() => {
                // The flattened coefficients `c_0` stay in `unsharpened`; the steps before
                // the last write to two buffers in turn, the last one to `output`.
                let floats = op.points() * LINK_DIM;
                let unsharpened = float_buffer(
                    gpu,
                    "unsharpened flat coefficients",
                    floats,
                    wgpu::BufferUsages::empty(),
                );
                // At least one step (`SharpenOp::set_steps` refuses zero).
                let steps = sharpen.steps();
                let between: Vec<wgpu::Buffer> = (0..(steps - 1).min(2))
                    .map(|_| {
                        float_buffer(
                            gpu,
                            "flat coefficients between sharpening steps",
                            floats,
                            wgpu::BufferUsages::empty(),
                        )
                    })
                    .collect();
                let smoothing = OpBuffers::upload(gpu, sharpen.smoothing())?;
                stages.push(flatten.stage(gpu, &pipeline, &hier, &hier, &unsharpened, None));
                let mut input = &unsharpened;
                for step in 0..steps {
                    let out = if step + 1 == steps {
                        output
                    } else {
                        &between[step % 2]
                    };
                    stages.push(smoothing.stage(
                        gpu,
                        &pipeline,
                        input,
                        &unsharpened,
                        out,
                        Some(step_weight(step)),
                    ));
                    input = out;
                }
                bytes += smoothing.bytes()
                    + unsharpened.size()
                    + between.iter().map(wgpu::Buffer::size).sum::<u64>();
            }
            Some(sharpen) => {
                return Err(GpuError::Validation(format!(
                    "sharpening for {} flat points, flattening to {}",
                    sharpen.points(),
                    op.points()
                )))
            }
            None => stages.push(flatten.stage(gpu, &pipeline, &hier, &hier, output, None)),
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
        self.encode_resident(encoder);
    }

    /// Records the passes into `encoder` over the hierarchical coefficients already in the
    /// input buffer ([`GpuFlatten::with_input`]).
    pub fn encode_resident(&self, encoder: &mut wgpu::CommandEncoder) {
        // One compute pass per stage: each reads what the one before wrote.
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
