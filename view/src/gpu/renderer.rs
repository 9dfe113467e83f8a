//! The passes of the deferred renderer (section 4.1):
//! 1. G-buffer: world position, shading normal and albedo (textures included) per pixel;
//! 2. shadow maps: linear light distance, a cube for a point light, one map for a spot;
//! 3. splatting: every flat basis function (all points with their own radii and their level's
//!    priority factor: `mlt_format::flatten`) that survives frustum culling is drawn as a
//!    footprint bounding its support sphere; covered pixels accumulate `f_j w_j` (Eq. 8),
//!    `f_j w_j c_j` and the unscaled `w_j` (which decides whether a pixel has support);
//! 4. resolve: `E = n . (sum w c / sum w)`, indirect radiance `albedo / pi E`, plus the
//!    shadow-mapped direct light, written as linear direct, indirect and final radiance;
//! 5. display: a buffer or debug view, Reinhard 2002 tone mapped, into a window or image.
//!
//! The G-buffer uses reversed depth (1 at the near plane) in a 32-bit float buffer, so depth
//! precision does not depend on the scene's scale.

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};
use mlt_format::flatten::flat_level_factor;
use mlt_format::links::LINK_DIM;
use mlt_format::{Basis, IndexedBasis};
use mlt_relight::{FlattenOp, Light};
use serde::Serialize;
use wgpu::util::DeviceExt;

use super::context::{Gpu, GpuError};
use super::cull::{visible_points, Frustum};
use super::flatten::GpuFlatten;
use super::mesh::{GpuMesh, Vertex};
use super::readback::read_rgba32f;
use super::uniforms::{FaceUniform, Globals, ShadowFaces};
use crate::camera::Camera;
use crate::images::{RgbImage, ToneMap};

const COMMON: &str = include_str!("shaders/common.wgsl");
const GBUFFER: &str = include_str!("shaders/gbuffer.wgsl");
const SPLAT: &str = include_str!("shaders/splat.wgsl");
const SHADOW: &str = include_str!("shaders/shadow.wgsl");
const RESOLVE: &str = include_str!("shaders/resolve.wgsl");
const DISPLAY: &str = include_str!("shaders/display.wgsl");
const POINTS: &str = include_str!("shaders/points.wgsl");

const POSITION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const NORMAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const ALBEDO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const RADIANCE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

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

/// Wall-clock milliseconds of the GPU passes of one frame (each pass submitted and waited for
/// on its own when timing was asked for), and the culling on the CPU.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RenderTimes {
    /// The flattening compute pass, when the renderer flattens (set by the caller).
    pub flatten_ms: f64,
    pub cull_ms: f64,
    pub gbuffer_ms: f64,
    pub shadow_ms: f64,
    pub splat_ms: f64,
    pub resolve_ms: f64,
    /// Basis functions drawn (those meeting the view frustum).
    pub splatted_points: usize,
    /// R-tree nodes visited by the culling.
    pub culling_nodes: usize,
}

/// The linear radiance buffers of a frame.
#[derive(Clone, Debug)]
pub struct Buffers {
    pub direct: RgbImage,
    pub indirect: RgbImage,
    pub final_: RgbImage,
}

