//! The viewer's GPU side: the adapter and device, the display pass (`shaders/view.wgsl`: tone
//! mapping and the debug views' colour maps) that turns a frame's linear radiance into the
//! viewport texture egui shows, and reading textures back for screenshots.

use std::path::Path;

use nrc_scene::image::Image;

use crate::ViewError;

/// The display pass's WGSL (tone mapping, false colour, heat map).
pub const SHADER: &str = include_str!("../../../shaders/view.wgsl");

/// Entries of each colour map in the shader's table.
const LUT: usize = 1024;

/// The format of the viewport texture and of offscreen screenshots: 8-bit, values already
/// sRGB-encoded (egui draws in gamma space).
pub const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// The adapter and device the viewer draws with.
pub struct Gpu {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

impl Gpu {
    /// An adapter (able to present to `surface`, where given) and its device; an error that says
    /// none was found (and what to install) rather than a panic.
    pub fn new(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Self, ViewError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| {
            ViewError::NoAdapter(format!(
                "{e} (the viewer draws with wgpu on Vulkan: install a driver, e.g. Mesa's software Vulkan, mesa-vulkan-drivers)"
            ))
        })?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("nrc view"),
            ..Default::default()
        }))
        .map_err(|e| ViewError::NoAdapter(format!("cannot open the adapter: {e}")))?;
        Ok(Self {
            instance,
            adapter,
            device,
            queue,
        })
    }

    /// Without a window: any adapter.
    pub fn headless() -> Result<Self, ViewError> {
        Self::new(instance(), None)
    }

    /// Refuses a `width × height` image larger than the adapter's textures can be.
    pub fn check_size(&self, what: &str, width: u32, height: u32) -> Result<(), ViewError> {
        let max = self.device.limits().max_texture_dimension_2d;
        if width > max || height > max {
            return Err(ViewError::Option(format!(
                "{what} {width}x{height} is larger than the adapter's textures ({max} pixels a side)"
            )));
        }
        Ok(())
    }

    /// The adapter in words: its name and driver.
    pub fn describe(&self) -> String {
        let i = self.adapter.get_info();
        format!("{} ({:?}, {})", i.name, i.backend, i.driver)
    }
}

/// The instance the viewer's adapters come from: the primary backends (Vulkan, Metal, DX12),
/// not OpenGL, whose EGL set-up probes for a Wayland display and complains where there is none;
/// `WGPU_BACKEND` and the other wgpu variables override.
pub fn instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::PRIMARY;
    wgpu::Instance::new(desc.with_env())
}

/// A pass that draws one full-screen triangle (`vs_main`) with `fs_main` of `wgsl` into a
/// target of `format`, its one bind group laid out by `entries`: the display pass and the
/// viewport copy.
pub(crate) fn fullscreen_pass(
    device: &wgpu::Device,
    label: &str,
    wgsl: &str,
    entries: &[wgpu::BindGroupLayoutEntry],
    format: wgpu::TextureFormat,
) -> (wgpu::RenderPipeline, wgpu::BindGroupLayout) {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(wgsl.into()),
    });
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries,
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_main"),
            buffers: &[],
            compilation_options: Default::default(),
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: None,
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            targets: &[Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
            compilation_options: Default::default(),
        }),
        multiview_mask: None,
        cache: None,
    });
    (pipeline, layout)
}

/// A fragment-stage binding.
pub(crate) fn binding(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty,
        count: None,
    }
}

pub(crate) fn uniform() -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Uniform,
        has_dynamic_offset: false,
        min_binding_size: None,
    }
}

fn storage() -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Storage { read_only: true },
        has_dynamic_offset: false,
        min_binding_size: None,
    }
}

/// A 2D float texture read with `textureLoad` (no sampler).
pub(crate) fn float_texture() -> wgpu::BindingType {
    wgpu::BindingType::Texture {
        multisampled: false,
        sample_type: wgpu::TextureSampleType::Float { filterable: false },
        view_dimension: wgpu::TextureViewDimension::D2,
    }
}

/// A uniform buffer of `size` bytes, written before each draw.
pub(crate) fn uniform_buffer(device: &wgpu::Device, label: &str, size: usize) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// How the display pass shows the frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shade {
    /// Tone-mapped radiance.
    Tone { exposure: f32, tonemap: ToneMap },
    /// Relative squared error against the reference (aux), log scale 1e-4 … 10.
    RelError,
    /// Counts (aux, red) on a log scale up to `max`.
    Heat { max: f32 },
    /// A scalar (image, red) on a linear scale.
    Scalar { min: f32, max: f32 },
}

