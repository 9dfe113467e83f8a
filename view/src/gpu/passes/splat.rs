//! The splatting pass: every flat basis function that survives frustum culling (one level, on
//! the points the solution needs, each with a radius from the local density of the flat
//! points: `mlt_format::flat_basis`) is drawn as a footprint bounding its support sphere;
//! covered pixels accumulate, with additive blending, `w_j` (Eq. 8) and `w_j (n . c_j)` per
//! colour (`n` the pixel's normal: dotted here, as the resolve pass would, so that each
//! fragment blends 5 floats, not 10), and `w_j level_j` for the level view. The
//! footprint lies at the depth of the support sphere's nearest point and is depth-tested
//! (without writing) against the G-buffer's depth: where the visible surface is in front of
//! the whole support, the pixel is rejected before the weight is evaluated. A function whose
//! support is clipped at occluders (`mlt_format::support_clip`) skips the pixels its planes
//! cut, as the CPU's evaluation of the flat basis does.

use wgpu::ShaderStages as Stages;

use crate::gpu::pipeline::{
    additive, begin, color_target, depth_attachment, depth_state, module, pipeline, PipelineSpec,
    Slot, TargetBinding, VS_FS,
};
use crate::gpu::scene_buffers::SceneBuffers;
use crate::gpu::targets::{level_format, Target, Targets, DEPTH_FORMAT};

const SPLAT: &str = include_str!("../shaders/splat.wgsl");

pub struct SplatPass {
    pipeline: wgpu::RenderPipeline,
    binding: TargetBinding,
}

impl SplatPass {
    /// Sums accumulated in `acc_format`.
    pub fn new(device: &wgpu::Device, acc_format: wgpu::TextureFormat) -> SplatPass {
        let slots = [
            Slot::Uniform(VS_FS),
            Slot::Storage(Stages::VERTEX),
            Slot::Storage(Stages::VERTEX),
            Slot::Storage(Stages::VERTEX),
            Slot::Textures(2),
            Slot::Storage(Stages::FRAGMENT),
        ];
        let binding = TargetBinding::new(device, "splat", &slots);
        let module = module(device, "splat", SPLAT);
        let targets = [acc_format, level_format(acc_format)]
            .map(|format| color_target(format, Some(additive())));
        let strip = wgpu::PrimitiveTopology::TriangleStrip;
        let mut spec =
            PipelineSpec::procedural("splat", binding.layout(), &module, strip, &targets);
        // Reversed depth: a footprint passes where the visible surface is not nearer than its
        // support sphere's nearest point.
        spec.depth = depth_state(DEPTH_FORMAT, false, wgpu::CompareFunction::GreaterEqual);
        SplatPass {
            pipeline: pipeline(device, spec),
            binding,
        }
    }

    /// Binds the basis and the G-buffer of `t`.
    pub fn attach(&mut self, device: &wgpu::Device, t: &Targets, scene: &SceneBuffers) {
        let buffers = [
            &scene.globals,
            &scene.points,
            &scene.coefficients,
            &scene.visible,
        ];
        let mut resources: Vec<_> = buffers.iter().map(|b| b.as_entire_binding()).collect();
        resources.extend([&t.position, &t.normal].map(Target::binding));
        resources.push(scene.clip_planes.as_entire_binding());
        self.binding.bind(device, &resources);
    }

    /// Clears the sums of `t` and splats the first `visible` points of the visible list.
    pub fn encode(&self, enc: &mut wgpu::CommandEncoder, t: &Targets, visible: usize) {
        let colors = [&t.acc[0], &t.acc[1]].map(Target::cleared);
        let depth = depth_attachment(&t.depth.view, wgpu::LoadOp::Load);
        let mut pass = begin(enc, "splat", &colors, depth);
        if let (Some(bg), true) = (self.binding.group(), visible > 0) {
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, bg, &[]);
            pass.draw(0..4, 0..visible as u32);
        }
    }
}
