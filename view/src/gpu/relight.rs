//! Relighting with the transport resident on the GPU (section 3.3, the per-frame steps that
//! the paper notes "could potentially be implemented on the GPU"): [`GpuRelighter`] implements
//! [`Relight`] with wgpu compute passes that keep every per-frame array on the GPU:
//!
//! 1. the direct irradiance at the sender points as [`CpuRelighter::direct_stats`] computes it:
//!    jittered shadow rays toward a disk around the light, half first and the rest only in the
//!    penumbra, walked through a bounding volume hierarchy of the scene's triangles
//!    ([`super::bvh`]); the CPU supplies per frame only the light, the surface nearest it (the
//!    rays' clearance) and the support averages of the few points within a few support radii
//!    of it ([`CpuRelighter::near_light`]). An analytic sphere's rays are cast by the CPU and
//!    its samples uploaded;
//! 2. the pull-push `e = P-dagger E`, one pass per level (the pull from the second finest
//!    level up, the push of Eq. 7 from level 1 down), from [`mlt_relight::PullPushParts`];
//! 3. `i = S e` receiver-major over the file's half-float links uploaded once
//!    ([`TransposedLinks`]: nine half floats in five words and a 32-bit sender slot, 24 bytes a
//!    link), one workgroup
//!    per row; with the fine bounces from every sender point ([`FineEmission::Senders`]) the
//!    bounce light `y = P-dagger (n . R i)` (the reconstruction at the sender points, then the
//!    same pull-push) and the finer rows' `T_fine y`, or with the lagged feedback the previous
//!    frame's `y` added to `e` for the finer rows in the one product, as the CPU relighter does;
//! 4. the flattening and sharpening ([`GpuFlatten`]) from the resident `i` into the buffer the
//!    splatting pass reads.
//!
//! Sums run in another order than on the CPU (64 partial sums per row, added pairwise) and
//! senders are never skipped (the CPU path skips those below `skip_fraction` of the largest),
//! so the coefficients agree with [`CpuRelighter`]'s to single-precision rounding and that
//! skip, not bit for bit. The chained bounces of files baked with `--level0-paths 0` (the
//! bounce-light feedback, [`FineEmission::Level0`]) are not on the GPU: [`GpuRelighter::new`]
//! refuses such settings.

use std::time::Instant;

use mlt_format::flat_basis::FlatBasis;
use mlt_format::light_model::Cone;
use mlt_format::links::LINK_DIM;
use mlt_relight::{CpuRelighter, FineEmission, Frame, Light, Relight, StageTimes, TransposedLinks};
use wgpu::util::DeviceExt;

use super::context::{Gpu, GpuError};
use super::flatten::GpuFlatten;

const WORKGROUP: u32 = 64;
/// Timestamps a timed frame writes.
const STAMPS: u32 = 5;

/// An array the GPU relighter keeps on the GPU, readable with [`GpuRelighter::read`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpuArray {
    /// The sender coefficients `e` (RGB per sender point).
    Senders,
    /// The receiver coefficients `i` (9 per point).
    Receivers,
    /// The fine bounces' emission `y` of the last frame (RGB per sender point).
    Emission,
    /// The flat coefficients (9 per flat point).
    Flat,
}

/// One dispatch: a pipeline, its bindings and its grid.
struct Dispatch {
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    groups: (u32, u32),
}

impl Dispatch {
    /// Records the dispatch as a compute pass of its own (each pass reads what the one before
    /// wrote).
    fn encode(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("relight"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.dispatch_workgroups(self.groups.0, self.groups.1, 1);
    }
}

/// The compute pipelines, one per kernel.
struct Kernels {
    pull: wgpu::ComputePipeline,
    push: wgpu::ComputePipeline,
    weights: wgpu::ComputePipeline,
    transport: wgpu::ComputePipeline,
    reconstruct: wgpu::ComputePipeline,
    direct: wgpu::ComputePipeline,
}

impl Kernels {
    fn new(device: &wgpu::Device) -> Kernels {
        let make = |label: &str, src: &str| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        Kernels {
            pull: make("pull", include_str!("shaders/relight/pull.wgsl")),
            push: make("push", include_str!("shaders/relight/push.wgsl")),
            weights: make("weights", include_str!("shaders/relight/weights.wgsl")),
            transport: make("transport", include_str!("shaders/relight/transport.wgsl")),
            reconstruct: make(
                "reconstruct",
                include_str!("shaders/relight/reconstruct.wgsl"),
            ),
            direct: make("direct", include_str!("shaders/relight/direct.wgsl")),
        }
    }
}

/// The device's buffers and dispatch grids, with the bytes uploaded counted.
struct Builder<'g> {
    gpu: &'g Gpu,
    max_x: u32,
    max_binding: u64,
    bytes: u64,
}