/// The G-buffer read back (for tests and probes): per pixel, rows from the top.
#[derive(Clone, Debug)]
pub struct GBuffer {
    pub width: u32,
    pub height: u32,
    /// World position, `w = 1` where a surface covers the pixel, 0 elsewhere.
    pub position: Vec<[f32; 4]>,
    pub normal: Vec<[f32; 3]>,
    pub albedo: Vec<[f32; 3]>,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PointGpu {
    pos_r: [f32; 4],
    normal_level: [f32; 4],
    /// x: the level's weight factor in the flat basis (`flat_level_factor`).
    factor: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DisplayUniform {
    params: [f32; 4],
    extra: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PointsUniform {
    params: [f32; 4],
}

/// Textures whose size follows the image.
struct Targets {
    width: u32,
    height: u32,
    position: wgpu::Texture,
    normal: wgpu::Texture,
    albedo: wgpu::Texture,
    depth: wgpu::Texture,
    acc: [wgpu::Texture; 3],
    direct: wgpu::Texture,
    indirect: wgpu::Texture,
    final_: wgpu::Texture,
    splat_bg: wgpu::BindGroup,
    resolve_bg: wgpu::BindGroup,
    display_bg: wgpu::BindGroup,
}

struct MaterialDraw {
    first: u32,
    count: u32,
    bind_group: wgpu::BindGroup,
}

/// The renderer of one baked scene.
pub struct Renderer {
    points: Basis,
    levels: usize,
    bounds: (Vec3, Vec3),
    vertex_buffer: wgpu::Buffer,
    draws: Vec<MaterialDraw>,
    globals: wgpu::Buffer,
    globals_bg: wgpu::BindGroup,
    point_buffer: wgpu::Buffer,
    coeff_buffer: wgpu::Buffer,
    visible_buffer: wgpu::Buffer,
    visible: Vec<u32>,
    culling_nodes: usize,
    gbuffer_pipeline: wgpu::RenderPipeline,
    shadow_pipeline: wgpu::RenderPipeline,
    splat_pipeline: wgpu::RenderPipeline,
    resolve_pipeline: wgpu::RenderPipeline,
    splat_layout: wgpu::BindGroupLayout,
    resolve_layout: wgpu::BindGroupLayout,
    display_layout: wgpu::BindGroupLayout,
    display_module: wgpu::ShaderModule,
    display_pipelines: Vec<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
    display_uniform: wgpu::Buffer,
    points_module: wgpu::ShaderModule,
    points_layout: wgpu::BindGroupLayout,
    points_pipelines: Vec<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
    points_uniform: wgpu::Buffer,
    points_bg: wgpu::BindGroup,
    shadow_res: u32,
    shadow_texture: wgpu::Texture,
    shadow_layer_views: Vec<wgpu::TextureView>,
    face_buffer: wgpu::Buffer,
    face_bgs: Vec<wgpu::BindGroup>,
    shadow_faces: Option<ShadowFaces>,
    shadow_sampler: wgpu::Sampler,
    gpu_flatten: Option<GpuFlatten>,
    acc_format: wgpu::TextureFormat,
    targets: Option<Targets>,
    last_camera: Option<Camera>,
    last_light: Option<Light>,
    /// Whether direct light is shadowed (shadow maps); on by default.
    pub shadows: bool,
}

fn module(device: &wgpu::Device, label: &str, src: &str) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(format!("{COMMON}\n{src}").into()),
    })
}

fn uniform_entry(binding: u32, vis: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: vis,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn storage_entry(binding: u32, vis: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: vis,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn texture_entry(binding: u32, filterable: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

fn view(t: &wgpu::Texture) -> wgpu::TextureView {
    t.create_view(&wgpu::TextureViewDescriptor::default())
}

fn target(
    device: &wgpu::Device,
    label: &str,
    w: u32,
    h: u32,
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

fn color_target(
    format: wgpu::TextureFormat,
    blend: Option<wgpu::BlendState>,
) -> Option<wgpu::ColorTargetState> {
    Some(wgpu::ColorTargetState {
        format,
        blend,
        write_mask: wgpu::ColorWrites::ALL,
    })
}

fn additive() -> wgpu::BlendState {
    let c = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Add,
    };
    wgpu::BlendState { color: c, alpha: c }
}

fn clear_attachment(v: &wgpu::TextureView) -> Option<wgpu::RenderPassColorAttachment<'_>> {
    Some(wgpu::RenderPassColorAttachment {
        view: v,
        depth_slice: None,
        resolve_target: None,
        ops: wgpu::Operations {
            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
            store: wgpu::StoreOp::Store,
        },
    })
}

fn half_texels(t: &mlt_scenes::Texture) -> Vec<u8> {
    let mut out = Vec::with_capacity(t.texels.len() * 8);
    for p in &t.texels {
        for c in [p[0], p[1], p[2], 1.0] {
            out.extend_from_slice(&half::f16::from_f32(c).to_le_bytes());
        }
    }
    out
}

/// What differs between the renderer's pipelines.
struct PipelineSpec<'a> {
    label: &'a str,
    bind_groups: &'a [&'a wgpu::BindGroupLayout],
    module: &'a wgpu::ShaderModule,
    vertex_buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
    topology: wgpu::PrimitiveTopology,
    depth: Option<wgpu::DepthStencilState>,
    targets: &'a [Option<wgpu::ColorTargetState>],
}

/// A render pipeline with entry points `vs` and `fs` of one module.
fn pipeline(device: &wgpu::Device, spec: PipelineSpec<'_>) -> wgpu::RenderPipeline {
    let groups: Vec<Option<&wgpu::BindGroupLayout>> =
        spec.bind_groups.iter().map(|g| Some(*g)).collect();
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(spec.label),
        bind_group_layouts: &groups,
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(spec.label),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: spec.module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: spec.vertex_buffers,
        },
        primitive: wgpu::PrimitiveState {
            topology: spec.topology,
            ..Default::default()
        },
        depth_stencil: spec.depth,
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: spec.module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: spec.targets,
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// A depth test (and write) against `format`.
fn depth_state(
    format: wgpu::TextureFormat,
    write: bool,
    compare: wgpu::CompareFunction,
) -> Option<wgpu::DepthStencilState> {
    Some(wgpu::DepthStencilState {
        format,
        depth_write_enabled: Some(write),
        depth_compare: Some(compare),
        stencil: Default::default(),
        bias: Default::default(),
    })
}

