//! The resolve pass, one full-screen triangle: `E = sum w (n . c) / sum w` from the splat
//! sums, indirect radiance `albedo / pi E`, plus the shadow-mapped direct light, written as
//! linear direct, indirect and final radiance.

use crate::gpu::pipeline::{
    begin, color_target, module, pipeline, PipelineSpec, Slot, TargetBinding, VS_FS,
};
use crate::gpu::scene_buffers::SceneBuffers;
use crate::gpu::targets::{Target, Targets, RADIANCE_FORMAT};

use super::shadow::ShadowPass;

const RESOLVE: &str = include_str!("../shaders/resolve.wgsl");

pub struct ResolvePass {
    pipeline: wgpu::RenderPipeline,
    binding: TargetBinding,
}

impl ResolvePass {
    pub fn new(device: &wgpu::Device) -> ResolvePass {
        // Globals; G-buffer position, normal, albedo; the splat sums; the shadow maps.
        let slots = [
            Slot::Uniform(VS_FS),
            Slot::Textures(4),
            Slot::DepthArray,
            Slot::Sampler(wgpu::SamplerBindingType::Comparison),
        ];
        let binding = TargetBinding::new(device, "resolve", &slots);
        let module = module(device, "resolve", RESOLVE);
        let targets = [0; 3].map(|_| color_target(RADIANCE_FORMAT, None));
        let list = wgpu::PrimitiveTopology::TriangleList;
        let spec = PipelineSpec::procedural("resolve", binding.layout(), &module, list, &targets);
        ResolvePass {
            pipeline: pipeline(device, spec),
            binding,
        }
    }

    /// Binds the G-buffer and the sums of `t` and the shadow maps.
    pub fn attach(
        &mut self,
        device: &wgpu::Device,
        t: &Targets,
        scene: &SceneBuffers,
        shadow: &ShadowPass,
    ) {
        let (maps, sampler) = shadow.maps();
        let inputs = [&t.position, &t.normal, &t.albedo, &t.acc[0]];
        let mut resources = vec![scene.globals.as_entire_binding()];
        resources.extend(inputs.map(Target::binding));
        resources.push(wgpu::BindingResource::TextureView(maps));
        resources.push(wgpu::BindingResource::Sampler(sampler));
        self.binding.bind(device, &resources);
    }

    pub fn encode(&self, enc: &mut wgpu::CommandEncoder, t: &Targets) {
        let colors = [&t.direct, &t.indirect, &t.final_].map(Target::cleared);
        let mut pass = begin(enc, "resolve", &colors, None);
        if let Some(bg) = self.binding.group() {
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, bg, &[]);
            pass.draw(0..3, 0..1);
        }
    }
}