impl Builder<'_> {
    /// A read-only storage buffer holding `data` (one word where it is empty).
    fn storage<T: bytemuck::Pod>(
        &mut self,
        label: &str,
        data: &[T],
    ) -> Result<wgpu::Buffer, GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let pad = [0u8; 4];
        let contents = if bytes.is_empty() { &pad[..] } else { bytes };
        if contents.len() as u64 > self.max_binding {
            return Err(GpuError::Validation(format!(
                "the relighting's {label} need a {}-byte storage buffer; the adapter allows {}",
                contents.len(),
                self.max_binding
            )));
        }
        self.bytes += contents.len() as u64;
        Ok(self
            .gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE,
            }))
    }

    /// A read-write storage buffer of `floats` floats that can be copied to and from.
    fn floats(&mut self, label: &str, floats: usize) -> wgpu::Buffer {
        let size = (floats.max(1) * 4) as u64;
        self.bytes += size;
        self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    }

    /// The grid of `workgroups` workgroups, and the workgroups per row of it.
    fn grid(&self, workgroups: u32) -> ((u32, u32), u32) {
        let w = workgroups.max(1);
        let x = w.min(self.max_x);
        ((x, w.div_ceil(x)), x)
    }

    /// A dispatch of `pipeline` over `items` items (64 per workgroup, or one workgroup each
    /// with `per_item`), its bindings `buffers` then a uniform of `params` whose word 2 is set
    /// to the invocations (or workgroups) per row of the grid.
    fn dispatch(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[&wgpu::Buffer],
        items: u32,
        per_item: bool,
        mut params: [u32; 8],
    ) -> Dispatch {
        let workgroups = if per_item {
            items
        } else {
            items.div_ceil(WORKGROUP)
        };
        let (groups, x) = self.grid(workgroups);
        params[2] = if per_item { x } else { x * WORKGROUP };
        let uniform = self
            .gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("relight params"),
                contents: bytemuck::cast_slice(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let mut resources: Vec<wgpu::BindingResource<'_>> =
            buffers.iter().map(|b| b.as_entire_binding()).collect();
        resources.push(uniform.as_entire_binding());
        let layout = pipeline.get_bind_group_layout(0);
        let bind_group =
            super::pipeline::bind_group(&self.gpu.device, "relight", &layout, &resources);
        Dispatch {
            pipeline: pipeline.clone(),
            bind_group,
            groups: if items == 0 { (0, 0) } else { groups },
        }
    }
}

/// The pull-push's arrays on the GPU, applied to a buffer of RGB per sender point.
struct Projection {
    /// Per level, the pulled parents' range (second finest level first).
    pull_levels: Vec<(u32, u32)>,
    /// Per level from 1 up, the push's rows' range.
    push_levels: Vec<(u32, u32)>,
    pull: [wgpu::Buffer; 5],
    push: [wgpu::Buffer; 5],
}

impl Projection {
    fn upload(b: &mut Builder<'_>, cpu: &CpuRelighter<'_>) -> Result<Projection, GpuError> {
        let (ib, _) = cpu.basis_and_links();
        let offsets = &ib.basis.level_offsets;
        let level = |j: u32| offsets.partition_point(|&o| o <= j) - 1;
        let p = cpu.pull_push_op().parts();
        // The pulled parents come level by level: split them into runs of one level.
        let runs = |items: &[u32]| {
            let mut out: Vec<(u32, u32)> = Vec::new();
            let mut start = 0usize;
            for k in 1..=items.len() {
                if k == items.len() || level(items[k]) != level(items[start]) {
                    if k > start {
                        out.push((start as u32, (k - start) as u32));
                    }
                    start = k;
                }
            }
            out
        };
        let pull_levels = runs(p.pull_parents);
        // The push's rows: one per point with segments, (point, first segment, end).
        let mut rows: Vec<u32> = Vec::new();
        let mut points: Vec<u32> = Vec::new();
        let mut s = 0usize;
        while s < p.push_points.len() {
            let j = p.push_points[s];
            let mut e = s + 1;
            while e < p.push_points.len() && p.push_points[e] == j {
                e += 1;
            }
            rows.extend([j, s as u32, e as u32]);
            points.push(j);
            s = e;
        }
        let push_levels = runs(&points);
        Ok(Projection {
            pull_levels,
            push_levels,
            pull: [
                b.storage("pull parents", p.pull_parents)?,
                b.storage("pull offsets", p.pull_offsets)?,
                b.storage("pull weight sums", p.pull_den)?,
                b.storage("pull children", p.pull_children)?,
                b.storage("pull weights", p.pull_weights)?,
            ],
            push: [
                b.storage("push rows", &rows)?,
                b.storage("push offsets", p.push_offsets)?,
                b.storage("push inverse sums", p.push_inv)?,
                b.storage("push points", p.push_ids)?,
                b.storage("push weights", p.push_weights)?,
            ],
        })
    }

