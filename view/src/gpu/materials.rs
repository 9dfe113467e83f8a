//! The materials the G-buffer pass draws with: per material, a range of vertices and a bind
//! group of its albedo colour, its albedo texture (white where it has none or the texture is
//! unusable) and a bilinear, repeating sampler (the filter of the ray caster's
//! `Texture::sample`).

use wgpu::util::DeviceExt;

use super::context::Gpu;
use super::mesh::GpuMesh;
use super::pipeline::{bind_group, layout, view, Slot};

/// One material's vertices and bindings.
pub struct MaterialDraw {
    pub first: u32,
    pub count: u32,
    pub bind_group: wgpu::BindGroup,
}

/// The bind-group layout of a material (group 1 of `gbuffer.wgsl`).
pub fn material_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let slots = [
        Slot::Uniform(wgpu::ShaderStages::FRAGMENT),
        Slot::FilteredTexture,
        Slot::Sampler(wgpu::SamplerBindingType::Filtering),
    ];
    layout(device, "material", &slots)
}

/// Uploads the mesh's textures and makes one draw per material.
pub fn material_draws(
    gpu: &Gpu,
    mesh: &GpuMesh,
    material_layout: &wgpu::BindGroupLayout,
) -> Vec<MaterialDraw> {
    let device = &gpu.device;
    let albedo_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("albedo"),
        address_mode_u: wgpu::AddressMode::Repeat,
        address_mode_v: wgpu::AddressMode::Repeat,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        ..Default::default()
    });
    let white = albedo_texture(
        gpu,
        &mlt_scenes::Texture::from_linear(1, 1, vec![[1.0; 3]]).expect("a valid 1x1 texture"),
    );
    let texture_views = texture_views(gpu, mesh);
    mesh.draws
        .iter()
        .map(|d| {
            let ub = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("material"),
                contents: bytemuck::cast_slice(&[d.albedo[0], d.albedo[1], d.albedo[2], 1.0]),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let tv = d
                .texture
                .and_then(|t| texture_views.get(t as usize).and_then(|v| v.as_ref()))
                .unwrap_or(&white);
            MaterialDraw {
                first: d.first_vertex,
                count: d.vertex_count,
                bind_group: bind_group(
                    device,
                    "material",
                    material_layout,
                    &[
                        ub.as_entire_binding(),
                        wgpu::BindingResource::TextureView(tv),
                        wgpu::BindingResource::Sampler(&albedo_sampler),
                    ],
                ),
            }
        })
        .collect()
}

/// The mesh's textures on the GPU, `None` for those empty, larger than the device allows or
/// whose texel count does not match their size.
fn texture_views(gpu: &Gpu, mesh: &GpuMesh) -> Vec<Option<wgpu::TextureView>> {
    let max_dim = gpu.device.limits().max_texture_dimension_2d;
    mesh.textures
        .iter()
        .map(|t| (t.width() <= max_dim && t.height() <= max_dim).then(|| albedo_texture(gpu, t)))
        .collect()
}

/// A texture of `t`'s texels in half floats, alpha 1.
fn albedo_texture(gpu: &Gpu, t: &mlt_scenes::Texture) -> wgpu::TextureView {
    let texture = gpu.device.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some("albedo texture"),
            size: wgpu::Extent3d {
                width: t.width(),
                height: t.height(),
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba16Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        &half_texels(t),
    );
    view(&texture)
}

fn half_texels(t: &mlt_scenes::Texture) -> Vec<u8> {
    let texels = t.texels();
    let mut out = Vec::with_capacity(texels.len() * 8);
    for p in texels {
        for c in [p[0], p[1], p[2], 1.0] {
            out.extend_from_slice(&half::f16::from_f32(c).to_le_bytes());
        }
    }
    out
}