/// The tone curve.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ToneMap {
    /// ACES filmic (Narkowicz 2015), as `nrc render --png`.
    #[default]
    Aces,
    /// Linear, clamped to [0, 1].
    Clamp,
    /// Reinhard, x / (1 + x).
    Reinhard,
}

impl ToneMap {
    pub const ALL: [ToneMap; 3] = [ToneMap::Aces, ToneMap::Clamp, ToneMap::Reinhard];

    pub fn name(self) -> &'static str {
        match self {
            ToneMap::Aces => "ACES filmic",
            ToneMap::Clamp => "clamp",
            ToneMap::Reinhard => "Reinhard",
        }
    }
}

/// The uniform block of `shaders/view.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    mode: u32,
    tonemap: u32,
    scale: f32,
    lo: f32,
    hi: f32,
    pad: [u32; 3],
}

impl Params {
    fn of(shade: Shade) -> Self {
        let (mode, tonemap, scale, lo, hi) = match shade {
            Shade::Tone { exposure, tonemap } => (0, tonemap as u32, exposure.exp2(), 0.0, 0.0),
            Shade::RelError => (1, 0, 1.0, -4.0, 1.0),
            Shade::Heat { max } => (2, 0, 1.0, 0.0, max),
            Shade::Scalar { min, max } => (3, 0, 1.0, min, max),
        };
        Self {
            mode,
            tonemap,
            scale,
            lo,
            hi,
            pad: [0; 3],
        }
    }
}

/// viridis then magma, [`LUT`] entries each, as nrc-eval's false-colour images colour them.
fn colour_table() -> Vec<[f32; 4]> {
    use nrc_eval::image::ScalarImage;
    use nrc_eval::png_output::{ColorMap, Scale, false_color_rgb8};
    let ramp = ScalarImage {
        width: LUT,
        height: 1,
        values: (0..LUT).map(|i| i as f32 / (LUT - 1) as f32).collect(),
    };
    [ColorMap::Viridis, ColorMap::Magma]
        .into_iter()
        .flat_map(|map| {
            let bytes = false_color_rgb8(&ramp, map, Scale::Linear { min: 0.0, max: 1.0 })
                .expect("a linear [0, 1] scale is valid");
            bytes
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]].map(|b| f32::from(b) / 255.0))
                .map(|[r, g, b]| [r, g, b, 1.0])
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The display pass and its textures, for one viewport size.
pub struct Display {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    lut: wgpu::Buffer,
    image: wgpu::Texture,
    aux: wgpu::Texture,
    bind_group: wgpu::BindGroup,
    /// The viewport: what egui shows and screenshots read.
    pub target: wgpu::Texture,
    pub target_view: wgpu::TextureView,
    pub width: u32,
    pub height: u32,
}

impl Display {
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Self {
        let device = &gpu.device;
        let (pipeline, layout) = fullscreen_pass(
            device,
            "view",
            SHADER,
            &[
                binding(0, uniform()),
                binding(1, float_texture()),
                binding(2, float_texture()),
                binding(3, storage()),
            ],
            FORMAT,
        );
        let params = uniform_buffer(device, "view params", std::mem::size_of::<Params>());
        let table = colour_table();
        let lut = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view colour maps"),
            size: std::mem::size_of_val(table.as_slice()) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        gpu.queue
            .write_buffer(&lut, 0, bytemuck::cast_slice(table.as_slice()));
        let (image, aux, target) = Self::textures(gpu, width, height);
        let bind_group = Self::bind(gpu, &layout, &params, &lut, &image, &aux);
        let target_view = target.create_view(&Default::default());
        Self {
            pipeline,
            layout,
            params,
            lut,
            image,
            aux,
            bind_group,
            target,
            target_view,
            width,
            height,
        }
    }