    /// The dispatches that project `values` in place.
    fn dispatches(&self, b: &Builder<'_>, k: &Kernels, values: &wgpu::Buffer) -> Vec<Dispatch> {
        let mut out = Vec::new();
        for &(first, count) in &self.pull_levels {
            let [a, o, d, c, w] = &self.pull;
            out.push(b.dispatch(
                &k.pull,
                &[a, o, d, c, w, values],
                count,
                false,
                [first, count, 0, 0, 0, 0, 0, 0],
            ));
        }
        for &(first, count) in &self.push_levels {
            let [r, o, i, ids, w] = &self.push;
            out.push(b.dispatch(
                &k.push,
                &[r, o, i, ids, w, values],
                count,
                false,
                [first, count, 0, 0, 0, 0, 0, 0],
            ));
        }
        out
    }
}

/// `S` receiver-major on the GPU ([`TransposedLinks`]): per link a 32-bit sender slot and
/// nine half floats in five words (the tenth half zero, so that a link is five aligned loads),
/// the rows in chunks whose link values fit one storage buffer each.
struct Links {
    receiver_ids: wgpu::Buffer,
    row_offsets: wgpu::Buffer,
    sender_ids: wgpu::Buffer,
    scales: wgpu::Buffer,
    /// Stored sender slots.
    slots: u32,
    /// The first row of a finer receiver (the level-0 rows come first).
    first_fine: u32,
    chunks: Vec<LinkChunk>,
}

/// Rows `rows.0..rows.1` and their links, the first being link `base` of the whole.
struct LinkChunk {
    rows: (u32, u32),
    base: u32,
    slots: wgpu::Buffer,
    values: wgpu::Buffer,
}

impl Links {
    /// Uploads the links of `cpu`'s file, at most `max_links` links a chunk (`None`: as many
    /// as the adapter's largest storage buffer holds of the values' 20 bytes a link).
    fn upload(
        b: &mut Builder<'_>,
        cpu: &CpuRelighter<'_>,
        max_links: Option<u64>,
    ) -> Result<Links, GpuError> {
        let (ib, links) = cpu.basis_and_links();
        let t = TransposedLinks::build(links, |_, _| true);
        let words: Vec<u32> = t
            .values
            .iter()
            .flat_map(|v| {
                let h = |d: usize| u32::from(v.get(d).copied().unwrap_or(0));
                [0, 2, 4, 6, 8].map(|d| h(d) | (h(d + 1) << 16))
            })
            .collect();
        let rows = t.receiver_ids.len();
        let max_links = max_links.unwrap_or(b.max_binding / 20).max(1);
        let mut chunks = Vec::new();
        let mut start = 0usize;
        for q in 0..rows {
            let end_here =
                q + 1 == rows || u64::from(t.offsets[q + 2] - t.offsets[start]) > max_links;
            if end_here {
                let (a, e) = (t.offsets[start] as usize, t.offsets[q + 1] as usize);
                chunks.push(LinkChunk {
                    rows: (start as u32, (q + 1) as u32),
                    base: t.offsets[start],
                    slots: b.storage("sender slots", &t.slots[a..e])?,
                    values: b.storage("link values", &words[5 * a..5 * e])?,
                });
                start = q + 1;
            }
        }
        let m = ib.basis.level_range(0).len() as u32;
        Ok(Links {
            receiver_ids: b.storage("receivers", &t.receiver_ids)?,
            row_offsets: b.storage("row offsets", &t.offsets)?,
            sender_ids: b.storage("slot senders", &t.sender_ids)?,
            scales: b.storage("slot scales", &t.scales)?,
            slots: t.sender_ids.len() as u32,
            first_fine: t.receiver_ids.partition_point(|&r| r < m) as u32,
            chunks,
        })
    }

    /// The dispatches of the product over the rows from `first` on, one a chunk, into `i`
    /// (added with `add`), with the sender weights `w`; the rows of receivers below `m` take
    /// the first three weights of a slot.
    #[allow(clippy::too_many_arguments)]
    fn product(
        &self,
        b: &Builder<'_>,
        k: &Kernels,
        w: &wgpu::Buffer,
        i: &wgpu::Buffer,
        m: u32,
        first: u32,
        add: bool,
    ) -> Vec<Dispatch> {
        self.chunks
            .iter()
            .filter(|c| c.rows.1 > first)
            .map(|c| {
                let from = first.max(c.rows.0);
                b.dispatch(
                    &k.transport,
                    &[
                        &self.receiver_ids,
                        &self.row_offsets,
                        &c.slots,
                        &c.values,
                        w,
                        i,
                    ],
                    c.rows.1 - from,
                    true,
                    [from, c.rows.1, 0, m, u32::from(add), c.base, 0, 0],
                )
            })
            .collect()
    }
}

