//! The basis-points overlay of the points view: the points of one level, each a small disk
//! coloured by the luminance of its flat coefficient's irradiance on a log scale, drawn over
//! the displayed image and depth-tested against the G-buffer's depth without writing it.

use bytemuck::{Pod, Zeroable};

use crate::gpu::pipeline::{
    begin, bind_group, color_target, depth_attachment, depth_state, layout, module, pipeline,
    uniform_buffer, PerFormat, PipelineSpec, Slot, VS_FS,
};
use crate::gpu::scene_buffers::SceneBuffers;
use crate::gpu::targets::{Targets, DEPTH_FORMAT};

use super::display::{encode_srgb, Output};

const POINTS: &str = include_str!("../shaders/points.wgsl");
/// A point's disk radius as a fraction of its support radius `r_j`.
const POINT_SIZE: f32 = 0.08;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PointsUniform {
    params: [f32; 4],
}

pub struct PointsPass {
    layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipelines: PerFormat,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl PointsPass {
    pub fn new(device: &wgpu::Device, scene: &SceneBuffers) -> PointsPass {
        // Globals, points, coefficients, the parameters.
        let slots = [
            Slot::Uniform(VS_FS),
            Slot::Storage(wgpu::ShaderStages::VERTEX),
            Slot::Storage(wgpu::ShaderStages::VERTEX),
            Slot::Uniform(VS_FS),
        ];
        let layout = layout(device, "points", &slots);
        let size = std::mem::size_of::<PointsUniform>() as u64;
        let uniform = uniform_buffer(device, "points", size);
        let buffers = [&scene.globals, &scene.points, &scene.coefficients, &uniform];
        let resources: Vec<_> = buffers.iter().map(|b| b.as_entire_binding()).collect();
        let bind_group = bind_group(device, "points", &layout, &resources);
        PointsPass {
            layout,
            module: module(device, "points", POINTS),
            pipelines: PerFormat::default(),
            uniform,
            bind_group,
        }
    }

    /// Draws the points of `level`, coloured on a log scale up to `flat_max_luminance`, into
    /// a target of `format`.
    pub fn set(
        &self,
        queue: &wgpu::Queue,
        level: usize,
        flat_max_luminance: f32,
        format: wgpu::TextureFormat,
    ) {
        let pu = PointsUniform {
            params: [
                level as f32,
                POINT_SIZE,
                flat_max_luminance.max(1e-30).log10(),
                encode_srgb(format),
            ],
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&pu));
    }

    /// Draws the chosen level's points among the first `count` over `out`, depth-tested
    /// against `t`'s depth.
    pub fn encode(
        &mut self,
        device: &wgpu::Device,
        enc: &mut wgpu::CommandEncoder,
        out: Output,
        t: &Targets,
        count: usize,
    ) {
        let (layout, module) = (&self.layout, &self.module);
        let pipeline = self.pipelines.get(out.format, |format| {
            let targets = [color_target(format, None)];
            let strip = wgpu::PrimitiveTopology::TriangleStrip;
            let spec = PipelineSpec::procedural("points", layout, module, strip, &targets);
            let depth = depth_state(DEPTH_FORMAT, false, wgpu::CompareFunction::GreaterEqual);
            pipeline(device, PipelineSpec { depth, ..spec })
        });
        let over = Some(wgpu::RenderPassColorAttachment {
            view: out.view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Load,
                store: wgpu::StoreOp::Store,
            },
        });
        let depth = depth_attachment(&t.depth.view, wgpu::LoadOp::Load);
        let mut pass = begin(enc, "points", &[over], depth);
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.draw(0..4, 0..count as u32);
    }
}
