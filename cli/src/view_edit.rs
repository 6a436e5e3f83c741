//! `prm view --edit` (cargo feature `view`): the level editor's view. The incremental baker
//! (paper 001) bakes the level, and the window shows its lightmap (direct and indirect, both
//! baked) on the level as it is now, ray cast on the CPU, while updates run between frames.
//!
//! Tab picks the next object (a glTF node) or light; dragging with the left button moves it
//! over the plane through it that faces the camera (the floor plane when the camera looks
//! down), PageUp / PageDown raise and lower it by 2 % of the level's size; Up / Down change the
//! exposure; Escape quits. A drag becomes an edit every 0.2 s and when the button is released,
//! so the lightmap follows the object as it goes. The title shows the pick, the updates waiting
//! and the invalid flux left.

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use glam::Vec3;
use prm::density::Atlas;
use prm::{Camera, TexelSet};
use prm_precompute::incremental::editor::{drag_plane, move_edit, on_plane, picks, Pick};
use prm_precompute::incremental::{Baker, BakerParams};
use prm_runtime::{Gpu, Tonemap};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use crate::render::{camera, shade};
use crate::view::{open_window, Args, Presenter};

/// Seconds between the edits a drag makes while the button is held.
const DRAG_EDIT_EVERY: f64 = 0.2;
/// Baker updates per frame, at most this long (at least one).
const UPDATE_SLICE: Duration = Duration::from_millis(60);
/// The CPU frame is cast at this fraction of the window's pixels a side, then enlarged.
const FRAME_SCALE: u32 = 2;

struct Drag {
    point: Vec3,
    normal: Vec3,
    grab: Vec3,
    offset: Vec3,
    applied: Vec3,
    released: bool,
}

struct Window3d {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    hdr: wgpu::Texture,
    tonemap: Tonemap,
}

struct App {
    baker: Baker,
    set: Arc<TexelSet>,
    atlas: Atlas,
    camera: Camera,
    names: Vec<Option<String>>,
    picks: Vec<Pick>,
    selected: usize,
    drag: Option<Drag>,
    cursor: (f32, f32),
    last_edit: Instant,
    step: f32,
    exposure: f32,
    note: String,
    view: Option<Window3d>,
    error: Option<anyhow::Error>,
}