/// Step 1 on the GPU: the shadow rays through the scene's triangles, with the light's
/// parameters and the support averages near the light written per frame.
struct DirectPass {
    dispatch: Dispatch,
    /// The shader's `Params` (96 bytes), rewritten per frame.
    params: wgpu::Buffer,
    /// Room for one support average per sender point: `(sample, index)`.
    near: wgpu::Buffer,
    /// The shadow rays the pass cast (one word, cleared per frame; read by timed frames).
    rays: wgpu::Buffer,
    eps: f32,
}

impl DirectPass {
    /// Uploads the scene's triangles as a hierarchy and the sender points; `None` when the
    /// caster has no triangle mesh (an analytic sphere: the CPU casts its rays).
    fn upload(
        b: &mut Builder<'_>,
        k: &Kernels,
        cpu: &CpuRelighter<'_>,
        senders: usize,
        out: &wgpu::Buffer,
    ) -> Result<Option<DirectPass>, GpuError> {
        let caster = cpu.caster();
        let Some(mesh) = caster.triangle_mesh() else {
            return Ok(None);
        };
        let bvh = super::bvh::Bvh::build(&mesh.positions, &mesh.triangles);
        let (ib, _) = cpu.basis_and_links();
        let basis = &ib.basis;
        let points: Vec<[f32; 4]> = (0..senders)
            .map(|j| {
                let p = basis.positions[j];
                [p[0], p[1], p[2], basis.radii[j]]
            })
            .collect();
        let normals: Vec<[f32; 4]> = (0..senders)
            .map(|j| {
                let n = basis.normals[j];
                [n[0], n[1], n[2], basis.disk_radii[basis.level_of(j)]]
            })
            .collect();
        let used: Vec<u32> = cpu.sample_used()[..senders]
            .iter()
            .map(|&u| u32::from(u))
            .collect();
        let nodes = b.storage("direct hierarchy", &bvh.nodes)?;
        let corners = b.storage("direct triangles", &bvh.corners)?;
        let points = b.storage("direct points", &points)?;
        let normals = b.storage("direct normals", &normals)?;
        let used = b.storage("direct used", &used)?;
        let device = &b.gpu.device;
        let near = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("direct near-light samples"),
            size: (16 * senders.max(1)) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("direct params"),
            size: 96,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let rays = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("direct shadow rays"),
            size: 4,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        b.bytes += near.size() + params.size() + rays.size();
        let (groups, _) = b.grid((senders as u32).div_ceil(WORKGROUP));
        let resources: Vec<wgpu::BindingResource<'_>> = [
            &nodes, &corners, &points, &normals, &used, &near, out, &params, &rays,
        ]
        .iter()
        .map(|b| b.as_entire_binding())
        .collect();
        let layout = k.direct.get_bind_group_layout(0);
        let bind_group = super::pipeline::bind_group(device, "direct", &layout, &resources);
        Ok(Some(DirectPass {
            dispatch: Dispatch {
                pipeline: k.direct.clone(),
                bind_group,
                groups: if senders == 0 { (0, 0) } else { groups },
            },
            params,
            near,
            rays,
            eps: caster.ray_epsilon(),
        }))
    }

    /// Writes the frame's parameters for `light` (`cpu`'s rays and its near-light inputs).
    /// Returns the support averages written.
    fn prepare(&self, gpu: &Gpu, cpu: &CpuRelighter<'_>, light: &Light, senders: usize) -> usize {
        let mlt_relight::NearLight {
            clearance,
            samples: near,
        } = cpu.near_light(light);
        let f = f32::to_bits;
        let (kind, axis, cos_a, cos_b) = match light.cone {
            Cone::None => (0.0, glam::Vec3::ZERO, 0.0, 0.0),
            Cone::Hard { axis, cos_half } => (1.0, axis, cos_half, 0.0),
            Cone::Smooth {
                axis,
                cos_inner,
                cos_outer,
            } => (2.0, axis, cos_inner, cos_outer),
        };
        let (h, nc) = clearance.unwrap_or((-1.0, glam::Vec3::ZERO));
        let p = light.position;
        let i = light.intensity;
        let per_row = self.dispatch.groups.0 * WORKGROUP;
        let words: [u32; 24] = [
            f(p.x),
            f(p.y),
            f(p.z),
            f(kind),
            f(i[0]),
            f(i[1]),
            f(i[2]),
            f(self.eps),
            f(axis.x),
            f(axis.y),
            f(axis.z),
            f(cos_a),
            f(nc.x),
            f(nc.y),
            f(nc.z),
            f(h),
            senders as u32,
            cpu.shadow_rays(),
            per_row,
            u32::from(cpu.adaptive_shadows),
            near.len() as u32,
            f(cos_b),
            0,
            0,
        ];
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::cast_slice(&words));
        if !near.is_empty() {
            let entries: Vec<[u32; 4]> = near
                .iter()
                .map(|&(j, e)| [f(e[0]), f(e[1]), f(e[2]), j])
                .collect();
            gpu.queue
                .write_buffer(&self.near, 0, bytemuck::cast_slice(&entries));
        }
        near.len()
    }
}

