//! The interactive window (winit + wgpu): a fly or orbit camera, a light moved with keys or
//! by dragging, view modes, screenshots, and a title-bar readout of frame rate and stage
//! timings. Relighting runs only when the light moved; the G-buffer only when the camera did.
//!
//! Controls: mouse drag (left) turns the camera, W/A/S/D/Q/E move it (Shift: faster), O
//! toggles fly and orbit; right drag or I/J/K/L/U/N move the light; V cycles the views (final,
//! direct, indirect, level used, basis points), [ and ] pick the level of the points view;
//! H toggles shadows; P saves a screenshot (PNG of the view, EXR of the linear buffers) in the
//! working directory; R resets camera and light; Esc quits.

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use glam::{Quat, Vec3};
use mlt_format::IndexedBasis;
use mlt_relight::{CpuRelighter, Light, Relight, StageTimes};
use mlt_scenes::Scene;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use crate::camera::Camera;
use crate::frame::{FrameDriver, Redraw};
use crate::gpu::mesh::GpuMesh;
use crate::gpu::{BoundGpuRelighter, Gpu, GpuRelighter, Renderer, ViewMode};
use crate::headless::{light_on_path, median};
use crate::images::{luminance, ToneMap};

/// Where the window's relighting runs.
pub enum Relighting<'a, 'b> {
    /// On the CPU; with [`WindowSetup::gpu_relight`] the window moves it to the GPU once its
    /// device is up.
    Cpu(&'a mut CpuRelighter<'b>),
    /// On the GPU, from this CPU relighter's direct light and operators.
    Gpu(Box<GpuRelighter<'a, 'b>>),
    /// Only while the window moves the relighter from the CPU to the GPU.
    Moving,
}

impl Relighting<'_, '_> {
    fn flat_basis(&self) -> Option<&mlt_format::flat_basis::FlatBasis> {
        match self {
            Relighting::Cpu(c) => Some(c.flat_basis()),
            Relighting::Gpu(g) => Some(g.flat_basis()),
            Relighting::Moving => None,
        }
    }
}

/// What the window starts from.
pub struct WindowSetup<'a, 'b> {
    pub title: String,
    pub scene: &'a Scene,
    pub ib: &'a IndexedBasis,
    pub relighter: Relighting<'a, 'b>,
    /// Relight on the GPU after the direct light ([`GpuRelighter`]): `Some(true)`, `Some(false)`,
    /// or `None` for "unless the adapter is a software rasteriser".
    pub gpu_relight: Option<bool>,
    /// Sum the splats in 16-bit floats.
    pub half_splat: bool,
    pub camera: Camera,
    pub light: Light,
    pub bounds: (Vec3, Vec3),
    pub shadow_res: u32,
    /// Flatten in a GPU compute pass (when the relighter has the operator): `Some(true)`,
    /// `Some(false)`, or `None` for "unless the adapter is a software rasteriser".
    pub gpu_flatten: Option<bool>,
    /// For scripts and tests: after this many frames, save a screenshot of every view mode
    /// (`window-MODE.png` in `screenshot_dir`) and close.
    pub exit_after_frames: Option<u32>,
    pub screenshot_dir: std::path::PathBuf,
    /// For measurements: move the light every frame along a horizontal circle of this radius
    /// around its position (the path of `view render --frames`, 60 frames a turn), so that
    /// every frame relights and splats.
    pub moving_light: Option<f32>,
}

/// Seconds between two measurements of the tone map while the view changes.
const TONE_INTERVAL_S: f64 = 0.25;

/// Frames a turn of [`WindowSetup::moving_light`].
const LIGHT_PATH_FRAMES: u32 = 60;

/// True when a display server can be reached (this build talks X11; Wayland sessions provide
/// it through XWayland).
pub fn display_available() -> bool {
    std::env::var_os("DISPLAY").is_some_and(|d| !d.is_empty())
}

