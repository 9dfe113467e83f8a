//! The display pass, one full-screen triangle: a linear buffer or a debug view, Reinhard 2002
//! tone mapped, into a window's surface or an image of any colour format (a pipeline per
//! format, made on first use); sRGB is encoded in the shader unless the format does it.

use bytemuck::{Pod, Zeroable};
use serde::Serialize;

use crate::gpu::pipeline::{
    begin, clear_attachment, color_target, module, pipeline, uniform_buffer, PerFormat,
    PipelineSpec, Slot, TargetBinding, VS_FS,
};
use crate::gpu::targets::{Target, Targets};
use crate::images::ToneMap;

const DISPLAY: &str = include_str!("../shaders/display.wgsl");

/// What the display pass shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ViewMode {
    Final = 0,
    Direct = 1,
    Indirect = 2,
    /// The weighted mean level of the flat basis functions at each pixel, coloured.
    LevelUsed = 3,
    /// The basis points of one level coloured by their coefficient, over the final image.
    Points = 4,
}

impl ViewMode {
    pub const ALL: [ViewMode; 5] = [
        ViewMode::Final,
        ViewMode::Direct,
        ViewMode::Indirect,
        ViewMode::LevelUsed,
        ViewMode::Points,
    ];

    pub fn next(self) -> ViewMode {
        ViewMode::ALL[(self as usize + 1) % ViewMode::ALL.len()]
    }

    pub fn name(self) -> &'static str {
        match self {
            ViewMode::Final => "final",
            ViewMode::Direct => "direct",
            ViewMode::Indirect => "indirect",
            ViewMode::LevelUsed => "level used",
            ViewMode::Points => "basis points",
        }
    }
}

/// Where the display pass (and the points over it) draws: a window's surface or an image of
/// the rendered size.
#[derive(Clone, Copy)]
pub struct Output<'a> {
    pub view: &'a wgpu::TextureView,
    pub format: wgpu::TextureFormat,
}

/// 1 where the shader encodes sRGB, 0 where the target's format does.
pub fn encode_srgb(format: wgpu::TextureFormat) -> f32 {
    if format.is_srgb() {
        0.0
    } else {
        1.0
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DisplayUniform {
    params: [f32; 4],
    extra: [f32; 4],
}

pub struct DisplayPass {
    module: wgpu::ShaderModule,
    pipelines: PerFormat,
    uniform: wgpu::Buffer,
    binding: TargetBinding,
}

impl DisplayPass {
    pub fn new(device: &wgpu::Device) -> DisplayPass {
        // The parameters; direct, indirect and final radiance; the splat sums and level sum.
        let slots = [Slot::Uniform(VS_FS), Slot::Textures(5)];
        let size = std::mem::size_of::<DisplayUniform>() as u64;
        DisplayPass {
            module: module(device, "display", DISPLAY),
            pipelines: PerFormat::default(),
            uniform: uniform_buffer(device, "display", size),
            binding: TargetBinding::new(device, "display", &slots),
        }
    }

    /// Binds the radiance buffers and the splat sums of `t`.
    pub fn attach(&mut self, device: &wgpu::Device, t: &Targets) {
        let inputs = [&t.direct, &t.indirect, &t.final_, &t.acc[0], &t.acc[1]];
        let mut resources = vec![self.uniform.as_entire_binding()];
        resources.extend(inputs.map(Target::binding));
        self.binding.bind(device, &resources);
    }

    /// Shows `mode` (the final image under the points view) tone mapped with `tone`, for a
    /// basis of `levels` levels, into a target of `format`.
    pub fn set(
        &self,
        queue: &wgpu::Queue,
        mode: ViewMode,
        tone: &ToneMap,
        levels: usize,
        format: wgpu::TextureFormat,
    ) {
        let scale = tone.key / tone.log_average.max(f32::MIN_POSITIVE);
        let shown = if mode == ViewMode::Points {
            ViewMode::Final
        } else {
            mode
        };
        let u = DisplayUniform {
            params: [
                shown as u32 as f32,
                scale,
                scale * tone.white,
                encode_srgb(format),
            ],
            extra: [levels as f32, 0.0, 0.0, 0.0],
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
    }

    /// Clears `out` and draws into it.
    pub fn encode(&mut self, device: &wgpu::Device, enc: &mut wgpu::CommandEncoder, out: Output) {
        let (layout, module) = (self.binding.layout(), &self.module);
        let pipeline = self.pipelines.get(out.format, |format| {
            let targets = [color_target(format, None)];
            let list = wgpu::PrimitiveTopology::TriangleList;
            let spec = PipelineSpec::procedural("display", layout, module, list, &targets);
            pipeline(device, spec)
        });
        let mut pass = begin(enc, "display", &[clear_attachment(out.view)], None);
        if let Some(bg) = self.binding.group() {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bg, &[]);
            pass.draw(0..3, 0..1);
        }
    }
}