/// The relighter: the CPU relighter for the direct light and the settings, the rest on the GPU.
pub struct GpuRelighter<'r, 'a> {
    cpu: &'r CpuRelighter<'a>,
    /// `E`, then in place `e` (RGB per sender point).
    senders_buf: wgpu::Buffer,
    /// The fine bounces' emission `y` (RGB per sender point).
    emission: wgpu::Buffer,
    /// `i` (9 per point).
    receivers_buf: wgpu::Buffer,
    /// The flat coefficients: the caller's buffer (the splatting pass's) or our own.
    flat_out: wgpu::Buffer,
    project_e: Vec<Dispatch>,
    project_y: Vec<Dispatch>,
    /// Sender weights in modes 0 (`e`), 1 (`e`, `e + y`) and 2 (`y` for the finer rows).
    weights: [Dispatch; 3],
    /// `S e` (or `T_fine y` added on the finer rows), one dispatch per chunk of rows.
    transport_all: Vec<Dispatch>,
    transport_fine: Vec<Dispatch>,
    reconstruct: Dispatch,
    flatten: GpuFlatten,
    /// Step 1 on the GPU, where the scene has triangles.
    direct: Option<DirectPass>,
    senders: usize,
    /// Stored sender slots: every one is applied (the GPU skips none).
    slots: usize,
    points: usize,
    flat_points: usize,
    fine_senders: bool,
    lagged: bool,
    /// The emission buffer holds the previous frame's `y` (lagged frames can use it).
    has_prev: bool,
    /// False after a lagged frame that took the `y` of another light: the same light again is
    /// relit once more, with its own.
    lag_settled: bool,
    /// The light of the last frame (whose `y` the emission buffer holds).
    last: Option<Light>,
    frame: Frame,
    /// Bytes uploaded and allocated on the GPU.
    pub bytes: u64,
    /// Time each stage: from timestamps the GPU writes between the stages where the device
    /// has them ([`GpuRelighter::clock`]), else by submitting each stage alone and waiting for
    /// it (wall clock); either way the frame waits for the GPU. Off, a frame is one submission
    /// that the GPU runs while the CPU goes on, and [`Frame::times`] holds only the direct
    /// light's time and the recording's.
    pub timed: bool,
    /// Five timestamps a frame (before and after the direct light, after the projection, after
    /// `S e`, after the flattening) and the buffer they resolve to, where the device writes
    /// them.
    stamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
}

impl<'r, 'a> GpuRelighter<'r, 'a> {
    /// Uploads the operators of `cpu` (configured as the frames should be: its fine bounces,
    /// lag and sharpening are followed) to `gpu`. The flat coefficients go to `output` (the
    /// splatting pass's coefficient buffer, 9 floats per flat point) or, without one, to a
    /// buffer of the relighter's own ([`GpuRelighter::read`] reads either). Fails for settings
    /// the GPU does not run (the bounce-light feedback, the level-0 emission), files whose
    /// receivers are not one per point, and operators larger than the adapter's buffers.
    pub fn new(
        gpu: &Gpu,
        cpu: &'r CpuRelighter<'a>,
        output: Option<&wgpu::Buffer>,
    ) -> Result<GpuRelighter<'r, 'a>, GpuError> {
        Self::with_link_chunks(gpu, cpu, output, None)
    }