/// The reversed-depth projection of a camera (near plane at depth 1, far at 0).
pub fn reversed_view_proj(camera: &Camera, planes: (f32, f32)) -> Mat4 {
    glam::camera::rh::proj::directx::perspective(
        camera.fovy_deg.to_radians(),
        camera.aspect(),
        planes.1,
        planes.0,
    ) * camera.view_matrix()
}

impl Renderer {
    /// Uploads the scene and the basis. `shadow_res` is the shadow maps' resolution.
    pub fn new(
        gpu: &Gpu,
        mesh: &GpuMesh,
        basis: &Basis,
        shadow_res: u32,
    ) -> Result<Renderer, GpuError> {
        let device = &gpu.device;
        let acc_format = if gpu.report.float32_blend {
            wgpu::TextureFormat::Rgba32Float
        } else {
            wgpu::TextureFormat::Rgba16Float
        };
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);

        // Geometry and materials.
        let vertex_bytes: &[u8] = if mesh.vertices.is_empty() {
            &[0u8; std::mem::size_of::<Vertex>()]
        } else {
            bytemuck::cast_slice(&mesh.vertices)
        };
        let vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: vertex_bytes,
            usage: wgpu::BufferUsages::VERTEX,
        });
        let vs_frag = wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT;
        let globals_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("globals"),
            entries: &[uniform_entry(0, vs_frag)],
        });
        let material_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("material"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::FRAGMENT),
                texture_entry(1, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: std::mem::size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let globals_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("globals"),
            layout: &globals_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: globals.as_entire_binding(),
            }],
        });
        // Bilinear, repeating: the same filter as `Texture::sample` of the ray caster.
        let albedo_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("albedo"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let make_texture = |w: u32, h: u32, data: &[u8]| {
            device.create_texture_with_data(
                &gpu.queue,
                &wgpu::TextureDescriptor {
                    label: Some("albedo texture"),
                    size: wgpu::Extent3d {
                        width: w,
                        height: h,
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
                data,
            )
        };
        let max_dim = device.limits().max_texture_dimension_2d;
        let white = view(&make_texture(
            1,
            1,
            &half_texels(&mlt_scenes::Texture {
                width: 1,
                height: 1,
                texels: vec![[1.0; 3]],
            }),
        ));
        let texture_views: Vec<Option<wgpu::TextureView>> = mesh
            .textures
            .iter()
            .map(|t| {
                (t.width > 0
                    && t.height > 0
                    && t.width <= max_dim
                    && t.height <= max_dim
                    && t.texels.len() == (t.width * t.height) as usize)
                    .then(|| view(&make_texture(t.width, t.height, &half_texels(t))))
            })
            .collect();
        let draws = mesh
            .draws
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
                let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("material"),
                    layout: &material_layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: ub.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: wgpu::BindingResource::TextureView(tv),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: wgpu::BindingResource::Sampler(&albedo_sampler),
                        },
                    ],
                });
                MaterialDraw {
                    first: d.first_vertex,
                    count: d.vertex_count,
                    bind_group,
                }
            })
            .collect();

        // G-buffer pipeline.
        let vertex_attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x2
        ];
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &vertex_attributes,
        };
        let gmod = module(device, "gbuffer", GBUFFER);
        let gbuffer_pipeline = pipeline(
            device,
            PipelineSpec {
                label: "gbuffer",
                bind_groups: &[&globals_layout, &material_layout],
                module: &gmod,
                vertex_buffers: &[Some(vertex_layout.clone())],
                topology: wgpu::PrimitiveTopology::TriangleList,
                depth: depth_state(DEPTH_FORMAT, true, wgpu::CompareFunction::Greater),
                targets: &[
                    color_target(POSITION_FORMAT, None),
                    color_target(NORMAL_FORMAT, None),
                    color_target(ALBEDO_FORMAT, None),
                ],
            },
        );

        // Shadow pipeline: positions only.
        let shadow_attributes = wgpu::vertex_attr_array![0 => Float32x3];
        let shadow_vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &shadow_attributes,
        };
        let face_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shadow face"),
            entries: &[uniform_entry(0, vs_frag)],
        });
        let smod = module(device, "shadow", SHADOW);
        let shadow_pipeline = pipeline(
            device,
            PipelineSpec {
                label: "shadow",
                bind_groups: &[&face_layout],
                module: &smod,
                vertex_buffers: &[Some(shadow_vertex_layout)],
                topology: wgpu::PrimitiveTopology::TriangleList,
                depth: depth_state(SHADOW_FORMAT, true, wgpu::CompareFunction::Less),
                targets: &[],
            },
        );
        let shadow_res = shadow_res.clamp(16, max_dim);
        let shadow_texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: shadow_res,
                height: shadow_res,
                depth_or_array_layers: 6,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: SHADOW_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let shadow_layer_views = (0..6)
            .map(|k| {
                shadow_texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("shadow face"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: k,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let face_size = std::mem::size_of::<FaceUniform>() as u64;
        let face_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow faces"),
            size: 6 * face_size,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let face_bgs = (0..6)
            .map(|k| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("shadow face"),
                    layout: &face_layout,
                    entries: &[wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &face_buffer,
                            offset: k * face_size,
                            size: wgpu::BufferSize::new(80),
                        }),
                    }],
                })
            })
            .collect();
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });

        // Basis points, coefficients, visible list.
        let n = basis.len();
        let levels = basis.levels();
        let pts: Vec<PointGpu> = (0..n)
            .map(|j| {
                let p = basis.positions[j];
                let nn = basis.normals[j];
                PointGpu {
                    pos_r: [p[0], p[1], p[2], basis.radii[j]],
                    normal_level: [nn[0], nn[1], nn[2], basis.level_of(j) as f32],
                    factor: [flat_level_factor(basis.level_of(j), levels), 0.0, 0.0, 0.0],
                }
            })
            .collect();
        let point_bytes: Vec<u8> = if pts.is_empty() {
            vec![0u8; std::mem::size_of::<PointGpu>()]
        } else {
            bytemuck::cast_slice(&pts).to_vec()
        };
        let point_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("basis points"),
            contents: &point_bytes,
            usage: wgpu::BufferUsages::STORAGE,
        });
        let coeff_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("flat coefficients"),
            size: (n.max(1) * LINK_DIM * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let visible_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("visible points"),
            size: (n.max(1) * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        // Splat pipeline.
        let splat_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("splat"),
            entries: &[
                uniform_entry(0, vs_frag),
                storage_entry(1, vs_frag),
                storage_entry(2, wgpu::ShaderStages::FRAGMENT),
                storage_entry(3, wgpu::ShaderStages::VERTEX),
                texture_entry(4, false),
                texture_entry(5, false),
            ],
        });
        let spmod = module(device, "splat", SPLAT);
        let splat_pipeline = pipeline(
            device,
            PipelineSpec {
                label: "splat",
                bind_groups: &[&splat_layout],
                module: &spmod,
                vertex_buffers: &[],
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                depth: None,
                targets: &[
                    color_target(acc_format, Some(additive())),
                    color_target(acc_format, Some(additive())),
                    color_target(acc_format, Some(additive())),
                ],
            },
        );

        // Resolve pipeline.
        let resolve_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("resolve"),
            entries: &[
                uniform_entry(0, vs_frag),
                texture_entry(1, false),
                texture_entry(2, false),
                texture_entry(3, false),
                texture_entry(4, false),
                texture_entry(5, false),
                texture_entry(6, false),
                wgpu::BindGroupLayoutEntry {
                    binding: 7,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 8,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                    count: None,
                },
            ],
        });
        let rmod = module(device, "resolve", RESOLVE);
        let resolve_pipeline = pipeline(
            device,
            PipelineSpec {
                label: "resolve",
                bind_groups: &[&resolve_layout],
                module: &rmod,
                vertex_buffers: &[],
                topology: wgpu::PrimitiveTopology::TriangleList,
                depth: None,
                targets: &[
                    color_target(RADIANCE_FORMAT, None),
                    color_target(RADIANCE_FORMAT, None),
                    color_target(RADIANCE_FORMAT, None),
                ],
            },
        );

        // Display and points (pipelines made per output format on first use).
        let display_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("display"),
            entries: &[
                uniform_entry(0, vs_frag),
                texture_entry(1, false),
                texture_entry(2, false),
                texture_entry(3, false),
                texture_entry(4, false),
                texture_entry(5, false),
            ],
        });
        let display_uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("display"),
            size: std::mem::size_of::<DisplayUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let points_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("points"),
            entries: &[
                uniform_entry(0, vs_frag),
                storage_entry(1, wgpu::ShaderStages::VERTEX),
                storage_entry(2, wgpu::ShaderStages::VERTEX),
                uniform_entry(3, vs_frag),
            ],
        });
        let points_uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("points"),
            size: std::mem::size_of::<PointsUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let points_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("points"),
            layout: &points_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: globals.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: point_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: coeff_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: points_uniform.as_entire_binding(),
                },
            ],
        });

        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        Ok(Renderer {
            points: basis.clone(),
            levels: basis.levels(),
            bounds: mesh.bounds,
            vertex_buffer,
            draws,
            globals,
            globals_bg,
            point_buffer,
            coeff_buffer,
            visible_buffer,
            visible: Vec::with_capacity(n),
            culling_nodes: 0,
            gbuffer_pipeline,
            shadow_pipeline,
            splat_pipeline,
            resolve_pipeline,
            splat_layout,
            resolve_layout,
            display_layout,
            display_module: module(device, "display", DISPLAY),
            display_pipelines: Vec::new(),
            display_uniform,
            points_module: module(device, "points", POINTS),
            points_layout,
            points_pipelines: Vec::new(),
            points_uniform,
            points_bg,
            shadow_res,
            shadow_texture,
            shadow_layer_views,
            face_buffer,
            face_bgs,
            shadow_faces: None,
            shadow_sampler,
            gpu_flatten: None,
            acc_format,
            targets: None,
            last_camera: None,
            last_light: None,
            shadows: true,
        })
    }

    /// The number of levels of the basis.
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// The accumulation format of the splat sums (`Rgba32Float` where it can be blended).
    pub fn accumulation_format(&self) -> wgpu::TextureFormat {
        self.acc_format
    }

    /// Uploads new flat coefficients (`LINK_DIM` floats per basis point).
    pub fn set_coefficients(&self, gpu: &Gpu, flat: &[f32]) {
        let n = self.points.len() * LINK_DIM;
        if n > 0 && flat.len() >= n {
            gpu.queue
                .write_buffer(&self.coeff_buffer, 0, bytemuck::cast_slice(&flat[..n]));
        }
    }

    /// Moves flattening to the GPU: uploads the precomputed operator once; afterwards
    /// [`Renderer::set_hierarchical_coefficients`] replaces [`Renderer::set_coefficients`].
    /// Returns the bytes uploaded.
    pub fn enable_gpu_flatten(&mut self, gpu: &Gpu, op: &FlattenOp) -> Result<u64, GpuError> {
        if op.points() != self.points.len() {
            return Err(GpuError::Validation(format!(
                "flattening operator for {} points, basis of {}",
                op.points(),
                self.points.len()
            )));
        }
        let f = GpuFlatten::new(gpu, op, &self.coeff_buffer)?;
        let bytes = f.bytes;
        self.gpu_flatten = Some(f);
        Ok(bytes)
    }

    /// True after [`Renderer::enable_gpu_flatten`].
    pub fn flattens_on_gpu(&self) -> bool {
        self.gpu_flatten.is_some()
    }

    /// Flattens the hierarchical coefficients `i` (`LINK_DIM` per point) on the GPU into the
    /// splatted coefficients. With `timed`, waits and returns the wall time in milliseconds.
    pub fn set_hierarchical_coefficients(
        &self,
        gpu: &Gpu,
        i: &[f32],
        timed: bool,
    ) -> Result<f64, GpuError> {
        let Some(f) = &self.gpu_flatten else {
            return Err(GpuError::Validation(
                "GPU flattening is not enabled (enable_gpu_flatten)".into(),
            ));
        };
        let start = Instant::now();
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("flatten"),
            });
        f.encode(gpu, i, &mut enc);
        gpu.queue.submit([enc.finish()]);
        if timed {
            gpu.wait()?;
        }
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }

    /// Reads back the flat coefficients the splatting pass uses (for tests).
    pub fn read_coefficients(&self, gpu: &Gpu) -> Result<Vec<f32>, GpuError> {
        super::readback::read_buffer_f32(gpu, &self.coeff_buffer, self.points.len() * LINK_DIM)
    }

    fn ensure_targets(&mut self, gpu: &Gpu, w: u32, h: u32) {
        if let Some(t) = &self.targets {
            if t.width == w && t.height == h {
                return;
            }
        }
        let device = &gpu.device;
        let position = target(device, "gbuffer position", w, h, POSITION_FORMAT);
        let normal = target(device, "gbuffer normal", w, h, NORMAL_FORMAT);
        let albedo = target(device, "gbuffer albedo", w, h, ALBEDO_FORMAT);
        let depth = target(device, "gbuffer depth", w, h, DEPTH_FORMAT);
        let acc = [0, 1, 2].map(|_| target(device, "splat sums", w, h, self.acc_format));
        let direct = target(device, "direct", w, h, RADIANCE_FORMAT);
        let indirect = target(device, "indirect", w, h, RADIANCE_FORMAT);
        let final_ = target(device, "final", w, h, RADIANCE_FORMAT);
        let (pv, nv, av) = (view(&position), view(&normal), view(&albedo));
        let accv = [view(&acc[0]), view(&acc[1]), view(&acc[2])];
        let (dv, iv, fv) = (view(&direct), view(&indirect), view(&final_));
        let shadow_view = self
            .shadow_texture
            .create_view(&wgpu::TextureViewDescriptor {
                label: Some("shadow maps"),
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            });
        fn entry(binding: u32, resource: wgpu::BindingResource<'_>) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry { binding, resource }
        }
        use wgpu::BindingResource::TextureView as Tv;
        let splat_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("splat"),
            layout: &self.splat_layout,
            entries: &[
                entry(0, self.globals.as_entire_binding()),
                entry(1, self.point_buffer.as_entire_binding()),
                entry(2, self.coeff_buffer.as_entire_binding()),
                entry(3, self.visible_buffer.as_entire_binding()),
                entry(4, Tv(&pv)),
                entry(5, Tv(&nv)),
            ],
        });
        let resolve_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("resolve"),
            layout: &self.resolve_layout,
            entries: &[
                entry(0, self.globals.as_entire_binding()),
                entry(1, Tv(&pv)),
                entry(2, Tv(&nv)),
                entry(3, Tv(&av)),
                entry(4, Tv(&accv[0])),
                entry(5, Tv(&accv[1])),
                entry(6, Tv(&accv[2])),
                entry(7, Tv(&shadow_view)),
                entry(8, wgpu::BindingResource::Sampler(&self.shadow_sampler)),
            ],
        });
        let display_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("display"),
            layout: &self.display_layout,
            entries: &[
                entry(0, self.display_uniform.as_entire_binding()),
                entry(1, Tv(&dv)),
                entry(2, Tv(&iv)),
                entry(3, Tv(&fv)),
                entry(4, Tv(&accv[0])),
                entry(5, Tv(&accv[2])),
            ],
        });
        self.targets = Some(Targets {
            width: w,
            height: h,
            position,
            normal,
            albedo,
            depth,
            acc,
            direct,
            indirect,
            final_,
            splat_bg,
            resolve_bg,
            display_bg,
        });
        self.last_camera = None;
    }

    /// Renders one frame of `camera` and `light` into the linear buffers. The G-buffer is
    /// redrawn only when the camera changed and the shadow maps only when the light did.
    /// With `timed`, each pass is submitted and waited for alone and its wall time reported.
    pub fn render(
        &mut self,
        gpu: &Gpu,
        ib: &IndexedBasis,
        camera: &Camera,
        light: &Light,
        timed: bool,
    ) -> Result<RenderTimes, GpuError> {
        let mut times = RenderTimes::default();
        self.ensure_targets(gpu, camera.width, camera.height);
        let planes = camera.planes_for_bounds(self.bounds.0, self.bounds.1);
        let camera_changed = self.last_camera.as_ref() != Some(camera);
        let light_changed = self.last_light.as_ref() != Some(light);
        if light_changed || self.shadow_faces.is_none() {
            self.shadow_faces = Some(ShadowFaces::new(light, self.bounds, self.shadow_res));
        }
        let faces = self.shadow_faces.clone();
        let shadows = if self.shadows {
            faces.as_ref().map(|f| (f, self.shadow_res))
        } else {
            None
        };
        let mut globals = Globals::new(camera, planes, light, shadows, 0, 0);
        let view_proj = reversed_view_proj(camera, planes);
        globals.view_proj = view_proj.to_cols_array_2d();
        gpu.queue
            .write_buffer(&self.globals, 0, bytemuck::bytes_of(&globals));

        if camera_changed {
            let t = Instant::now();
            self.culling_nodes = visible_points(
                ib,
                &Frustum::from_view_proj(&view_proj),
                f32::INFINITY,
                &mut self.visible,
            );
            if !self.visible.is_empty() {
                gpu.queue.write_buffer(
                    &self.visible_buffer,
                    0,
                    bytemuck::cast_slice(&self.visible),
                );
            }
            times.cull_ms = t.elapsed().as_secs_f64() * 1e3;
        }
        times.splatted_points = self.visible.len();
        times.culling_nodes = self.culling_nodes;

        let Some(t) = &self.targets else {
            return Err(GpuError::Validation("render targets missing".into()));
        };
        let submit = |encoder: wgpu::CommandEncoder| -> Result<f64, GpuError> {
            let start = Instant::now();
            gpu.queue.submit([encoder.finish()]);
            if timed {
                gpu.wait()?;
            }
            Ok(start.elapsed().as_secs_f64() * 1e3)
        };
        let new_encoder = |label: &str| {
            gpu.device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
        };
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);

        if camera_changed {
            let mut enc = new_encoder("gbuffer");
            {
                let (pv, nv, av, dv) = (
                    view(&t.position),
                    view(&t.normal),
                    view(&t.albedo),
                    view(&t.depth),
                );
                let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("gbuffer"),
                    color_attachments: &[
                        clear_attachment(&pv),
                        clear_attachment(&nv),
                        clear_attachment(&av),
                    ],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &dv,
                        depth_ops: Some(wgpu::Operations {
                            load: wgpu::LoadOp::Clear(0.0),
                            store: wgpu::StoreOp::Store,
                        }),
                        stencil_ops: None,
                    }),
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&self.gbuffer_pipeline);
                pass.set_bind_group(0, &self.globals_bg, &[]);
                pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
                for d in &self.draws {
                    if d.count > 0 {
                        pass.set_bind_group(1, &d.bind_group, &[]);
                        pass.draw(d.first..d.first + d.count, 0..1);
                    }
                }
            }
            times.gbuffer_ms = submit(enc)?;
        }

        if light_changed && self.shadows {
            if let Some(f) = &faces {
                let face_size = std::mem::size_of::<FaceUniform>() as u64;
                for (k, m) in f.view_proj.iter().enumerate() {
                    let p = light.position;
                    let u = FaceUniform {
                        view_proj: m.to_cols_array_2d(),
                        light: [p.x, p.y, p.z, f.far],
                        pad: [0.0; 44],
                    };
                    gpu.queue.write_buffer(
                        &self.face_buffer,
                        k as u64 * face_size,
                        bytemuck::bytes_of(&u),
                    );
                }
                let mut enc = new_encoder("shadow");
                for k in 0..f.view_proj.len() {
                    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                        label: Some("shadow face"),
                        color_attachments: &[],
                        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                            view: &self.shadow_layer_views[k],
                            depth_ops: Some(wgpu::Operations {
                                load: wgpu::LoadOp::Clear(1.0),
                                store: wgpu::StoreOp::Store,
                            }),
                            stencil_ops: None,
                        }),
                        timestamp_writes: None,
                        occlusion_query_set: None,
                        multiview_mask: None,
                    });
                    pass.set_pipeline(&self.shadow_pipeline);
                    pass.set_bind_group(0, &self.face_bgs[k], &[]);
                    pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
                    let total: u32 = self
                        .draws
                        .iter()
                        .map(|d| d.first + d.count)
                        .max()
                        .unwrap_or(0);
                    if total > 0 {
                        pass.draw(0..total, 0..1);
                    }
                }
                times.shadow_ms = submit(enc)?;
            }
        }

        {
            let mut enc = new_encoder("splat");
            {
                let accv = [view(&t.acc[0]), view(&t.acc[1]), view(&t.acc[2])];
                let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("splat"),
                    color_attachments: &[
                        clear_attachment(&accv[0]),
                        clear_attachment(&accv[1]),
                        clear_attachment(&accv[2]),
                    ],
                    depth_stencil_attachment: None,
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                if !self.visible.is_empty() {
                    pass.set_pipeline(&self.splat_pipeline);
                    pass.set_bind_group(0, &t.splat_bg, &[]);
                    pass.draw(0..4, 0..self.visible.len() as u32);
                }
            }
            times.splat_ms = submit(enc)?;
        }
        {
            let mut enc = new_encoder("resolve");
            {
                let (dv, iv, fv) = (view(&t.direct), view(&t.indirect), view(&t.final_));
                let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("resolve"),
                    color_attachments: &[
                        clear_attachment(&dv),
                        clear_attachment(&iv),
                        clear_attachment(&fv),
                    ],
                    depth_stencil_attachment: None,
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&self.resolve_pipeline);
                pass.set_bind_group(0, &t.resolve_bg, &[]);
                pass.draw(0..3, 0..1);
            }
            times.resolve_ms = submit(enc)?;
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        self.last_camera = Some(*camera);
        self.last_light = Some(*light);
        Ok(times)
    }

    /// Forgets the last light, so that the next frame redraws the shadow maps (after new
    /// coefficients for the same light, nothing else needs it).
    pub fn invalidate(&mut self) {
        self.last_light = None;
        self.last_camera = None;
    }

    /// Reads back direct, indirect and final linear radiance.
    pub fn read_buffers(&self, gpu: &Gpu) -> Result<Buffers, GpuError> {
        let t = self.rendered()?;
        Ok(Buffers {
            direct: read_rgb(gpu, t, &t.direct)?,
            indirect: read_rgb(gpu, t, &t.indirect)?,
            final_: read_rgb(gpu, t, &t.final_)?,
        })
    }

    /// Reads back the final linear radiance only (what tone mapping measures).
    pub fn read_final(&self, gpu: &Gpu) -> Result<RgbImage, GpuError> {
        let t = self.rendered()?;
        read_rgb(gpu, t, &t.final_)
    }

    fn rendered(&self) -> Result<&Targets, GpuError> {
        self.targets
            .as_ref()
            .ok_or_else(|| GpuError::Readback("nothing rendered yet".into()))
    }

    /// Reads back the G-buffer.
    pub fn read_gbuffer(&self, gpu: &Gpu) -> Result<GBuffer, GpuError> {
        let t = self.rendered()?;
        let p = read_rgba32f(gpu, &t.position)?;
        let n = read_rgba32f(gpu, &t.normal)?;
        let a = read_albedo(gpu, &t.albedo)?;
        Ok(GBuffer {
            width: t.width,
            height: t.height,
            position: p
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            normal: n.chunks_exact(4).map(|c| [c[0], c[1], c[2]]).collect(),
            albedo: a,
        })
    }

    fn display_pipeline(&mut self, gpu: &Gpu, format: wgpu::TextureFormat) -> usize {
        if let Some(k) = self
            .display_pipelines
            .iter()
            .position(|(f, _)| *f == format)
        {
            return k;
        }
        let p = pipeline(
            &gpu.device,
            PipelineSpec {
                label: "display",
                bind_groups: &[&self.display_layout],
                module: &self.display_module,
                vertex_buffers: &[],
                topology: wgpu::PrimitiveTopology::TriangleList,
                depth: None,
                targets: &[color_target(format, None)],
            },
        );
        self.display_pipelines.push((format, p));
        self.display_pipelines.len() - 1
    }

    fn points_pipeline(&mut self, gpu: &Gpu, format: wgpu::TextureFormat) -> usize {
        if let Some(k) = self.points_pipelines.iter().position(|(f, _)| *f == format) {
            return k;
        }
        let p = pipeline(
            &gpu.device,
            PipelineSpec {
                label: "points",
                bind_groups: &[&self.points_layout],
                module: &self.points_module,
                vertex_buffers: &[],
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                depth: depth_state(DEPTH_FORMAT, false, wgpu::CompareFunction::GreaterEqual),
                targets: &[color_target(format, None)],
            },
        );
        self.points_pipelines.push((format, p));
        self.points_pipelines.len() - 1
    }

    /// Draws `mode` into `target` (of the rendered size and `format`), tone mapped with
    /// `tone`; `level` picks the level of the points view. sRGB is encoded in the shader
    /// unless the format does it.
    #[allow(clippy::too_many_arguments)]
    pub fn display(
        &mut self,
        gpu: &Gpu,
        target_view: &wgpu::TextureView,
        format: wgpu::TextureFormat,
        tone: &ToneMap,
        mode: ViewMode,
        level: usize,
        flat_max_luminance: f32,
    ) -> Result<(), GpuError> {
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let k = self.display_pipeline(gpu, format);
        let kp = self.points_pipeline(gpu, format);
        let encode_srgb = if format.is_srgb() { 0.0 } else { 1.0 };
        let scale = tone.key / tone.log_average.max(f32::MIN_POSITIVE);
        let shown = if mode == ViewMode::Points {
            ViewMode::Final
        } else {
            mode
        };
        let u = DisplayUniform {
            params: [shown as u32 as f32, scale, scale * tone.white, encode_srgb],
            extra: [self.levels as f32, 0.0, 0.0, 0.0],
        };
        gpu.queue
            .write_buffer(&self.display_uniform, 0, bytemuck::bytes_of(&u));
        let level = level.min(self.levels.saturating_sub(1));
        let range = if self.levels == 0 {
            0..0
        } else {
            self.points.level_range(level)
        };
        let pu = PointsUniform {
            params: [
                range.start as f32,
                0.08,
                flat_max_luminance.max(1e-30).log10(),
                encode_srgb,
            ],
        };
        gpu.queue
            .write_buffer(&self.points_uniform, 0, bytemuck::bytes_of(&pu));
        let Some(t) = &self.targets else {
            return Err(GpuError::Validation("render before display".into()));
        };
        let depth_view = view(&t.depth);
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("display"),
            });
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("display"),
                color_attachments: &[clear_attachment(target_view)],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.display_pipelines[k].1);
            pass.set_bind_group(0, &t.display_bg, &[]);
            pass.draw(0..3, 0..1);
        }
        if mode == ViewMode::Points && !range.is_empty() {
            // The points over the image, depth-tested against the G-buffer's depth.
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("points"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.points_pipelines[kp].1);
            pass.set_bind_group(0, &self.points_bg, &[]);
            pass.draw(0..4, 0..range.len() as u32);
        }
        gpu.queue.submit([enc.finish()]);
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(GpuError::Validation(e.to_string())),
            None => Ok(()),
        }
    }
}

/// One RGBA32F target as an RGB image.
fn read_rgb(gpu: &Gpu, t: &Targets, tex: &wgpu::Texture) -> Result<RgbImage, GpuError> {
    let data = read_rgba32f(gpu, tex)?;
    Ok(RgbImage {
        width: t.width,
        height: t.height,
        pixels: data.chunks_exact(4).map(|c| [c[0], c[1], c[2]]).collect(),
    })
}

/// Reads the f16 albedo target (copies cannot convert formats, so the texels are converted
/// here).
fn read_albedo(gpu: &Gpu, texture: &wgpu::Texture) -> Result<Vec<[f32; 3]>, GpuError> {
    let raw = super::readback::read_raw(gpu, texture, 8)?;
    Ok(raw
        .chunks_exact(8)
        .map(|c| {
            let h = |k: usize| half::f16::from_le_bytes([c[2 * k], c[2 * k + 1]]).to_f32();
            [h(0), h(1), h(2)]
        })
        .collect())
}