/// Opens the window and runs until it is closed.
pub fn run(setup: WindowSetup<'_, '_>) -> Result<()> {
    if !display_available() {
        bail!(
            "no display: DISPLAY is not set, so no window can open. Render to files instead with \
             `view render FILE --out DIR` (or start an X server, e.g. xvfb-run)"
        );
    }
    let event_loop = EventLoop::new().map_err(|e| {
        anyhow!("cannot open the display ({e}); render to files instead with `view render FILE --out DIR`")
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        start_camera: setup.camera,
        start_light: setup.light,
        setup,
        state: None,
        error: None,
    };
    event_loop
        .run_app(&mut app)
        .context("the window's event loop")?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

struct App<'a, 'b> {
    setup: WindowSetup<'a, 'b>,
    start_camera: Camera,
    start_light: Light,
    state: Option<State>,
    error: Option<anyhow::Error>,
}

struct State {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    renderer: Renderer,
    /// The relighter's flat basis (what the renderer culls and splats).
    flat: IndexedBasis,
    camera: Camera,
    light: Light,
    orbit: bool,
    mode: ViewMode,
    level: usize,
    keys: HashSet<KeyCode>,
    drag: Option<(MouseButton, (f64, f64))>,
    cursor: (f64, f64),
    tone: ToneMap,
    tone_dirty: bool,
    /// When the tone map was last measured: while the view changes it is measured again at
    /// most every [`TONE_INTERVAL_S`], because measuring reads the image back and so waits for
    /// the GPU, which would keep the CPU's relighting from overlapping the GPU's passes.
    tone_measured: Option<Instant>,
    last_tick: Instant,
    frame_times: Vec<f64>,
    /// Every frame's time, for the median printed when the window closes by itself.
    all_frame_times: Vec<f64>,
    stage: StageTimes,
    flat_max: f32,
    screenshots: u32,
    frames: u32,
    scale: f32,
}

impl App<'_, '_> {
    fn init(&mut self, event_loop: &ActiveEventLoop) -> Result<State> {
        let cam = self.setup.camera;
        let attrs = Window::default_attributes()
            .with_title(self.setup.title.clone())
            .with_inner_size(winit::dpi::PhysicalSize::new(cam.width, cam.height));
        let window = Arc::new(
            event_loop
                .create_window(attrs)
                .context("creating the window")?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(
                Box::new(event_loop.owned_display_handle()),
            ));
        let surface = instance
            .create_surface(window.clone())
            .context("creating the window's surface")?;
        let gpu = Gpu::with_instance(instance, Some(&surface))?;
        let size = window.inner_size();
        let caps = surface.get_capabilities(&gpu.adapter);
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| f.is_srgb())
            .or_else(|| caps.formats.first().copied())
            .context("the surface offers no format")?;
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            color_space: wgpu::SurfaceColorSpace::Auto,
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode: wgpu::PresentMode::AutoVsync,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
        };
        surface.configure(&gpu.device, &config);
        let mesh = GpuMesh::from_scene(self.setup.scene);
        let fb = self
            .setup
            .relighter
            .flat_basis()
            .context("the relighter is being moved")?;
        let hier = &self.setup.ib.basis;
        let mut renderer = Renderer::for_flat(&gpu, &mesh, fb, hier, self.setup.shadow_res)?;
        renderer.set_half_precision_splat(&gpu, self.setup.half_splat);
        let flat = fb.ib.clone();
        match std::mem::replace(&mut self.setup.relighter, Relighting::Moving) {
            Relighting::Cpu(cpu) if GpuRelighter::chosen(self.setup.gpu_relight, &gpu, cpu) => {
                let g = GpuRelighter::new(&gpu, cpu, Some(renderer.coefficient_buffer()))
                    .context("uploading the relighting to the GPU (or use --relight cpu)")?;
                self.setup.relighter = Relighting::Gpu(Box::new(g));
            }
            Relighting::Cpu(cpu) => {
                if self.setup.gpu_flatten.unwrap_or(!gpu.is_software()) {
                    FrameDriver {
                        gpu: &gpu,
                        renderer: &mut renderer,
                        relighter: &mut *cpu,
                        ib: &flat,
                    }
                    .flatten_on_gpu()?;
                }
                self.setup.relighter = Relighting::Cpu(cpu);
            }
            other => self.setup.relighter = other,
        }
        let mut camera = cam;
        camera.width = config.width;
        camera.height = config.height;
        let (lo, hi) = self.setup.bounds;
        let state = State {
            window,
            surface,
            config,
            gpu,
            renderer,
            flat,
            camera,
            light: self.setup.light,
            orbit: false,
            mode: ViewMode::Final,
            level: 0,
            keys: HashSet::new(),
            drag: None,
            cursor: (0.0, 0.0),
            tone: ToneMap {
                key: 0.18,
                log_average: 1.0,
                white: 1.0,
            },
            tone_dirty: true,
            tone_measured: None,
            last_tick: Instant::now(),
            frame_times: Vec::new(),
            all_frame_times: Vec::new(),
            stage: StageTimes::default(),
            flat_max: 1.0,
            screenshots: 0,
            frames: 0,
            scale: (hi - lo).length().max(f32::MIN_POSITIVE),
        };
        eprintln!(
            "view: {} ({:?}); V views, P screenshot, O orbit/fly, I/J/K/L/U/N or right drag move the light, Esc quits",
            state.gpu.report.name, state.gpu.report.backend
        );
        Ok(state)
    }

    fn frame(&mut self) -> Result<()> {
        let Some(s) = self.state.as_mut() else {
            return Ok(());
        };
        let now = Instant::now();
        let dt = (now - s.last_tick).as_secs_f32().min(0.25);
        s.last_tick = now;
        move_with_keys(s, dt);
        if let Some(radius) = self.setup.moving_light {
            s.light = light_on_path(&self.setup.light, radius, s.frames, LIGHT_PATH_FRAMES);
        }

        let mut bound = None;
        let relighter: &mut dyn Relight = match &mut self.setup.relighter {
            Relighting::Cpu(c) => &mut **c,
            Relighting::Gpu(g) => bound.insert(BoundGpuRelighter {
                gpu: &s.gpu,
                relighter: g.as_mut(),
                error: None,
            }),
            Relighting::Moving => bail!("the relighter is being moved"),
        };
        let mut driver = FrameDriver {
            gpu: &s.gpu,
            renderer: &mut s.renderer,
            relighter,
            ib: &s.flat,
        };
        let drawn = driver.draw(&s.camera, &s.light, Redraw::WhenRelit, false)?;
        let times = drawn.gpu;
        if !drawn.frame.reused {
            let frame = drawn.frame;
            s.stage = frame.times;
            // The GPU relighter's coefficients stay on the GPU: the points view keeps its scale.
            let coefficients = if frame.flat.is_empty() {
                &frame.i
            } else {
                &frame.flat
            };
            if !coefficients.is_empty() {
                s.flat_max = max_irradiance(coefficients);
            }
            s.tone_dirty = true;
        }
        if let Some(e) = bound.and_then(|b| b.error) {
            return Err(e).context("relighting on the GPU");
        }
        if times.gbuffer_ms > 0.0 || times.cull_ms > 0.0 {
            s.tone_dirty = true;
        }
        let tone_due = s
            .tone_measured
            .is_none_or(|t| t.elapsed().as_secs_f64() >= TONE_INTERVAL_S);
        if s.tone_dirty && tone_due {
            // Reinhard's key needs the image's log-average luminance: read the final buffer.
            s.tone = ToneMap::measure(&s.renderer.read_final(&s.gpu)?);
            s.tone_dirty = false;
            s.tone_measured = Some(Instant::now());
        }
        let output = match s.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            other => {
                // Lost or outdated: reconfigure and try on the next frame.
                let _ = other;
                s.surface.configure(&s.gpu.device, &s.config);
                return Ok(());
            }
        };
        let view = output
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        s.renderer.display(
            &s.gpu,
            &view,
            s.config.format,
            &s.tone,
            s.mode,
            s.level,
            s.flat_max,
        )?;
        s.gpu.queue.present(output);

        s.frames += 1;
        s.frame_times.push(dt as f64);
        s.all_frame_times
            .push(f64::from((Instant::now() - now).as_secs_f32()));
        if s.frame_times.len() >= 10 {
            let mean = s.frame_times.iter().sum::<f64>() / s.frame_times.len() as f64;
            s.frame_times.clear();
            let t = &s.stage;
            s.window.set_title(&format!(
                "{} | {:.1} fps | {} | relight: direct {:.1} + pull-push {:.1} + S e {:.1} + feedback {:.1} + flatten {:.1} ms | {} splats",
                self.setup.title,
                1.0 / mean.max(1e-9),
                s.mode.name(),
                t.direct_ms,
                t.project_ms,
                t.transport_ms,
                t.feedback_ms,
                t.flatten_ms,
                times.splatted_points
            ));
        }
        Ok(())
    }

    /// Saves what the window shows (the display pass rendered offscreen, so debug views are
    /// saved as seen) as `NAME.png`, and the linear final buffer as `NAME-final.exr`.
    fn screenshot(&mut self, name: &str) -> Result<()> {
        let Some(s) = self.state.as_mut() else {
            return Ok(());
        };
        let dir = &self.setup.screenshot_dir;
        let (w, h) = (s.camera.width, s.camera.height);
        let texture = s.gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("screenshot"),
            size: wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        s.renderer.display(
            &s.gpu,
            &view,
            wgpu::TextureFormat::Rgba8Unorm,
            &s.tone,
            s.mode,
            s.level,
            s.flat_max,
        )?;
        let raw = crate::gpu::readback::read_raw(&s.gpu, &texture, 4)?;
        let rgb: Vec<u8> = raw
            .chunks_exact(4)
            .flat_map(|c| [c[0], c[1], c[2]])
            .collect();
        let img = image::RgbImage::from_raw(w, h, rgb).context("screenshot size")?;
        let png = dir.join(format!("{name}.png"));
        let mut bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut bytes, image::ImageFormat::Png)
            .with_context(|| format!("encoding {}", png.display()))?;
        mlt_format::file::write_atomic(&png, bytes.get_ref())
            .with_context(|| format!("writing {}", png.display()))?;
        let exr = dir.join(format!("{name}-final.exr"));
        s.renderer.read_final(&s.gpu)?.write_exr(&exr)?;
        eprintln!("view: wrote {} and {}", png.display(), exr.display());
        Ok(())
    }
}

