//! The boilerplate every render pass shares: shader modules (each with `shaders/common.wgsl`
//! prepended), bind-group layouts and groups, the one render-pipeline helper, per-format
//! pipeline caches for passes that draw into a caller's target, and attachments.

use super::mesh::Vertex;

const COMMON: &str = include_str!("shaders/common.wgsl");

/// A shader module of `src` with the shared declarations of `common.wgsl` before it.
pub fn module(device: &wgpu::Device, label: &str, src: &str) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(format!("{COMMON}\n{src}").into()),
    })
}

/// Vertex and fragment stages: where most bindings are visible.
pub const VS_FS: wgpu::ShaderStages = wgpu::ShaderStages::VERTEX_FRAGMENT;

/// A binding of a bind-group layout; [`layout`] numbers them in order.
#[derive(Clone, Copy, Debug)]
pub enum Slot {
    /// A uniform buffer.
    Uniform(wgpu::ShaderStages),
    /// A read-only storage buffer.
    Storage(wgpu::ShaderStages),
    /// This many unfilterable 2-D float textures of the fragment stage.
    Textures(u32),
    /// A filterable 2-D float texture of the fragment stage.
    FilteredTexture,
    /// A 2-D array of depth textures of the fragment stage.
    DepthArray,
    /// A sampler of the fragment stage.
    Sampler(wgpu::SamplerBindingType),
}

/// A bind-group layout of `slots`, numbered from 0.
pub fn layout(device: &wgpu::Device, label: &str, slots: &[Slot]) -> wgpu::BindGroupLayout {
    let buffer = |ty| wgpu::BindingType::Buffer {
        ty,
        has_dynamic_offset: false,
        min_binding_size: None,
    };
    let texture = |sample_type, view_dimension| wgpu::BindingType::Texture {
        sample_type,
        view_dimension,
        multisampled: false,
    };
    let float = |filterable| wgpu::TextureSampleType::Float { filterable };
    let (d2, fragment) = (wgpu::TextureViewDimension::D2, wgpu::ShaderStages::FRAGMENT);
    let mut entries: Vec<wgpu::BindGroupLayoutEntry> = Vec::new();
    let mut push = |visibility, ty| {
        entries.push(wgpu::BindGroupLayoutEntry {
            binding: entries.len() as u32,
            visibility,
            ty,
            count: None,
        })
    };
    for slot in slots {
        match *slot {
            Slot::Uniform(vis) => push(vis, buffer(wgpu::BufferBindingType::Uniform)),
            Slot::Storage(vis) => push(
                vis,
                buffer(wgpu::BufferBindingType::Storage { read_only: true }),
            ),
            Slot::Textures(n) => (0..n).for_each(|_| push(fragment, texture(float(false), d2))),
            Slot::FilteredTexture => push(fragment, texture(float(true), d2)),
            Slot::DepthArray => push(
                fragment,
                texture(
                    wgpu::TextureSampleType::Depth,
                    wgpu::TextureViewDimension::D2Array,
                ),
            ),
            Slot::Sampler(ty) => push(fragment, wgpu::BindingType::Sampler(ty)),
        }
    }
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    })
}