    fn textures(
        gpu: &Gpu,
        width: u32,
        height: u32,
    ) -> (wgpu::Texture, wgpu::Texture, wgpu::Texture) {
        let size = wgpu::Extent3d {
            width: width.max(1),
            height: height.max(1),
            depth_or_array_layers: 1,
        };
        let float = |label| {
            gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        };
        let target = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("viewport"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        (float("frame"), float("aux"), target)
    }

    fn bind(
        gpu: &Gpu,
        layout: &wgpu::BindGroupLayout,
        params: &wgpu::Buffer,
        lut: &wgpu::Buffer,
        image: &wgpu::Texture,
        aux: &wgpu::Texture,
    ) -> wgpu::BindGroup {
        let image_view = image.create_view(&Default::default());
        let aux_view = aux.create_view(&Default::default());
        gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("view"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&image_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&aux_view),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: lut.as_entire_binding(),
                },
            ],
        })
    }

    /// Resizes the textures to `width × height` (a new frame size); whether they changed.
    pub fn resize(&mut self, gpu: &Gpu, width: u32, height: u32) -> bool {
        if (width, height) == (self.width, self.height) {
            return false;
        }
        let (image, aux, target) = Self::textures(gpu, width, height);
        self.bind_group = Self::bind(gpu, &self.layout, &self.params, &self.lut, &image, &aux);
        self.target_view = target.create_view(&Default::default());
        (self.image, self.aux, self.target) = (image, aux, target);
        (self.width, self.height) = (width, height);
        true
    }

    /// Uploads `image` (the frame's radiance or a view's scalar) and, where the view needs one,
    /// `aux` (the reference or the counts); non-finite values as 0. Both must be of the
    /// display's size.
    pub fn upload(&mut self, gpu: &Gpu, image: &Image, aux: Option<&Image>) {
        let write = |texture: &wgpu::Texture, img: &Image| {
            if (img.width, img.height) != (self.width as usize, self.height as usize) {
                return;
            }
            let texels: Vec<[f32; 4]> = img
                .data
                .iter()
                .map(|v| {
                    let f = |x: f32| if x.is_finite() { x } else { 0.0 };
                    [f(v.x), f(v.y), f(v.z), 1.0]
                })
                .collect();
            gpu.queue.write_texture(
                texture.as_image_copy(),
                bytemuck::cast_slice(&texels),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.width * 16),
                    rows_per_image: Some(self.height),
                },
                texture.size(),
            );
        };
        write(&self.image, image);
        if let Some(aux) = aux {
            write(&self.aux, aux);
        }
    }

    /// Draws the uploaded frame into the viewport texture as `shade` says.
    pub fn draw(&self, gpu: &Gpu, shade: Shade) {
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&Params::of(shade)));
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("view"),
            });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("view"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.target_view,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                    depth_slice: None,
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.draw(0..3, 0..1);
        }
        gpu.queue.submit([encoder.finish()]);
    }

    /// The viewport's pixels, RGBA 8-bit, row-major.
    pub fn read(&self, gpu: &Gpu) -> Result<Vec<u8>, ViewError> {
        read_rgba8(gpu, &self.target)
    }
}

/// The pixels of an 8-bit RGBA (or BGRA, swizzled to RGBA) texture, row-major.
pub fn read_rgba8(gpu: &Gpu, texture: &wgpu::Texture) -> Result<Vec<u8>, ViewError> {
    let (w, h) = (texture.width(), texture.height());
    let row = w * 4;
    let padded =
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: u64::from(padded) * u64::from(h),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: Some(h),
            },
        },
        texture.size(),
    );
    gpu.queue.submit([encoder.finish()]);
    let slice = buffer.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| ViewError::Gpu(format!("waiting for a readback: {e}")))?;
    rx.recv()
        .map_err(|e| ViewError::Gpu(format!("readback: {e}")))?
        .map_err(|e| ViewError::Gpu(format!("readback: {e}")))?;
    let bgra = matches!(
        texture.format(),
        wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb
    );
    let mut out = Vec::with_capacity((row * h) as usize);
    {
        let view = slice
            .get_mapped_range()
            .map_err(|e| ViewError::Gpu(format!("readback: {e}")))?;
        for y in 0..h as usize {
            let start = y * padded as usize;
            out.extend_from_slice(&view[start..start + row as usize]);
        }
    }
    buffer.unmap();
    if bgra {
        for px in out.chunks_exact_mut(4) {
            px.swap(0, 2);
        }
    }
    Ok(out)
}

/// Writes RGBA pixels as an 8-bit RGB PNG, atomically.
pub fn write_png(path: &Path, width: u32, height: u32, rgba: &[u8]) -> Result<(), ViewError> {
    let rgb: Vec<u8> = rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    nrc_eval::png_output::write_rgb8_png(path, width as usize, height as usize, &rgb)
        .map_err(|e| ViewError::Output(path.display().to_string(), e.to_string()))
}
