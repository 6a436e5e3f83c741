//! `prm view` (cargo feature `view`): the level in a window, lit by the wgpu runtime, with the
//! first light following the mouse across the level's floor plan at its own height (a level
//! without lights gets a point light). Keys: Escape quits, I toggles indirect light, Up/Down
//! change the exposure. The title bar shows the frame time and whether the frame recomposed.
//!
//! `prm view --edit` is the level editor's view instead (`view_edit`): the incremental baker's
//! lightmap, converging while objects and lights are dragged.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use glam::Vec3;
use prm::{Light, LightKind, Scene};
use prm_runtime::Tonemap;
use prm_runtime::{Gpu, Renderer, Runtime, RuntimeParams};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use crate::common::{load_with_prm, AtlasArgs, ComposeArgs, SceneArgs};
use crate::render::camera;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// The level's .prm (the runtime's view; not with --edit).
    #[arg(long, required_unless_present = "edit", conflicts_with = "edit")]
    pub prm: Option<std::path::PathBuf>,
    /// The editor's view: the incremental baker's lightmap (paper 001) while Tab picks an object
    /// or light and the mouse drags it (PageUp / PageDown raise and lower it).
    #[arg(long)]
    pub edit: bool,
    /// Light paths of the editor's baker (--edit).
    #[arg(long, default_value_t = 20_000)]
    pub paths: usize,
    #[command(flatten)]
    pub lightmap: AtlasArgs,
    /// glTF camera to view from (default: the first).
    #[arg(long)]
    pub camera: Option<String>,
    #[command(flatten)]
    compose: ComposeArgs,
}

struct View {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    runtime: Runtime,
    renderer: Renderer,
    tonemap: Tonemap,
}

struct App {
    scene: Scene,
    prm: prm::prm_file::Prm,
    camera: prm::Camera,
    params: RuntimeParams,
    lights: Vec<Light>,
    indirect: bool,
    exposure: f32,
    view: Option<View>,
    error: Option<anyhow::Error>,
}