pub fn run(a: Args) -> Result<()> {
    let (mut scene, atlas) = a.lightmap.load(&a.scene, false)?;
    if atlas.pages > 1 {
        anyhow::bail!("prm view --edit takes a one-page atlas (give --atlas)");
    }
    let camera = camera(&scene, a.camera.as_deref())?;
    let glow = scene.emissive_lights();
    scene.lights.extend(glow);
    let names = crate::common::node_names(&a.scene.scene);
    let bvh = prm::Bvh::build(&scene);
    let set = Arc::new(TexelSet::build_visible(&scene, &bvh, atlas.width(), atlas.height()));
    let step = 0.02 * scene.diagonal();
    let params = BakerParams { paths: a.paths, ..BakerParams::default() };
    let baker = Baker::new(scene, set.clone(), params).map_err(|e| anyhow!("bad parameter: {e}"))?;
    let picks = picks(baker.level().current(), &names);
    let mut app = App {
        baker,
        set,
        atlas,
        camera,
        names,
        picks,
        selected: 0,
        drag: None,
        cursor: (0.0, 0.0),
        last_edit: Instant::now(),
        step,
        exposure: 1.0,
        note: String::new(),
        view: None,
        error: None,
    };
    let event_loop = EventLoop::new().context("opening a window needs a display (X11 or Wayland)")?;
    event_loop.run_app(&mut app)?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl App {
    fn open(&mut self, el: &ActiveEventLoop) -> Result<Window3d> {
        let Presenter { window, surface, config, gpu } = open_window(el, "prm view --edit", &self.camera)?;
        let hdr = hdr_texture(&gpu.device, config.width, config.height);
        let tonemap = Tonemap::new(&gpu.device, config.format);
        Ok(Window3d { window, surface, config, gpu, hdr, tonemap })
    }

    /// The ray under the cursor.
    fn cursor_ray(&self) -> Option<(Vec3, Vec3)> {
        let v = self.view.as_ref()?;
        Some(self.camera.ray(self.cursor.0, self.cursor.1, v.config.width, v.config.height))
    }

    /// Move the pick by `by` as one edit; false if it was refused.
    fn edit_by(&mut self, by: Vec3) -> bool {
        let Some(pick) = self.picks.get(self.selected).cloned() else { return true };
        if by.length_squared() == 0.0 {
            return true;
        }
        let v = self.baker.level().current().clone();
        let applied = move_edit(&v, &pick, by).and_then(|e| self.baker.apply(&e));
        self.last_edit = Instant::now();
        match applied {
            Ok(r) => {
                self.note = format!("{} paths changed", r.paths_changed);
                self.picks = picks(self.baker.level().current(), &self.names);
                true
            }
            Err(e) => {
                self.note = format!("refused: {e}");
                false
            }
        }
    }

    fn redraw(&mut self) -> Result<()> {
        if let Some(d) = &mut self.drag {
            let due = d.released || self.last_edit.elapsed().as_secs_f64() >= DRAG_EDIT_EVERY;
            let by = d.offset - d.applied;
            let done = d.released;
            if due {
                d.applied = d.offset;
                if !self.edit_by(by) {
                    // Refused: the next edit starts from where the object is.
                    if let Some(d) = &mut self.drag {
                        d.grab += by;
                    }
                }
                if done {
                    self.drag = None;
                }
            }
        }
        let t = Instant::now();
        if !self.baker.converged() {
            self.baker.run_for(UPDATE_SLICE);
        }
        let updates_ms = t.elapsed().as_secs_f64() * 1e3;
        let Some(v) = &mut self.view else { return Ok(()) };
        let (w, h) = (v.config.width, v.config.height);
        let (iw, ih) = ((w / FRAME_SCALE).max(1), (h / FRAME_SCALE).max(1));
        let (direct, indirect) = self.baker.lightmap();
        let total: Vec<Vec3> = direct.iter().zip(&indirect).map(|(a, b)| *a + *b).collect();
        let img = self.set.to_image(&total, Vec3::ZERO);
        let cur = self.baker.level().current().clone();
        let frame =
            shade(&cur.scene, &cur.bvh, &self.camera, &[], &img, self.atlas, (iw as usize, ih as usize));
        let mut rgba = vec![0f32; (w * h * 4) as usize];
        for y in 0..h {
            for x in 0..w {
                let c = frame[((y / FRAME_SCALE).min(ih - 1) * iw + (x / FRAME_SCALE).min(iw - 1)) as usize];
                rgba[((y * w + x) * 4) as usize..][..4].copy_from_slice(&[c.x, c.y, c.z, 1.0]);
            }
        }
        v.gpu.queue.write_texture(
            v.hdr.as_image_copy(),
            &rgba.iter().flat_map(|c| c.to_le_bytes()).collect::<Vec<u8>>(),
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(w * 16), rows_per_image: Some(h) },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        let surface = match v.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f) | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            _ => {
                v.surface.configure(&v.gpu.device, &v.config);
                return Ok(());
            }
        };
        let target = surface.texture.create_view(&Default::default());
        v.tonemap.draw(&v.gpu.device, &v.gpu.queue, &v.hdr, &target, self.exposure);
        v.gpu.queue.present(surface);
        let pick = self.picks.get(self.selected).map_or("nothing", |p| p.name());
        let state = if self.baker.converged() {
            "converged".to_string()
        } else {
            format!(
                "{} updates waiting, invalid flux {:.3} W",
                self.baker.pending(),
                self.baker.invalid_flux()
            )
        };
        v.window.set_title(&format!(
            "prm view --edit: {pick} (Tab: next, drag: move, PgUp/PgDn: up/down) | {state} | updates {updates_ms:.0} ms, \
             frame {:.0} ms | {}",
            t.elapsed().as_secs_f64() * 1e3,
            self.note
        ));
        Ok(())
    }
}

fn hdr_texture(device: &wgpu::Device, w: u32, h: u32) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("edit view frame"),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
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
                    v.hdr = hdr_texture(&v.gpu.device, v.config.width, v.config.height);
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x as f32, position.y as f32);
                let ray = self.cursor_ray();
                if let (Some(d), Some((o, dir))) = (&mut self.drag, ray) {
                    if let Some(p) = on_plane(o, dir, d.point, d.normal) {
                        d.offset = p - d.grab;
                    }
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => match state {
                ElementState::Pressed => {
                    let at = self.picks.get(self.selected).map(Pick::at);
                    let normal = drag_plane(-self.camera.to_world.col(2).truncate());
                    if let (Some(point), Some((o, dir))) = (at, self.cursor_ray()) {
                        if let Some(grab) = on_plane(o, dir, point, normal) {
                            let (offset, applied, released) = (Vec3::ZERO, Vec3::ZERO, false);
                            self.drag = Some(Drag { point, normal, grab, offset, applied, released });
                        }
                    }
                }
                ElementState::Released => {
                    if let Some(d) = &mut self.drag {
                        d.released = true;
                    }
                }
            },
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match event.logical_key {
                    Key::Named(NamedKey::Escape) => el.exit(),
                    Key::Named(NamedKey::Tab) if self.drag.is_none() && !self.picks.is_empty() => {
                        self.selected = (self.selected + 1) % self.picks.len();
                    }
                    Key::Named(NamedKey::PageUp) if self.drag.is_none() => {
                        self.edit_by(Vec3::Y * self.step);
                    }
                    Key::Named(NamedKey::PageDown) if self.drag.is_none() => {
                        self.edit_by(-Vec3::Y * self.step);
                    }
                    Key::Named(NamedKey::ArrowUp) => self.exposure *= 1.25,
                    Key::Named(NamedKey::ArrowDown) => self.exposure /= 1.25,
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