/// A bind group whose binding `k` is `resources[k]`.
pub fn bind_group(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    resources: &[wgpu::BindingResource<'_>],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
        .iter()
        .enumerate()
        .map(|(k, resource)| wgpu::BindGroupEntry {
            binding: k as u32,
            resource: resource.clone(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

/// The layout of a pass's bind group that holds render targets, and the group for the
/// current ones (made again by [`TargetBinding::bind`] when the targets change).
pub struct TargetBinding {
    label: &'static str,
    layout: wgpu::BindGroupLayout,
    group: Option<wgpu::BindGroup>,
}

impl TargetBinding {
    /// A layout of `slots`, nothing bound yet.
    pub fn new(device: &wgpu::Device, label: &'static str, slots: &[Slot]) -> TargetBinding {
        TargetBinding {
            label,
            layout: layout(device, label, slots),
            group: None,
        }
    }

    pub fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// Binds `resources` (binding `k` is `resources[k]`), replacing the previous group.
    pub fn bind(&mut self, device: &wgpu::Device, resources: &[wgpu::BindingResource<'_>]) {
        self.group = Some(bind_group(device, self.label, &self.layout, resources));
    }

    /// The group, once bound.
    pub fn group(&self) -> Option<&wgpu::BindGroup> {
        self.group.as_ref()
    }
}

/// A uniform buffer of `size` bytes, written with `Queue::write_buffer`.
pub fn uniform_buffer(device: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// The default view of a whole texture.
pub fn view(t: &wgpu::Texture) -> wgpu::TextureView {
    t.create_view(&wgpu::TextureViewDescriptor::default())
}

pub fn color_target(
    format: wgpu::TextureFormat,
    blend: Option<wgpu::BlendState>,
) -> Option<wgpu::ColorTargetState> {
    Some(wgpu::ColorTargetState {
        format,
        blend,
        write_mask: wgpu::ColorWrites::ALL,
    })
}

/// Blending that adds the fragment to the target (the splat sums).
pub fn additive() -> wgpu::BlendState {
    let c = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Add,
    };
    wgpu::BlendState { color: c, alpha: c }
}

/// A depth test (and write) against `format`.
pub fn depth_state(
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

/// What differs between the renderer's pipelines.
pub struct PipelineSpec<'a> {
    pub label: &'a str,
    pub bind_groups: Vec<&'a wgpu::BindGroupLayout>,
    pub module: &'a wgpu::ShaderModule,
    pub vertex_buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
    pub topology: wgpu::PrimitiveTopology,
    pub depth: Option<wgpu::DepthStencilState>,
    pub targets: &'a [Option<wgpu::ColorTargetState>],
}

impl<'a> PipelineSpec<'a> {
    /// A pipeline of one bind group that makes its primitives in the vertex shader (a
    /// full-screen triangle, instanced quads): no vertex buffers and no depth test.
    pub fn procedural(
        label: &'a str,
        layout: &'a wgpu::BindGroupLayout,
        module: &'a wgpu::ShaderModule,
        topology: wgpu::PrimitiveTopology,
        targets: &'a [Option<wgpu::ColorTargetState>],
    ) -> PipelineSpec<'a> {
        PipelineSpec {
            label,
            bind_groups: vec![layout],
            module,
            vertex_buffers: &[],
            topology,
            depth: None,
            targets,
        }
    }
}

/// The layout of the mesh's vertex buffer ([`Vertex`]) with the attributes a shader reads.
pub fn vertex_layout(attributes: &[wgpu::VertexAttribute]) -> wgpu::VertexBufferLayout<'_> {
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes,
    }
}

/// A render pipeline with entry points `vs` and `fs` of one module.
pub fn pipeline(device: &wgpu::Device, spec: PipelineSpec<'_>) -> wgpu::RenderPipeline {
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

/// The pipelines of a pass that draws into targets of the caller's format (a window's
/// surface, an image), made on first use of each format.
#[derive(Default)]
pub struct PerFormat {
    pipelines: Vec<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
}

impl PerFormat {
    /// The pipeline for `format`, made by `make` the first time.
    pub fn get(
        &mut self,
        format: wgpu::TextureFormat,
        make: impl FnOnce(wgpu::TextureFormat) -> wgpu::RenderPipeline,
    ) -> &wgpu::RenderPipeline {
        let k = match self.pipelines.iter().position(|(f, _)| *f == format) {
            Some(k) => k,
            None => {
                self.pipelines.push((format, make(format)));
                self.pipelines.len() - 1
            }
        };
        &self.pipelines[k].1
    }
}

/// A colour attachment cleared to transparent black and stored.
pub fn clear_attachment(v: &wgpu::TextureView) -> Option<wgpu::RenderPassColorAttachment<'_>> {
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

/// A depth attachment loaded with `load` and stored.
pub fn depth_attachment(
    v: &wgpu::TextureView,
    load: wgpu::LoadOp<f32>,
) -> Option<wgpu::RenderPassDepthStencilAttachment<'_>> {
    Some(wgpu::RenderPassDepthStencilAttachment {
        view: v,
        depth_ops: Some(wgpu::Operations {
            load,
            store: wgpu::StoreOp::Store,
        }),
        stencil_ops: None,
    })
}

/// Begins a render pass into `colors` and `depth`.
pub fn begin<'e>(
    enc: &'e mut wgpu::CommandEncoder,
    label: &str,
    colors: &[Option<wgpu::RenderPassColorAttachment<'_>>],
    depth: Option<wgpu::RenderPassDepthStencilAttachment<'_>>,
) -> wgpu::RenderPass<'e> {
    enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: colors,
        depth_stencil_attachment: depth,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

#[cfg(test)]
mod tests {
    use super::COMMON;

    /// The value of `const NAME: f32 = VALUE;` in `common.wgsl`.
    fn wgsl_constant(name: &str) -> f32 {
        let start = format!("const {name}: f32 = ");
        let line = COMMON
            .lines()
            .find_map(|l| l.strip_prefix(&start))
            .unwrap_or_else(|| panic!("no {name} in common.wgsl"));
        line.trim_end_matches(';').trim().parse().unwrap()
    }

    #[test]
    fn the_shaders_constants_are_the_libraries() {
        assert_eq!(wgsl_constant("F_SQUASH"), mlt_format::kernel::F_SQUASH);
        assert_eq!(
            wgsl_constant("MIN_WEIGHT_SUM"),
            mlt_format::shepard::MIN_WEIGHT_SUM
        );
        assert_eq!(
            wgsl_constant("FLAT_NORMAL_FLOOR"),
            mlt_format::flat_basis::FLAT_NORMAL_FLOOR
        );
    }
}