fn max_irradiance(flat: &[f32]) -> f32 {
    flat.chunks_exact(9)
        .map(|c| {
            let e = [0, 1, 2].map(|k| Vec3::new(c[3 * k], c[3 * k + 1], c[3 * k + 2]).length());
            luminance(e)
        })
        .fold(0.0f32, f32::max)
}

fn move_with_keys(s: &mut State, dt: f32) {
    let fast = if s.keys.contains(&KeyCode::ShiftLeft) {
        4.0
    } else {
        1.0
    };
    let speed = 0.25 * s.scale * dt * fast;
    let (right, up, back) = s.camera.frame();
    let mut m = Vec3::ZERO;
    for (k, d) in [
        (KeyCode::KeyW, -back),
        (KeyCode::KeyS, back),
        (KeyCode::KeyD, right),
        (KeyCode::KeyA, -right),
        (KeyCode::KeyE, up),
        (KeyCode::KeyQ, -up),
    ] {
        if s.keys.contains(&k) {
            m += d;
        }
    }
    if m != Vec3::ZERO {
        let m = m * speed;
        s.camera.position += m;
        if !s.orbit {
            s.camera.target += m;
        }
    }
    let mut l = Vec3::ZERO;
    for (k, d) in [
        (KeyCode::KeyI, -back),
        (KeyCode::KeyK, back),
        (KeyCode::KeyL, right),
        (KeyCode::KeyJ, -right),
        (KeyCode::KeyU, up),
        (KeyCode::KeyN, -up),
    ] {
        if s.keys.contains(&k) {
            l += d;
        }
    }
    if l != Vec3::ZERO {
        s.light.position += l * speed;
    }
}