    /// [`GpuRelighter::new`] with the links split into buffers of at most `max_links` links
    /// each (`None`: as many as the adapter's largest storage buffer holds), for tests of the
    /// split that large scenes need.
    pub fn with_link_chunks(
        gpu: &Gpu,
        cpu: &'r CpuRelighter<'a>,
        output: Option<&wgpu::Buffer>,
        max_links: Option<u64>,
    ) -> Result<GpuRelighter<'r, 'a>, GpuError> {
        Self::supports(cpu)?;
        let (ib, _) = cpu.basis_and_links();
        let points = ib.basis.len();
        let Some(op) = cpu.flatten_op() else {
            return Err(GpuError::Validation(
                "the flattening operator is too large for 32-bit offsets".into(),
            ));
        };
        let device = &gpu.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let kernels = Kernels::new(device);
        let mut b = Builder {
            gpu,
            max_x: device.limits().max_compute_workgroups_per_dimension.max(1),
            max_binding: device.limits().max_storage_buffer_binding_size,
            bytes: 0,
        };
        let senders = cpu.pull_push_op().parts().points;
        let m = ib.basis.level_range(0).len() as u32;
        let links = Links::upload(&mut b, cpu, max_links)?;
        let projection = Projection::upload(&mut b, cpu)?;
        let senders_buf = b.floats("sender coefficients", 3 * senders);
        let emission = b.floats("bounce emission", 3 * senders);
        let w = b.floats("sender weights", 6 * links.slots as usize);
        let receivers_buf = b.floats("receiver coefficients", LINK_DIM * points);
        let flat_points = op.points();
        let flat_out = match output {
            Some(o) => o.clone(),
            None => b.floats("flat coefficients", LINK_DIM * flat_points),
        };
        let weights = [0u32, 1, 2].map(|mode| {
            b.dispatch(
                &kernels.weights,
                &[
                    &links.sender_ids,
                    &links.scales,
                    &senders_buf,
                    &emission,
                    &w,
                ],
                links.slots,
                false,
                [links.slots, mode, 0, 0, 0, 0, 0, 0],
            )
        });
        let transport_all = links.product(&b, &kernels, &w, &receivers_buf, m, 0, false);
        let transport_fine =
            links.product(&b, &kernels, &w, &receivers_buf, m, links.first_fine, true);
        let reconstruct = reconstruction(&mut b, &kernels, cpu, &receivers_buf, &emission)?;
        let direct = DirectPass::upload(&mut b, &kernels, cpu, senders, &senders_buf)?;
        let project_e = projection.dispatches(&b, &kernels, &senders_buf);
        let project_y = projection.dispatches(&b, &kernels, &emission);
        let sharpen = cpu.sharpen_operator();
        let flatten = GpuFlatten::with_input(gpu, op, sharpen, Some(&receivers_buf), &flat_out)?;
        let bytes = b.bytes + flatten.bytes;
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Validation(e.to_string()));
        }
        Ok(GpuRelighter {
            cpu,
            senders_buf,
            emission,
            receivers_buf,
            flat_out,
            project_e,
            project_y,
            weights,
            transport_all,
            transport_fine,
            reconstruct,
            flatten,
            direct,
            senders,
            slots: links.slots as usize,
            points,
            flat_points,
            fine_senders: cpu.fine_bounces,
            lagged: cpu.lagged_feedback && cpu.fine_bounces,
            has_prev: false,
            lag_settled: true,
            last: None,
            frame: Frame::default(),
            bytes,
            timed: false,
            stamps: timestamps(gpu),
        })
    }

    /// Whether step 1 (the direct light's shadow rays) runs on the GPU: where the scene has
    /// triangles (an analytic sphere's rays are cast by the CPU).
    pub fn direct_on_gpu(&self) -> bool {
        self.direct.is_some()
    }

    /// Whether to relight on `gpu`: as `choice` says, or without one (`--relight auto`) unless
    /// the adapter is a software rasteriser (where the CPU path is faster) or the GPU does not
    /// run `cpu`'s settings ([`GpuRelighter::supports`]; an explicit choice then fails with its
    /// reason in [`GpuRelighter::new`]).
    pub fn chosen(choice: Option<bool>, gpu: &Gpu, cpu: &CpuRelighter<'_>) -> bool {
        choice.unwrap_or_else(|| !gpu.is_software() && Self::supports(cpu).is_ok())
    }

    /// Whether the GPU runs `cpu`'s settings and file: an error naming what it does not run
    /// (the bounce-light feedback, the level-0 emission, a file whose receivers are not one per
    /// point, a flattening operator too large for 32-bit offsets).
    pub fn supports(cpu: &CpuRelighter<'_>) -> Result<(), GpuError> {
        let unsupported = |what: &str| {
            Err(GpuError::Validation(format!(
                "{what} is not on the GPU relighter yet (use --relight cpu)"
            )))
        };
        if cpu.bounce_feedback > 0 {
            return unsupported("the bounce-light feedback (files baked with --level0-paths 0)");
        }
        if cpu.fine_bounces && cpu.fine_emission == FineEmission::Level0 {
            return unsupported("the level-0 emission of the fine bounces");
        }
        let (ib, links) = cpu.basis_and_links();
        if links.receivers.to_native() as usize != ib.basis.len() {
            return unsupported("a file whose receivers are not its points");
        }
        if cpu.flatten_op().is_none() {
            return unsupported("a flattening operator too large for 32-bit offsets");
        }
        Ok(())
    }

    /// Reads one of the resident arrays back (waits for the GPU; for tests and diagnostics).
    pub fn read(&self, gpu: &Gpu, array: GpuArray) -> Result<Vec<f32>, GpuError> {
        let (buffer, count) = match array {
            GpuArray::Senders => (&self.senders_buf, 3 * self.senders),
            GpuArray::Receivers => (&self.receivers_buf, LINK_DIM * self.points),
            GpuArray::Emission => (&self.emission, 3 * self.senders),
            GpuArray::Flat => (&self.flat_out, LINK_DIM * self.flat_points),
        };
        super::readback::read_buffer_f32(gpu, buffer, count)
    }

    /// How [`GpuRelighter::timed`] frames time the GPU's stages (the CPU's part of the direct
    /// light, its near-light inputs, is timed by the wall clock and added to it).
    pub fn clock(&self) -> &'static str {
        if self.stamps.is_some() {
            "GPU timestamps between the stages (the direct light's CPU part by the wall clock, added)"
        } else {
            "wall clock, each stage submitted alone and waited for"
        }
    }

    /// Flat points whose coefficients a frame computes (all of them).
    pub fn frame_flat_rows(&self) -> usize {
        self.flat_points
    }

    /// Relights for `light` on `gpu`: the CPU's near-light inputs (or, without triangles, the
    /// whole direct light) written, then every stage's passes submitted, waited for only when
    /// [`GpuRelighter::timed`]. When the light has not moved, nothing is recomputed.
    pub fn relight_on(&mut self, gpu: &Gpu, light: &Light) -> Result<&Frame, GpuError> {
        if self.last.as_ref() == Some(light) && self.lag_settled {
            self.frame.reused = true;
            return Ok(&self.frame);
        }
        let mut times = StageTimes::default();
        let t = Instant::now();
        let (shadow_rays, averaged_points) = match &self.direct {
            Some(d) => (0, d.prepare(gpu, self.cpu, light, self.senders) as u64),
            None => {
                let (direct, rays, averaged) = self.cpu.direct_stats(light);
                gpu.queue
                    .write_buffer(&self.senders_buf, 0, bytemuck::cast_slice(&direct));
                (rays, averaged)
            }
        };
        times.direct_ms = ms(t);
        // Step 3, as CpuRelighter::relight orders it.
        let lag = self.lagged && self.has_prev;
        self.lag_settled = !lag || self.last.as_ref() == Some(light);
        let emission = || std::iter::once(&self.reconstruct).chain(&self.project_y);
        // With the lag, `S_0 e` on the level-0 rows and `T_fine (e + y)` on the finer rows with
        // the last frame's `y`; without, `S e` then the finer rows' `T_fine y` of its `y`.
        let mut transport: Vec<&Dispatch> = std::iter::once(&self.weights[usize::from(lag)])
            .chain(&self.transport_all)
            .collect();
        if self.fine_senders {
            transport.extend(emission());
            if !lag {
                transport.push(&self.weights[2]);
                transport.extend(&self.transport_fine);
                if self.lagged {
                    // The next frame's `y`, as a lagged frame's: from the whole `i`.
                    transport.extend(emission());
                }
            }
        }
        let stamps = self.stamps.as_ref().filter(|_| self.timed);
        // Submitting each stage alone is the wall clock's way; timestamps need one submission.
        let per_stage = self.timed && stamps.is_none();
        let mut enc = encoder(gpu);
        let stamp = |enc: &mut wgpu::CommandEncoder, k: u32| {
            if let Some((set, _)) = stamps {
                enc.write_timestamp(set, k);
            }
        };
        stamp(&mut enc, 0);
        if let Some(d) = &self.direct {
            let t = Instant::now();
            enc.clear_buffer(&d.rays, 0, None);
            d.dispatch.encode(&mut enc);
            times.direct_ms += stage_end(gpu, per_stage, &mut enc, t)?;
        }
        stamp(&mut enc, 1);
        let t = Instant::now();
        for d in &self.project_e {
            d.encode(&mut enc);
        }
        stamp(&mut enc, 2);
        times.project_ms = stage_end(gpu, per_stage, &mut enc, t)?;
        let t = Instant::now();
        enc.clear_buffer(&self.receivers_buf, 0, None);
        for d in transport {
            d.encode(&mut enc);
        }
        stamp(&mut enc, 3);
        times.transport_ms = stage_end(gpu, per_stage, &mut enc, t)?;
        let t = Instant::now();
        self.flatten.encode_resident(&mut enc);
        stamp(&mut enc, 4);
        times.flatten_ms = stage_end(gpu, per_stage, &mut enc, t)?;
        if let Some((set, resolved)) = stamps {
            enc.resolve_query_set(set, 0..STAMPS, resolved, 0);
        }
        gpu.queue.submit([enc.finish()]);
        let mut shadow_rays = shadow_rays;
        if let Some(d) = self.direct.as_ref().filter(|_| self.timed) {
            // Timed frames wait for the GPU anyway: the ray count comes with them.
            let counted = super::readback::read_buffer::<u32>(gpu, &d.rays, 1)?;
            shadow_rays = u64::from(counted.first().copied().unwrap_or(0));
        }
        if let Some((_, resolved)) = stamps {
            let ticks = super::readback::read_buffer::<u64>(gpu, resolved, STAMPS as usize)?;
            let ns = f64::from(gpu.queue.get_timestamp_period());
            let ms = |a: usize, b: usize| ticks[b].saturating_sub(ticks[a]) as f64 * ns * 1e-6;
            if self.direct.is_some() {
                times.direct_ms += ms(0, 1);
            }
            times.project_ms = ms(1, 2);
            times.transport_ms = ms(2, 3);
            times.flatten_ms = ms(3, 4);
        }
        // `lagged` implies the fine bounces, whose emission this frame left for the next.
        self.has_prev = self.lagged;
        self.frame = Frame {
            times,
            shadow_rays,
            averaged_points,
            senders_used: self.slots,
            flat_rows: self.flat_points,
            reused: false,
            ..Frame::default()
        };
        self.last = Some(*light);
        Ok(&self.frame)
    }

    /// The flat basis whose coefficients the flattening writes.
    pub fn flat_basis(&self) -> &FlatBasis {
        self.cpu.flat_basis()
    }
}

