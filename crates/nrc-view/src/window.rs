//! `nrc view` in a window: winit's event loop, a wgpu surface, egui's input through egui-winit.
//! The UI redraws when there is something new (a frame of the loop, input, a camera in motion,
//! egui's own animations), at up to [`UI_HZ`] frames a second whatever the loop's rate, showing
//! the loop's last finished frame; closing the window (or Escape) stops the loop after the frame it
//! is in, so a snapshot being written is finished first.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use winit::application::ApplicationHandler;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::window::{Window, WindowId};

use crate::ViewError;
use crate::canvas::Canvas;
use crate::display::{self, Gpu};
use crate::session::{self, LoopSetup, Running, Session};
use crate::ui::UiState;

/// The UI's frame rate cap.
pub const UI_HZ: f64 = 60.0;

/// How the window opens.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    pub title: String,
    /// Logical size of the window.
    pub size: [u32; 2],
    /// Where F5/F9 save and load the snapshot (the UI's field starts there).
    pub snapshot: PathBuf,
    /// Where F12 writes the screenshot of the whole UI.
    pub screenshot: PathBuf,
    pub exposure: f32,
    pub tonemap: display::ToneMap,
    /// The scene's largest extent (the fly camera's speed).
    pub extent: f32,
    /// Print the UI and loop frame rates every few seconds (stderr).
    pub print_rates: bool,
    /// The debug view at the start.
    pub view: crate::session::View,
}

struct Open {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    input: egui_winit::State,
    canvas: Canvas,
    running: Running,
}

struct App {
    options: WindowOptions,
    start: Option<(Session, rayon::ThreadPool)>,
    open: Option<Open>,
    error: Option<ViewError>,
    next_frame: Instant,
    last_print: Instant,
    /// Something new to draw: input, a new frame of the loop, or the UI asked for more.
    dirty: bool,
    /// The loop's generation last drawn.
    drawn: u64,
}

