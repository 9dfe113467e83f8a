//! The G-buffer pass: the scene's triangles, depth-tested with reversed depth (1 at the near
//! plane, cleared to 0, `Greater` passes), write per pixel the world position (`w = 1` where
//! a surface covers it), the shading normal and the albedo (texture included).

use crate::gpu::context::Gpu;
use crate::gpu::materials::{material_draws, material_layout, MaterialDraw};
use crate::gpu::mesh::GpuMesh;
use crate::gpu::pipeline::{
    begin, color_target, depth_attachment, depth_state, module, pipeline, vertex_layout,
    PipelineSpec,
};
use crate::gpu::scene_buffers::SceneBuffers;
use crate::gpu::targets::{
    Target, Targets, ALBEDO_FORMAT, DEPTH_FORMAT, NORMAL_FORMAT, POSITION_FORMAT,
};

const GBUFFER: &str = include_str!("../shaders/gbuffer.wgsl");

pub struct GBufferPass {
    pipeline: wgpu::RenderPipeline,
    draws: Vec<MaterialDraw>,
}

impl GBufferPass {
    /// Uploads the mesh's materials.
    pub fn new(gpu: &Gpu, mesh: &GpuMesh, scene: &SceneBuffers) -> GBufferPass {
        let device = &gpu.device;
        let materials = material_layout(device);
        // Position, shading normal, geometric normal, texture coordinates.
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x2
        ];
        let targets =
            [POSITION_FORMAT, NORMAL_FORMAT, ALBEDO_FORMAT].map(|f| color_target(f, None));
        let pipeline = pipeline(
            device,
            PipelineSpec {
                label: "gbuffer",
                bind_groups: vec![&scene.globals_layout, &materials],
                module: &module(device, "gbuffer", GBUFFER),
                vertex_buffers: &[Some(vertex_layout(&attributes))],
                topology: wgpu::PrimitiveTopology::TriangleList,
                depth: depth_state(DEPTH_FORMAT, true, wgpu::CompareFunction::Greater),
                targets: &targets,
            },
        );
        GBufferPass {
            pipeline,
            draws: material_draws(gpu, mesh, &materials),
        }
    }

    pub fn encode(&self, enc: &mut wgpu::CommandEncoder, t: &Targets, scene: &SceneBuffers) {
        let colors = [&t.position, &t.normal, &t.albedo].map(Target::cleared);
        let depth = depth_attachment(&t.depth.view, wgpu::LoadOp::Clear(0.0));
        let mut pass = begin(enc, "gbuffer", &colors, depth);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &scene.globals_bg, &[]);
        pass.set_vertex_buffer(0, scene.vertices.slice(..));
        for d in &self.draws {
            if d.count > 0 {
                pass.set_bind_group(1, &d.bind_group, &[]);
                pass.draw(d.first..d.first + d.count, 0..1);
            }
        }
    }
}
