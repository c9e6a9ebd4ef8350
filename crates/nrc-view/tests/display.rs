//! The display pass (`shaders/view.wgsl`) against the CPU's own images: tone mapping as
//! `nrc render --png` writes it, the error view as `nrc compare`'s relMSE images, the heat map
//! as a log scale of counts. Needs a wgpu adapter (Mesa's software Vulkan in CI).

use glam::Vec3;
use nrc_eval::ImageView;
use nrc_eval::png_output::{ColorMap, Scale, false_color_rgb8};
use nrc_scene::image::Image;
use nrc_view::display::{Display, Gpu, Shade, ToneMap};

fn gpu(test: &str) -> Option<Gpu> {
    match Gpu::headless() {
        Ok(g) => Some(g),
        Err(e) => {
            nrc_scene::testing::skipped(test, &format!("no wgpu adapter: {e}"));
            None
        }
    }
}

/// An HDR test image: a ramp over six decades per channel, with the values the CPU's preview
/// treats specially (negative, NaN, infinite, zero).
fn ramp(w: usize, h: usize) -> Image {
    let mut data = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let t = (y * w + x) as f32 / (w * h - 1) as f32;
            let v = 10f32.powf(-4.0 + 6.0 * t);
            data.push(Vec3::new(v, v * 0.5, (1.0 - t) * 3.0));
        }
    }
    data[0] = Vec3::new(-1.0, f32::NAN, f32::INFINITY);
    data[1] = Vec3::ZERO;
    Image::from_data(w, h, data).unwrap()
}

fn rgb(rgba: &[u8]) -> Vec<u8> {
    rgba.chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

/// Largest channel difference and how many channels differ at all.
fn diff(a: &[u8], b: &[u8]) -> (u8, usize) {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).fold((0, 0), |(m, n), (x, y)| {
        let d = x.abs_diff(*y);
        (m.max(d), n + usize::from(d > 0))
    })
}

#[test]
fn tone_mapping_matches_the_cpu_preview_and_exposure_and_curve_change_it() {
    let Some(gpu) = gpu("tone_mapping_matches_the_cpu_preview_and_exposure_and_curve_change_it")
    else {
        return;
    };
    let (w, h) = (96, 40);
    let image = ramp(w, h);
    let mut display = Display::new(&gpu, w as u32, h as u32);
    display.upload(&gpu, &image, None);
    for exposure in [0.0, 2.5, -3.0] {
        display.draw(
            &gpu,
            Shade::Tone {
                exposure,
                tonemap: ToneMap::Aces,
            },
        );
        let shown = rgb(&display.read(&gpu).unwrap());
        let cpu = image.to_srgb8(exposure);
        let (max, _) = diff(&shown, &cpu);
        assert!(max <= 1, "exposure {exposure}: off by {max} levels");
        // The special pixels: negative, NaN and infinite show black, as on the CPU.
        assert_eq!(&shown[0..3], &[0, 0, 0]);
    }
    // Negative control: another curve (or exposure) is not the preview.
    display.draw(
        &gpu,
        Shade::Tone {
            exposure: 0.0,
            tonemap: ToneMap::Reinhard,
        },
    );
    let reinhard = rgb(&display.read(&gpu).unwrap());
    let (max, n) = diff(&reinhard, &image.to_srgb8(0.0));
    assert!(max > 10 && n > w * h, "Reinhard should differ: {max} {n}");
    let (max, _) = diff(&reinhard, &image.to_srgb8(1.0));
    assert!(max > 10);
}

#[test]
fn error_and_heat_views_use_the_colour_maps_of_the_comparison_images() {
    let Some(gpu) = gpu("error_and_heat_views_use_the_colour_maps_of_the_comparison_images") else {
        return;
    };
    let (w, h) = (64, 32);
    let reference = ramp(w, h);
    // A test image with errors from 0 to large, relative to the reference.
    let mut test = reference.clone();
    for (i, v) in test.data.iter_mut().enumerate() {
        let f = 1.0 + 3.0 * (i as f32 / (w * h) as f32).powi(3);
        *v = Vec3::new(v.x * f, v.y, v.z + 0.01 * i as f32);
    }
    test.data[0] = Vec3::ZERO;
    let mut clean = reference.clone();
    clean.data[0] = Vec3::ZERO;
    let mut display = Display::new(&gpu, w as u32, h as u32);
    display.upload(&gpu, &test, Some(&clean));
    display.draw(&gpu, Shade::RelError);
    let shown = rgb(&display.read(&gpu).unwrap());
    let map = nrc_eval::metrics::rel_mse_map(
        &ImageView::of_scene_image("test", &test).unwrap(),
        &ImageView::of_scene_image("reference", &clean).unwrap(),
        nrc_eval::metrics::REL_MSE_EPSILON,
    )
    .unwrap();
    let cpu = false_color_rgb8(
        &map,
        ColorMap::Viridis,
        Scale::Log {
            min: 1e-4,
            max: 10.0,
        },
    )
    .unwrap();
    // The shader reads the map at 1,024 points: within a few levels of the continuous map.
    let (max, _) = diff(&shown, &cpu);
    assert!(max <= 3, "error view off by {max} levels");

    // Heat map: counts on a log scale up to the largest, through magma.
    let counts = Image::from_data(
        w,
        h,
        (0..w * h)
            .map(|i| Vec3::new((i % 37) as f32, 0.0, 0.0))
            .collect(),
    )
    .unwrap();
    display.upload(&gpu, &Image::new(w, h), Some(&counts));
    display.draw(&gpu, Shade::Heat { max: 36.0 });
    let heat = rgb(&display.read(&gpu).unwrap());
    let scalar = nrc_eval::ScalarImage {
        width: w,
        height: h,
        values: counts
            .data
            .iter()
            .map(|c| (1.0 + c.x).ln() / 37f32.ln())
            .collect(),
    };
    let cpu = false_color_rgb8(
        &scalar,
        ColorMap::Magma,
        Scale::Linear { min: 0.0, max: 1.0 },
    )
    .unwrap();
    let (max, _) = diff(&heat, &cpu);
    assert!(max <= 3, "heat map off by {max} levels");
    // Negative control: the heat map is not the error view's colour map.
    let viridis = false_color_rgb8(
        &scalar,
        ColorMap::Viridis,
        Scale::Linear { min: 0.0, max: 1.0 },
    )
    .unwrap();
    assert!(diff(&heat, &viridis).0 > 20);
}