fn turn(s: &mut State, dx: f32, dy: f32) {
    let (right, _, _) = s.camera.frame();
    let yaw = Quat::from_axis_angle(s.camera.up.normalize(), -dx * 0.005);
    let pitch = Quat::from_axis_angle(right, -dy * 0.005);
    let q = yaw * pitch;
    if s.orbit {
        let v = s.camera.position - s.camera.target;
        let nv = q * v;
        if nv.normalize().cross(s.camera.up.normalize()).length() > 0.02 {
            s.camera.position = s.camera.target + nv;
        }
    } else {
        let v = s.camera.target - s.camera.position;
        let nv = q * v;
        if nv.normalize().cross(s.camera.up.normalize()).length() > 0.02 {
            s.camera.target = s.camera.position + nv;
        }
    }
}

/// What a key press asks of the event loop.
enum KeyAction {
    Nothing,
    Exit,
    Screenshot,
}

/// Acts on a key going down; `start` is the camera and light that R resets to.
fn press(s: &mut State, code: KeyCode, start: (Camera, Light)) -> KeyAction {
    match code {
        KeyCode::Escape => return KeyAction::Exit,
        KeyCode::KeyP => return KeyAction::Screenshot,
        KeyCode::KeyV => s.mode = s.mode.next(),
        KeyCode::KeyO => s.orbit = !s.orbit,
        KeyCode::KeyH => {
            s.renderer.shadows = !s.renderer.shadows;
            s.renderer.invalidate();
        }
        KeyCode::BracketLeft => s.level = s.level.saturating_sub(1),
        KeyCode::BracketRight => s.level = (s.level + 1).min(s.renderer.levels().saturating_sub(1)),
        KeyCode::KeyR => {
            let (w, h) = (s.camera.width, s.camera.height);
            s.camera = start.0;
            s.camera.width = w;
            s.camera.height = h;
            s.light = start.1;
        }
        _ => {}
    }
    KeyAction::Nothing
}