/// Opens the window and runs the loop of `setup` on `pool` until the window closes.
pub fn run_window(
    setup: LoopSetup,
    options: WindowOptions,
    pool: rayon::ThreadPool,
) -> Result<(), ViewError> {
    // winit returns an error where it cannot reach a display; a panic on the way (a library
    // missing at run time) is reported the same way.
    let event_loop = std::panic::catch_unwind(EventLoop::new)
        .map_err(|_| ViewError::NoDisplay("the window system failed to start".into()))?
        .map_err(|e| ViewError::NoDisplay(e.to_string()))?;
    let mut app = App {
        options,
        start: Some((Session::new(setup), pool)),
        open: None,
        error: None,
        next_frame: Instant::now(),
        last_print: Instant::now(),
        dirty: true,
        drawn: u64::MAX,
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| ViewError::NoDisplay(e.to_string()))?;
    if let Some(open) = app.open.take() {
        open.running.stop();
    }
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl App {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewError> {
        let Some((session, pool)) = self.start.take() else {
            return Ok(());
        };
        let o = &self.options;
        let attributes = Window::default_attributes()
            .with_title(o.title.clone())
            .with_inner_size(winit::dpi::LogicalSize::new(o.size[0], o.size[1]));
        let window = Arc::new(
            event_loop
                .create_window(attributes)
                .map_err(|e| ViewError::NoDisplay(e.to_string()))?,
        );
        let instance = display::instance();
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| ViewError::NoAdapter(format!("cannot draw into the window: {e}")))?;
        let gpu = Gpu::new(instance, Some(&surface))?;
        let size = window.inner_size();
        let caps = surface.get_capabilities(&gpu.adapter);
        // egui paints in gamma space: a plain 8-bit format where the surface offers one, else
        // an 8-bit sRGB one (egui and the viewport copy encode for it); screenshots read 8 bits.
        use wgpu::TextureFormat as F;
        let format = [
            F::Bgra8Unorm,
            F::Rgba8Unorm,
            F::Bgra8UnormSrgb,
            F::Rgba8UnormSrgb,
        ]
        .into_iter()
        .find(|f| caps.formats.contains(f))
        .ok_or_else(|| {
            ViewError::NoAdapter(format!(
                "the window's surface offers no 8-bit format (it offers {:?})",
                caps.formats
            ))
        })?;
        let mut config = surface
            .get_default_config(&gpu.adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| {
                ViewError::NoAdapter("the adapter cannot draw into the window".into())
            })?;
        config.format = format;
        config.present_mode = wgpu::PresentMode::AutoNoVsync;
        surface.configure(&gpu.device, &config);

        let published = session.publish();
        gpu.check_size(
            "the image",
            published.image.width as u32,
            published.image.height as u32,
        )?;
        let camera = session.camera();
        let mut ui = UiState::new(camera, o.extent, o.snapshot.clone(), o.screenshot.clone());
        ui.exposure = o.exposure;
        ui.tonemap = o.tonemap;
        ui.adapter = gpu.describe();
        ui.view = o.view;
        let tone = ui.tone();
        let canvas = Canvas::new(
            &gpu,
            format,
            published.image.width as u32,
            published.image.height as u32,
            ui,
        );
        let input = egui_winit::State::new(
            canvas.ctx.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(gpu.device.limits().max_texture_dimension_2d as usize),
        );
        let running = session::spawn(session, pool);
        let _ = running.commands.send(tone);
        let _ = running
            .commands
            .send(crate::session::Command::View(self.options.view));
        eprintln!("nrc view: drawing with {}", gpu.describe());
        self.open = Some(Open {
            window,
            surface,
            config,
            gpu,
            input,
            canvas,
            running,
        });
        Ok(())
    }

    /// One UI frame: the loop's last frame into the viewport, the panels, the surface.
    fn redraw(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewError> {
        let Some(open) = &mut self.open else {
            return Ok(());
        };
        let published = match open.running.shared.lock() {
            Ok(p) => p.clone(),
            Err(_) => return Err(ViewError::Loop("the loop's thread failed".into())),
        };
        open.canvas.update_viewport(&open.gpu, &published);
        let input = open.input.take_egui_input(&open.window);
        self.drawn = published.generation;
        let (output, commands) = open.canvas.run(input, &published);
        // egui asks for another frame (an animation, a tooltip), or the camera is moving.
        let again = output
            .viewport_output
            .get(&egui::ViewportId::ROOT)
            .is_some_and(|v| v.repaint_delay.is_zero());
        self.dirty |= again || open.canvas.ui.active;
        for c in commands {
            let _ = open.running.commands.send(c);
        }
        open.input
            .handle_platform_output(&open.window, output.platform_output.clone());
        let painted = open.canvas.tessellate(output);
        open.canvas.prepare(&open.gpu, &painted);
        let frame = match open.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f)
            | wgpu::CurrentSurfaceTexture::Suboptimal(f) => Some(f),
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                open.surface.configure(&open.gpu.device, &open.config);
                None
            }
            _ => None,
        };
        if let Some(frame) = frame {
            let view = frame.texture.create_view(&Default::default());
            let size = [open.config.width, open.config.height];
            open.canvas.paint(&open.gpu, &painted, &view, size);
            open.window.pre_present_notify();
            open.gpu.queue.present(frame);
        }
        if open.canvas.ui.take_screenshot {
            open.canvas.ui.take_screenshot = false;
            let size = [open.config.width, open.config.height];
            let path = open.canvas.ui.screenshot.clone();
            // A screenshot that cannot be written is said in the panel; the session goes on.
            let written = open
                .canvas
                .screenshot(&open.gpu, &painted, size)
                .and_then(|rgba| display::write_png(&path, size[0], size[1], &rgba));
            // (A success is said on stderr only: a line in the panel would make the next
            // screenshot differ from this one.)
            match written {
                Ok(()) => eprintln!("nrc view: screenshot written to {}", path.display()),
                Err(e) => {
                    eprintln!("nrc view: error: screenshot: {e}");
                    open.canvas.ui.say(format!("error: screenshot: {e}"));
                }
            }
        }
        open.canvas.finish(painted);
        if open.canvas.ui.quit {
            event_loop.exit();
        }
        if self.options.print_rates && self.last_print.elapsed() > Duration::from_secs(5) {
            self.last_print = Instant::now();
            eprintln!(
                "nrc view: UI {:.0} frames/s, loop {:.1} frames/s, frame {}",
                open.canvas.ui.ui_fps(),
                published.loop_fps,
                published.frames
            );
        }
        Ok(())
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: ViewError) {
        self.error.get_or_insert(e);
        event_loop.exit();
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if let Err(e) = self.open(event_loop) {
            self.fail(event_loop, e);
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(open) = &mut self.open else {
            return;
        };
        let _ = open.input.on_window_event(&open.window, &event);
        if !matches!(event, WindowEvent::RedrawRequested) {
            self.dirty = true;
        }
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                // A minimised window has no size to draw at: keep the surface as it was.
                let max = open.gpu.device.limits().max_texture_dimension_2d;
                if size.width > 0 && size.height > 0 {
                    open.config.width = size.width.min(max);
                    open.config.height = size.height.min(max);
                    open.surface.configure(&open.gpu.device, &open.config);
                }
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw(event_loop) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let now = Instant::now();
        if let Some(open) = &self.open {
            let generation = open
                .running
                .generation
                .load(std::sync::atomic::Ordering::SeqCst);
            self.dirty |= generation != self.drawn;
            if self.dirty && now >= self.next_frame {
                self.dirty = false;
                open.window.request_redraw();
                self.next_frame = now + Duration::from_secs_f64(1.0 / UI_HZ);
            }
        }
        // Wake at the UI's rate to look for a new frame of the loop.
        let wake = self
            .next_frame
            .max(now + Duration::from_secs_f64(1.0 / UI_HZ));
        event_loop.set_control_flow(ControlFlow::WaitUntil(wake));
    }

    fn exiting(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(open) = self.open.take() {
            // The loop finishes the frame (or the snapshot) it is in.
            open.running.stop();
        }
    }
}
