//! The buffers several passes bind: the scene's vertices, the per-frame globals, the flat
//! basis's points (position, flat radius, normal), their supports' clip planes, their flat
//! coefficients and the list of points that survive culling.

use bytemuck::{Pod, Zeroable};
use mlt_format::links::LINK_DIM;
use mlt_format::support_clip::SupportClip;
use mlt_format::Basis;
use wgpu::util::DeviceExt;

use super::mesh::{GpuMesh, Vertex};
use super::pipeline::{bind_group, layout, uniform_buffer, Slot, VS_FS};
use super::uniforms::Globals;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PointGpu {
    pos_r: [f32; 4],
    normal_level: [f32; 4],
    /// x: the exponent of the flat weights' normal factor (`FlatBasis::normal_power`); y, z:
    /// the bits of the `u32` index of the point's first clip plane and of their count; w:
    /// unused padding.
    weight_params: [f32; 4],
}

/// A clip plane as `mlt_format::support_clip::ClipPlane`, three `vec4`s.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ClipPlaneGpu {
    plane: [f32; 4],
    edge0: [f32; 4],
    edge1: [f32; 4],
}

/// The scene and the basis on the GPU.
pub struct SceneBuffers {
    /// The mesh's triangles, grouped by material ([`GpuMesh`]).
    pub vertices: wgpu::Buffer,
    /// Vertices drawn in all (the end of the last material's range).
    pub vertex_count: u32,
    /// [`Globals`], written once per frame.
    pub globals: wgpu::Buffer,
    pub globals_layout: wgpu::BindGroupLayout,
    pub globals_bg: wgpu::BindGroup,
    /// One `PointGpu` per flat basis point.
    pub points: wgpu::Buffer,
    /// The flat points' clip planes (`ClipPlaneGpu`; one zero plane when there are none).
    pub clip_planes: wgpu::Buffer,
    /// `LINK_DIM` flat coefficients per flat basis point.
    pub coefficients: wgpu::Buffer,
    /// Indices of the points to splat.
    pub visible: wgpu::Buffer,
}

impl SceneBuffers {
    /// The buffers of `mesh` and `basis`; each point's level is `levels[j]` when given (a flat
    /// basis' points: the level of the hierarchical point each one is), else its level in
    /// `basis`. `normal_power` is the exponent of the flat weights' normal factor; `clip`
    /// holds the points' clip planes.
    pub fn new(
        device: &wgpu::Device,
        mesh: &GpuMesh,
        (basis, clip): (&Basis, &SupportClip),
        levels: Option<&[u32]>,
        normal_power: f32,
    ) -> SceneBuffers {
        let vertex_bytes: &[u8] = if mesh.vertices.is_empty() {
            &[0u8; std::mem::size_of::<Vertex>()]
        } else {
            bytemuck::cast_slice(&mesh.vertices)
        };
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: vertex_bytes,
            usage: wgpu::BufferUsages::VERTEX,
        });
        let vertex_count = mesh
            .draws
            .iter()
            .map(|d| d.first_vertex + d.vertex_count)
            .max()
            .unwrap_or(0);
        let globals_layout = layout(device, "globals", &[Slot::Uniform(VS_FS)]);
        let globals = uniform_buffer(device, "globals", std::mem::size_of::<Globals>() as u64);
        let globals_bg = bind_group(
            device,
            "globals",
            &globals_layout,
            &[globals.as_entire_binding()],
        );
        let n = basis.len();
        let coefficients = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("flat coefficients"),
            size: (n.max(1) * LINK_DIM * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let visible = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("visible points"),
            size: (n.max(1) * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        SceneBuffers {
            vertices,
            vertex_count,
            globals,
            globals_layout,
            globals_bg,
            points: point_buffer(device, basis, clip, levels, normal_power),
            clip_planes: clip_buffer(device, clip),
            coefficients,
            visible,
        }
    }
}

fn point_buffer(
    device: &wgpu::Device,
    basis: &Basis,
    clip: &SupportClip,
    levels: Option<&[u32]>,
    normal_power: f32,
) -> wgpu::Buffer {
    let pts: Vec<PointGpu> = (0..basis.len())
        .map(|j| {
            let p = basis.positions[j];
            let nn = basis.normals[j];
            let level = levels.map_or(basis.level_of(j), |l| l[j] as usize);
            let (first, count) = if j + 1 < clip.offsets.len() {
                (clip.offsets[j], clip.offsets[j + 1] - clip.offsets[j])
            } else {
                (0, 0)
            };
            PointGpu {
                pos_r: [p[0], p[1], p[2], basis.radii[j]],
                normal_level: [nn[0], nn[1], nn[2], level as f32],
                weight_params: [
                    normal_power,
                    f32::from_bits(first),
                    f32::from_bits(count),
                    0.0,
                ],
            }
        })
        .collect();
    let point_bytes: Vec<u8> = if pts.is_empty() {
        vec![0u8; std::mem::size_of::<PointGpu>()]
    } else {
        bytemuck::cast_slice(&pts).to_vec()
    };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("basis points"),
        contents: &point_bytes,
        usage: wgpu::BufferUsages::STORAGE,
    })
}

fn clip_buffer(device: &wgpu::Device, clip: &SupportClip) -> wgpu::Buffer {
    let mut planes: Vec<ClipPlaneGpu> = clip
        .planes
        .iter()
        .map(|p| ClipPlaneGpu {
            plane: p.plane,
            edge0: p.edge0,
            edge1: p.edge1,
        })
        .collect();
    if planes.is_empty() {
        planes.push(ClipPlaneGpu::zeroed());
    }
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("clip planes"),
        contents: bytemuck::cast_slice(&planes),
        usage: wgpu::BufferUsages::STORAGE,
    })
}
