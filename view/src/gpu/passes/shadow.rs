//! The shadow-map pass: the scene's depth seen from the light, as linear light distance over
//! [`ShadowFaces::far`], into one layer of a six-layer depth texture per face (a cube for a
//! point light or a wide spot, one map for a narrower spot). The resolve pass samples the
//! layers with a comparison sampler.

use glam::Vec3;

use crate::gpu::pipeline::{
    begin, bind_group, depth_attachment, depth_state, layout, module, pipeline, uniform_buffer,
    vertex_layout, PipelineSpec, Slot, VS_FS,
};
use crate::gpu::scene_buffers::SceneBuffers;
use crate::gpu::uniforms::{FaceUniform, ShadowFaces};
use mlt_relight::Light;

const SHADOW: &str = include_str!("../shaders/shadow.wgsl");
const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Bytes of `Face` in `shadow.wgsl` (a matrix and a vector).
const FACE_BINDING_SIZE: u64 = 80;

pub struct ShadowPass {
    pipeline: wgpu::RenderPipeline,
    resolution: u32,
    layer_views: Vec<wgpu::TextureView>,
    /// All six layers, as the resolve pass binds them.
    array_view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    face_buffer: wgpu::Buffer,
    face_bgs: Vec<wgpu::BindGroup>,
    faces: Option<ShadowFaces>,
}

impl ShadowPass {
    /// Maps of `resolution` texels on a side (clamped to 16 and the device's limit).
    pub fn new(device: &wgpu::Device, resolution: u32) -> ShadowPass {
        let face_layout = layout(device, "shadow face", &[Slot::Uniform(VS_FS)]);
        // Positions only.
        let attributes = wgpu::vertex_attr_array![0 => Float32x3];
        let pipeline = pipeline(
            device,
            PipelineSpec {
                label: "shadow",
                bind_groups: vec![&face_layout],
                module: &module(device, "shadow", SHADOW),
                vertex_buffers: &[Some(vertex_layout(&attributes))],
                topology: wgpu::PrimitiveTopology::TriangleList,
                depth: depth_state(SHADOW_FORMAT, true, wgpu::CompareFunction::Less),
                targets: &[],
            },
        );
        let resolution = resolution.clamp(16, device.limits().max_texture_dimension_2d);
        let texture = shadow_texture(device, resolution);
        let layer_views = (0..6)
            .map(|k| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("shadow face"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: k,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let array_view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("shadow maps"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let face_size = std::mem::size_of::<FaceUniform>() as u64;
        let face_buffer = uniform_buffer(device, "shadow faces", 6 * face_size);
        ShadowPass {
            pipeline,
            resolution,
            layer_views,
            array_view,
            sampler: comparison_sampler(device),
            face_bgs: face_bind_groups(device, &face_layout, &face_buffer, face_size),
            face_buffer,
            faces: None,
        }
    }

    /// Places the faces for `light` in a scene of `bounds`, when the light changed or none
    /// are placed yet.
    pub fn place(&mut self, light: &Light, bounds: (Vec3, Vec3), light_changed: bool) {
        if light_changed || self.faces.is_none() {
            self.faces = Some(ShadowFaces::new(light, bounds, self.resolution));
        }
    }

    /// The faces and the resolution, as `Globals::new` takes them.
    pub fn faces(&self) -> Option<(&ShadowFaces, u32)> {
        self.faces.as_ref().map(|f| (f, self.resolution))
    }

    /// The maps and their comparison sampler, for the resolve pass.
    pub fn maps(&self) -> (&wgpu::TextureView, &wgpu::Sampler) {
        (&self.array_view, &self.sampler)
    }

    /// Writes the faces' parameters and draws every face of the placed faces.
    pub fn encode(
        &self,
        queue: &wgpu::Queue,
        enc: &mut wgpu::CommandEncoder,
        light: &Light,
        scene: &SceneBuffers,
    ) {
        let Some(f) = &self.faces else {
            return;
        };
        let face_size = std::mem::size_of::<FaceUniform>() as u64;
        for (k, m) in f.view_proj.iter().enumerate() {
            let p = light.position;
            let u = FaceUniform {
                view_proj: m.to_cols_array_2d(),
                light: [p.x, p.y, p.z, f.far],
                pad: [0.0; 44],
            };
            queue.write_buffer(
                &self.face_buffer,
                k as u64 * face_size,
                bytemuck::bytes_of(&u),
            );
        }
        for k in 0..f.view_proj.len() {
            let depth = depth_attachment(&self.layer_views[k], wgpu::LoadOp::Clear(1.0));
            let mut pass = begin(enc, "shadow face", &[], depth);
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.face_bgs[k], &[]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            if scene.vertex_count > 0 {
                pass.draw(0..scene.vertex_count, 0..1);
            }
        }
    }
}

/// One bind group per face: its slice of the face buffer.
fn face_bind_groups(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    buffer: &wgpu::Buffer,
    face_size: u64,
) -> Vec<wgpu::BindGroup> {
    (0..6)
        .map(|k| {
            let face = wgpu::BufferBinding {
                buffer,
                offset: k * face_size,
                size: wgpu::BufferSize::new(FACE_BINDING_SIZE),
            };
            let resource = wgpu::BindingResource::Buffer(face);
            bind_group(device, "shadow face", layout, &[resource])
        })
        .collect()
}

/// Comparison sampling, filtered bilinearly: the weighted fraction of the four nearest texels
/// whose stored distance is at least the compared one (lit).
fn comparison_sampler(device: &wgpu::Device) -> wgpu::Sampler {
    device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("shadow"),
        address_mode_u: wgpu::AddressMode::ClampToEdge,
        address_mode_v: wgpu::AddressMode::ClampToEdge,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        compare: Some(wgpu::CompareFunction::LessEqual),
        ..Default::default()
    })
}

fn shadow_texture(device: &wgpu::Device, resolution: u32) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("shadow maps"),
        size: wgpu::Extent3d {
            width: resolution,
            height: resolution,
            depth_or_array_layers: 6,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: SHADOW_FORMAT,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    })
}