/// The cursor moved to `position`: a left drag turns the camera, a right drag moves the light
/// in the camera's image plane.
fn drag_to(s: &mut State, position: (f64, f64)) {
    s.cursor = position;
    let Some((button, last)) = s.drag else {
        return;
    };
    let (dx, dy) = ((position.0 - last.0) as f32, (position.1 - last.1) as f32);
    s.drag = Some((button, s.cursor));
    match button {
        MouseButton::Left => turn(s, dx, dy),
        MouseButton::Right => {
            let (right, up, _) = s.camera.frame();
            let d = (s.light.position - s.camera.position).length();
            let k = d * 2.0 * (0.5 * s.camera.fovy_deg.to_radians()).tan() / s.camera.height as f32;
            s.light.position += (right * dx - up * dy) * k;
        }
        _ => {}
    }
}

impl App<'_, '_> {
    /// Saves a screenshot of every view mode as `window-MODE.png`.
    fn save_every_view(&mut self) -> Result<()> {
        for mode in ViewMode::ALL {
            if let Some(s) = self.state.as_mut() {
                s.mode = mode;
                s.level = s.renderer.levels() / 2;
            }
            self.screenshot(&format!("window-{}", mode.name().replace(' ', "-")))?;
        }
        Ok(())
    }
}

impl ApplicationHandler for App<'_, '_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match self.init(event_loop) {
            Ok(s) => self.state = Some(s),
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let mut screenshot = false;
        if let Some(s) = self.state.as_mut() {
            match event {
                WindowEvent::CloseRequested => event_loop.exit(),
                WindowEvent::Resized(size) => {
                    s.config.width = size.width.max(1);
                    s.config.height = size.height.max(1);
                    s.surface.configure(&s.gpu.device, &s.config);
                    s.camera.width = s.config.width;
                    s.camera.height = s.config.height;
                }
                WindowEvent::KeyboardInput { event, .. } => {
                    if let PhysicalKey::Code(code) = event.physical_key {
                        if event.state != ElementState::Pressed {
                            s.keys.remove(&code);
                        } else {
                            s.keys.insert(code);
                            if !event.repeat {
                                match press(s, code, (self.start_camera, self.start_light)) {
                                    KeyAction::Exit => event_loop.exit(),
                                    KeyAction::Screenshot => screenshot = true,
                                    KeyAction::Nothing => {}
                                }
                            }
                        }
                    }
                }
                WindowEvent::MouseInput { state, button, .. } => {
                    s.drag = (state == ElementState::Pressed).then_some((button, s.cursor));
                }
                WindowEvent::CursorMoved { position, .. } => {
                    drag_to(s, (position.x, position.y));
                }
                WindowEvent::RedrawRequested => {
                    if let Err(e) = self.frame() {
                        self.error = Some(e);
                        event_loop.exit();
                    }
                }
                _ => {}
            }
        }
        if screenshot {
            let name = self.state.as_mut().map(|s| {
                s.screenshots += 1;
                format!("screenshot-{:03}", s.screenshots - 1)
            });
            if let Err(e) = self.screenshot(&name.unwrap_or_default()) {
                eprintln!("view: screenshot failed: {e:#}");
            }
        }
        let done = match (&self.state, self.setup.exit_after_frames) {
            (Some(s), Some(n)) => s.frames >= n,
            _ => false,
        };
        if done {
            if let Some(s) = &self.state {
                report_frame_times(&s.all_frame_times);
            }
            if let Err(e) = self.save_every_view() {
                self.error = Some(e);
            }
            event_loop.exit();
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(s) = &self.state {
            s.window.request_redraw();
        }
    }
}

/// Prints the median time of the frames after the first (which also builds the G-buffer and
/// the shadow maps) and its frame rate.
fn report_frame_times(times: &[f64]) {
    let rest = times.get(1..).unwrap_or_default().to_vec();
    if rest.is_empty() {
        return;
    }
    let n = rest.len();
    let m = median(rest);
    eprintln!(
        "view: median frame time over {n} frames after the first: {:.1} ms ({:.2} fps)",
        m * 1e3,
        1.0 / m.max(1e-9)
    );
}
