//! The render targets whose size follows the image, all in one place and made again when the
//! size changes: the G-buffer (world position, shading normal, albedo, reversed depth), the
//! two splat sums and the linear direct, indirect and final radiance.

use super::pipeline::{clear_attachment, view};

pub const POSITION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
pub const NORMAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
pub const ALBEDO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Reversed depth (1 at the near plane) in 32-bit floats.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
pub const RADIANCE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;

/// A texture and the view the passes bind or draw into.
pub struct Target {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
}

impl Target {
    /// The view as a binding.
    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::TextureView(&self.view)
    }

    /// The view as a colour attachment cleared to transparent black.
    pub fn cleared(&self) -> Option<wgpu::RenderPassColorAttachment<'_>> {
        clear_attachment(&self.view)
    }
}

/// The image-sized textures of a frame.
pub struct Targets {
    pub width: u32,
    pub height: u32,
    pub position: Target,
    pub normal: Target,
    pub albedo: Target,
    pub depth: Target,
    /// The splatting pass' sums: `acc[0]` holds `sum w_j (n . c_j)` per colour and `sum w_j`,
    /// `acc[1]` (one channel) `sum w_j level_j` for the level view.
    pub acc: [Target; 2],
    pub direct: Target,
    pub indirect: Target,
    pub final_: Target,
}

impl Targets {
    /// Targets of `width x height` pixels; the splat sums in `acc_format` (four channels) and
    /// its one-channel counterpart ([`level_format`]).
    pub fn new(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        acc_format: wgpu::TextureFormat,
    ) -> Targets {
        let make = |label: &str, format| target(device, label, width, height, format);
        Targets {
            width,
            height,
            position: make("gbuffer position", POSITION_FORMAT),
            normal: make("gbuffer normal", NORMAL_FORMAT),
            albedo: make("gbuffer albedo", ALBEDO_FORMAT),
            depth: make("gbuffer depth", DEPTH_FORMAT),
            acc: [
                make("splat sums", acc_format),
                make("splat level sum", level_format(acc_format)),
            ],
            direct: make("direct", RADIANCE_FORMAT),
            indirect: make("indirect", RADIANCE_FORMAT),
            final_: make("final", RADIANCE_FORMAT),
        }
    }

    /// True when the targets are `width x height`.
    pub fn fit(&self, width: u32, height: u32) -> bool {
        self.width == width && self.height == height
    }
}

/// The one-channel format of the level sum beside the four-channel `acc_format`: 32-bit
/// floats where those can be blended, 16-bit otherwise.
pub fn level_format(acc_format: wgpu::TextureFormat) -> wgpu::TextureFormat {
    if acc_format == wgpu::TextureFormat::Rgba32Float {
        wgpu::TextureFormat::R32Float
    } else {
        wgpu::TextureFormat::R16Float
    }
}

fn target(
    device: &wgpu::Device,
    label: &str,
    w: u32,
    h: u32,
    format: wgpu::TextureFormat,
) -> Target {
    let usage = wgpu::TextureUsages::RENDER_ATTACHMENT
        | wgpu::TextureUsages::TEXTURE_BINDING
        | wgpu::TextureUsages::COPY_SRC;
    let size = wgpu::Extent3d {
        width: w,
        height: h,
        depth_or_array_layers: 1,
    };
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    });
    Target {
        view: view(&texture),
        texture,
    }
}
