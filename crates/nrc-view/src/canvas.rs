//! The UI as drawn, the same in the window and offscreen: the viewport texture filled by the
//! display pass from the loop's last frame, copied into the target where egui left room for it
//! (`shaders/view_blit.wgsl`), and egui's panels around it, painted by egui-wgpu into the same
//! target (the window's surface, or a texture read back for a screenshot).

use crate::ViewError;
use crate::display::{self, Display, Gpu};
use crate::session::{Command, Published};
use crate::ui::UiState;

pub struct Canvas {
    pub ctx: egui::Context,
    renderer: egui_wgpu::Renderer,
    pub display: Display,
    blit: Blit,
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
        let renderer = egui_wgpu::Renderer::new(
            &gpu.device,
            format,
            egui_wgpu::RendererOptions {
                dithering: false,
                ..Default::default()
            },
        );
        let display = Display::new(gpu, width, height);
        let blit = Blit::new(gpu, format, &display);
        Self {
            ctx: egui::Context::default(),
            renderer,
            display,
            blit,
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
            self.blit.bind(gpu, &self.display);
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
        let ui_state = &mut self.ui;
        let output = self
            .ctx
            .run_ui(input, |ui| ui_state.show(ui, p, size, &mut commands));
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
            let mut pass = pass.forget_lifetime();
            if let Some(rect) = self.ui.viewport_rect {
                let rect = rect * painted.pixels_per_point;
                self.blit
                    .draw(gpu, &mut pass, rect, size, self.display.width);
            }
            self.renderer.render(&mut pass, &painted.jobs, &screen);
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

/// The pass copying the viewport into the UI's target (`shaders/view_blit.wgsl`).
struct Blit {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    group: wgpu::BindGroup,
    /// Whether the target encodes sRGB itself.
    decode: bool,
}

/// The uniform block of `shaders/view_blit.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BlitParams {
    origin: [f32; 2],
    scale: f32,
    decode: u32,
}

impl Blit {
    fn new(gpu: &Gpu, format: wgpu::TextureFormat, display: &Display) -> Self {
        let device = &gpu.device;
        use display::{binding, float_texture, uniform};
        let (pipeline, layout) = display::fullscreen_pass(
            device,
            "blit",
            include_str!("../../../shaders/view_blit.wgsl"),
            &[binding(0, uniform()), binding(1, float_texture())],
            format,
        );
        let params =
            display::uniform_buffer(device, "blit params", std::mem::size_of::<BlitParams>());
        let group = Self::group(gpu, &layout, &params, display);
        Self {
            pipeline,
            layout,
            params,
            group,
            decode: format.is_srgb(),
        }
    }

    fn group(
        gpu: &Gpu,
        layout: &wgpu::BindGroupLayout,
        params: &wgpu::Buffer,
        display: &Display,
    ) -> wgpu::BindGroup {
        gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("blit"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&display.target_view),
                },
            ],
        })
    }

    /// Points at `display`'s (new) viewport texture.
    fn bind(&mut self, gpu: &Gpu, display: &Display) {
        self.group = Self::group(gpu, &self.layout, &self.params, display);
    }

    /// Copies the viewport (`texels` wide) into `rect` (target pixels) of a target of `size`.
    fn draw(
        &self,
        gpu: &Gpu,
        pass: &mut wgpu::RenderPass<'static>,
        rect: egui::Rect,
        size: [u32; 2],
        texels: u32,
    ) {
        let (w, h) = (size[0] as f32, size[1] as f32);
        let x0 = rect.min.x.clamp(0.0, w).round();
        let y0 = rect.min.y.clamp(0.0, h).round();
        let x1 = rect.max.x.clamp(x0, w).round();
        let y1 = rect.max.y.clamp(y0, h).round();
        if x1 - x0 < 1.0 || y1 - y0 < 1.0 {
            return;
        }
        let params = BlitParams {
            origin: [rect.min.x, rect.min.y],
            scale: rect.width() / texels.max(1) as f32,
            decode: u32::from(self.decode),
        };
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        pass.set_viewport(0.0, 0.0, w, h, 0.0, 1.0);
        pass.set_scissor_rect(x0 as u32, y0 as u32, (x1 - x0) as u32, (y1 - y0) as u32);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.group, &[]);
        pass.draw(0..3, 0..1);
    }
}