/// The reconstruction at the sender points (`R i` along their normals, the first half of the
/// fine bounces' emission) from `i` into `emission`, over `cpu`'s precomputed basis values.
fn reconstruction(
    b: &mut Builder<'_>,
    k: &Kernels,
    cpu: &CpuRelighter<'_>,
    i: &wgpu::Buffer,
    emission: &wgpu::Buffer,
) -> Result<Dispatch, GpuError> {
    let r = cpu.feedback_op().parts();
    let senders = r.normals.len() as u32;
    let normals = b.storage("sender normals", r.normals.as_flattened())?;
    let offsets = b.storage("reconstruction offsets", r.offsets)?;
    let columns = b.storage("reconstruction columns", r.columns)?;
    let weights = b.storage("reconstruction weights", r.weights)?;
    Ok(b.dispatch(
        &k.reconstruct,
        &[&normals, &offsets, &columns, &weights, i, emission],
        senders,
        false,
        [senders, 0, 0, 0, 0, 0, 0, 0],
    ))
}

/// The query set of a timed frame's [`STAMPS`] timestamps and the buffer they resolve to,
/// where the device writes timestamps between commands.
fn timestamps(gpu: &Gpu) -> Option<(wgpu::QuerySet, wgpu::Buffer)> {
    gpu.report.timestamps.then(|| {
        let set = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("relight stages"),
            ty: wgpu::QueryType::Timestamp,
            count: STAMPS,
        });
        let resolved = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relight stage times"),
            size: u64::from(STAMPS) * 8,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        (set, resolved)
    })
}

