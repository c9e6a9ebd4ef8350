//! The UI as drawn, the same in the window and offscreen: the viewport texture filled by the
//! display pass from the loop's last frame, egui's panels around it, painted by egui-wgpu into
//! a target (the window's surface, or a texture read back for a screenshot).

use crate::ViewError;
use crate::display::{self, Display, Gpu};
use crate::session::{Command, Published};
use crate::ui::UiState;

pub struct Canvas {
    pub ctx: egui::Context,
    renderer: egui_wgpu::Renderer,
    pub display: Display,
    viewport: egui::TextureId,
    /// The format of the targets the UI is painted into.
    format: wgpu::TextureFormat,
    /// The loop's generation last uploaded.
    generation: Option<u64>,
    pub ui: UiState,
}

/// One UI frame, tessellated, ready to paint (as many times as needed).
pub struct Painted {
    jobs: Vec<egui::ClippedPrimitive>,
    textures: egui::TexturesDelta,
    pixels_per_point: f32,
}

impl Canvas {
    /// egui painting into targets of `format`, the viewport `width × height`.
    pub fn new(
        gpu: &Gpu,
        format: wgpu::TextureFormat,
        width: u32,
        height: u32,
        ui: UiState,
    ) -> Self {
        let mut renderer = egui_wgpu::Renderer::new(
            &gpu.device,
            format,
            egui_wgpu::RendererOptions {
                dithering: false,
                ..Default::default()
            },
        );
        let display = Display::new(gpu, width, height);
        let viewport = renderer.register_native_texture(
            &gpu.device,
            &display.target_view,
            wgpu::FilterMode::Nearest,
        );
        Self {
            ctx: egui::Context::default(),
            renderer,
            display,
            viewport,
            format,
            generation: None,
            ui,
        }
    }

    /// Draws the loop's last frame into the viewport texture, if it is new.
    pub fn update_viewport(&mut self, gpu: &Gpu, p: &Published) {
        if self.generation == Some(p.generation) {
            return;
        }
        self.generation = Some(p.generation);
        let (w, h) = (p.image.width as u32, p.image.height as u32);
        if self.display.resize(gpu, w, h) {
            self.renderer.update_egui_texture_from_wgpu_texture(
                &gpu.device,
                &self.display.target_view,
                wgpu::FilterMode::Nearest,
                self.viewport,
            );
        }
        self.display.upload(gpu, &p.image, p.aux.as_ref());
        self.display.draw(gpu, p.shade);
    }

    /// Runs the UI for one frame on `input`; returns what to paint and the loop's commands.
    pub fn run(
        &mut self,
        input: egui::RawInput,
        p: &Published,
    ) -> (egui::FullOutput, Vec<Command>) {
        let mut commands = Vec::new();
        let size = [self.display.width, self.display.height];
        let viewport = self.viewport;
        let ui_state = &mut self.ui;
        let output = self.ctx.run_ui(input, |ui| {
            ui_state.show(ui, p, viewport, size, &mut commands)
        });
        (output, commands)
    }

    /// Tessellates a UI frame's shapes.
    pub fn tessellate(&self, output: egui::FullOutput) -> Painted {
        let pixels_per_point = output.pixels_per_point;
        Painted {
            jobs: self.ctx.tessellate(output.shapes, pixels_per_point),
            textures: output.textures_delta,
            pixels_per_point,
        }
    }

    /// Uploads the frame's new egui textures (once per frame, before painting it).
    pub fn prepare(&mut self, gpu: &Gpu, painted: &Painted) {
        for (id, deltas) in &painted.textures.set {
            for delta in deltas {
                self.renderer
                    .update_texture(&gpu.device, &gpu.queue, *id, delta);
            }
        }
    }

    /// Paints a frame into `target` of `size` pixels.
    pub fn paint(
        &mut self,
        gpu: &Gpu,
        painted: &Painted,
        target: &wgpu::TextureView,
        size: [u32; 2],
    ) {
        let screen = egui_wgpu::ScreenDescriptor {
            size_in_pixels: size,
            pixels_per_point: painted.pixels_per_point,
        };
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("ui") });
        let extra = self.renderer.update_buffers(
            &gpu.device,
            &gpu.queue,
            &mut encoder,
            &painted.jobs,
            &screen,
        );
        {
            let pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("ui"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: 0.05,
                            g: 0.05,
                            b: 0.05,
                            a: 1.0,
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                    depth_slice: None,
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            self.renderer
                .render(&mut pass.forget_lifetime(), &painted.jobs, &screen);
        }
        gpu.queue
            .submit(extra.into_iter().chain(std::iter::once(encoder.finish())));
    }

    /// Frees the textures egui dropped this frame (after painting it).
    pub fn finish(&mut self, painted: Painted) {
        for id in &painted.textures.free {
            self.renderer.free_texture(id);
        }
    }

    /// Paints `painted` offscreen at `size` and returns its RGBA pixels (a screenshot of the
    /// whole UI).
    pub fn screenshot(
        &mut self,
        gpu: &Gpu,
        painted: &Painted,
        size: [u32; 2],
    ) -> Result<Vec<u8>, ViewError> {
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("screenshot"),
            size: wgpu::Extent3d {
                width: size[0],
                height: size[1],
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: self.format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&Default::default());
        self.paint(gpu, painted, &view, size);
        display::read_rgba8(gpu, &texture)
    }
}

/// The raw input of an offscreen UI frame of `size` pixels at `time` seconds.
pub fn offscreen_input(size: [u32; 2], time: f64) -> egui::RawInput {
    egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(
            egui::Pos2::ZERO,
            egui::vec2(size[0] as f32, size[1] as f32),
        )),
        time: Some(time),
        ..Default::default()
    }
}