pub fn run(a: Args) -> Result<()> {
    if a.edit {
        return crate::view_edit::run(a);
    }
    let prm_path = a.prm.as_deref().context("--prm is needed without --edit")?;
    let (scene, prm) = load_with_prm(&a.scene, prm_path)?;
    let camera = camera(&scene, a.camera.as_deref())?;
    let mut lights = scene.lights.clone();
    if lights.is_empty() {
        let (lo, hi) = scene.bounds();
        let c = (lo + hi) * 0.5;
        lights.push(Light {
            name: "mouse".into(),
            kind: LightKind::Point,
            position: c,
            direction: -Vec3::Y,
            intensity: Vec3::splat((hi - lo).length_squared()),
            range: None,
            aperture: Default::default(),
            profile: None,
        });
    }
    let mut params = a.compose.runtime(1024)?;
    // The view's camera stays where it starts (the mouse moves a light), so a budget fitted for
    // it holds for the whole session.
    let aspect = camera.aspect.unwrap_or(1.0);
    let prm =
        crate::budget::fit_params(a.compose.gpu_budget, &scene, prm, &camera, aspect, &lights, &mut params)?;
    let mut app =
        App { scene, prm, camera, params, lights, indirect: true, exposure: 1.0, view: None, error: None };
    let event_loop = EventLoop::new().context("opening a window needs a display (X11 or Wayland)")?;
    event_loop.run_app(&mut app)?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// A window 960 pixels wide at `camera`'s aspect, and a GPU that presents to it.
pub(crate) struct Presenter {
    pub window: Arc<Window>,
    pub surface: wgpu::Surface<'static>,
    pub config: wgpu::SurfaceConfiguration,
    pub gpu: Gpu,
}

pub(crate) fn open_window(el: &ActiveEventLoop, title: &str, camera: &prm::Camera) -> Result<Presenter> {
    let aspect = camera.aspect.unwrap_or(1.0);
    let attrs = Window::default_attributes()
        .with_title(title)
        .with_inner_size(winit::dpi::LogicalSize::new(960.0, 960.0 / aspect as f64));
    let window = Arc::new(el.create_window(attrs)?);
    let instance = Gpu::instance();
    let surface = instance.create_surface(window.clone())?;
    let gpu = Gpu::with_surface(&instance, Some(&surface))?;
    let size = window.inner_size();
    let config = surface
        .get_default_config(&gpu.adapter, size.width.max(1), size.height.max(1))
        .context("the adapter cannot present to this window")?;
    surface.configure(&gpu.device, &config);
    Ok(Presenter { window, surface, config, gpu })
}

impl App {
    fn open(&mut self, el: &ActiveEventLoop) -> Result<View> {
        let Presenter { window, surface, config, gpu } = open_window(el, "prm view", &self.camera)?;
        let runtime = Runtime::new(&gpu.device, &gpu.queue, &self.scene, &self.prm, self.params)?;
        let renderer = Renderer::new(
            &gpu.device,
            &gpu.queue,
            &self.scene,
            &runtime,
            &self.camera,
            config.width,
            config.height,
        )?;
        let tonemap = Tonemap::new(&gpu.device, config.format);
        Ok(View { window, surface, config, gpu, runtime, renderer, tonemap })
    }

    fn redraw(&mut self) -> Result<()> {
        let Some(v) = &mut self.view else { return Ok(()) };
        let t = Instant::now();
        let up = if self.indirect {
            v.runtime.update(&self.lights)?.composed
        } else {
            v.runtime.update_direct(&self.lights).map(|_| false)?
        };
        v.renderer.draw(&v.runtime, self.indirect, None);
        let frame = match v.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f) | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            _ => {
                v.surface.configure(&v.gpu.device, &v.config);
                return Ok(());
            }
        };
        let target = frame.texture.create_view(&Default::default());
        v.tonemap.draw(&v.gpu.device, &v.gpu.queue, v.renderer.target(), &target, self.exposure);
        v.gpu.queue.present(frame);
        v.renderer.wait();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        v.window.set_title(&format!(
            "prm view: {ms:.1} ms{}{}, exposure {:.2} (mouse: light, I: indirect, Up/Down: exposure)",
            if up { ", recomposed" } else { "" },
            if self.indirect { "" } else { ", direct only" },
            self.exposure
        ));
        Ok(())
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.view.is_none() {
            match self.open(el) {
                Ok(v) => self.view = Some(v),
                Err(e) => {
                    self.error = Some(e);
                    el.exit();
                }
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(size) => {
                if let Some(v) = &mut self.view {
                    v.config.width = size.width.max(1);
                    v.config.height = size.height.max(1);
                    v.surface.configure(&v.gpu.device, &v.config);
                    match Renderer::new(
                        &v.gpu.device,
                        &v.gpu.queue,
                        &self.scene,
                        &v.runtime,
                        &self.camera,
                        v.config.width,
                        v.config.height,
                    ) {
                        Ok(r) => v.renderer = r,
                        Err(e) => {
                            self.error = Some(e.into());
                            el.exit();
                        }
                    }
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let Some(v) = &self.view {
                    // Mouse x, y over the window -> the level's x, z extent, keeping the height.
                    let (lo, hi) = self.scene.bounds();
                    let fx = (position.x as f32 / v.config.width as f32).clamp(0.0, 1.0);
                    let fz = (position.y as f32 / v.config.height as f32).clamp(0.0, 1.0);
                    let l = &mut self.lights[0];
                    l.position.x = lo.x + (hi.x - lo.x) * (0.05 + 0.9 * fx);
                    l.position.z = lo.z + (hi.z - lo.z) * (0.05 + 0.9 * fz);
                    v.window.request_redraw();
                }
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match event.logical_key {
                    Key::Named(NamedKey::Escape) => el.exit(),
                    Key::Named(NamedKey::ArrowUp) => self.exposure *= 1.25,
                    Key::Named(NamedKey::ArrowDown) => self.exposure /= 1.25,
                    Key::Character(c) if c.eq_ignore_ascii_case("i") => self.indirect = !self.indirect,
                    _ => {}
                }
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.error = Some(e);
                    el.exit();
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _el: &ActiveEventLoop) {
        if let Some(v) = &self.view {
            v.window.request_redraw();
        }
    }
}