fn encoder(gpu: &Gpu) -> wgpu::CommandEncoder {
    gpu.device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("relight"),
        })
}

/// The end of a stage begun at `t`: with `timed`, what `enc` recorded is submitted and waited
/// for (and `enc` is a new encoder), so the time is the stage's wall time; without, only the
/// recording's.
fn stage_end(
    gpu: &Gpu,
    timed: bool,
    enc: &mut wgpu::CommandEncoder,
    t: Instant,
) -> Result<f64, GpuError> {
    if timed {
        let done = std::mem::replace(enc, encoder(gpu));
        gpu.queue.submit([done.finish()]);
        gpu.wait()?;
    }
    Ok(ms(t))
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// [`Relight`] for a GPU relighter bound to its device: the frame's arrays stay on the GPU
/// (`Frame::direct`, `e`, `i` and `flat` are empty; [`GpuRelighter::read`] reads them), and the
/// flat coefficients are already where the splatting pass reads them, so the renderer neither
/// uploads nor flattens (no [`Relight::flatten_operator`]).
pub struct BoundGpuRelighter<'g, 'x, 'r, 'a> {
    pub gpu: &'g Gpu,
    pub relighter: &'x mut GpuRelighter<'r, 'a>,
    /// The last error of a frame (a frame that failed is returned as the one before).
    pub error: Option<GpuError>,
}

impl Relight for BoundGpuRelighter<'_, '_, '_, '_> {
    fn relight(&mut self, light: &Light) -> &Frame {
        if let Err(e) = self.relighter.relight_on(self.gpu, light) {
            self.error = Some(e);
        }
        &self.relighter.frame
    }

    fn flat_basis(&self) -> &FlatBasis {
        self.relighter.flat_basis()
    }
}
