//! MSE, relMSE, MAPE and FLIP on constructed images with closed-form answers, and the errors
//! bad input must give.

use nrc_eval::metrics::{
    MAPE_EPSILON, REL_MSE_EPSILON, mape, mse, rel_mse, rel_mse_map, squared_error_map,
};
use nrc_eval::{EvalError, HdrFlipParams, ImageView, MetricOptions, compute_metrics, hdr_flip};

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * b.abs().max(1.0)
}

#[test]
fn constant_images_with_known_difference() {
    let y = vec![[2.0f32; 3]; 12];
    let x = vec![[2.5f32; 3]; 12];
    let (r, t) = (
        ImageView::new("ref", 4, 3, &y).unwrap(),
        ImageView::new("test", 4, 3, &x).unwrap(),
    );
    assert!(close(mse(&t, &r).unwrap(), 0.25));
    assert!(close(
        rel_mse(&t, &r, REL_MSE_EPSILON).unwrap(),
        0.25 / 4.01
    ));
    assert!(close(mape(&t, &r, MAPE_EPSILON).unwrap(), 0.5 / 2.01));
    // A larger ε only shrinks relMSE.
    assert!(close(rel_mse(&t, &r, 1.0).unwrap(), 0.25 / 5.0));
}

#[test]
fn per_channel_errors_are_averaged() {
    // Channel errors 0, 1, −2 against reference 1, 2, 4.
    let y = vec![[1.0f32, 2.0, 4.0]; 6];
    let x = vec![[1.0f32, 3.0, 2.0]; 6];
    let (r, t) = (
        ImageView::new("ref", 3, 2, &y).unwrap(),
        ImageView::new("test", 3, 2, &x).unwrap(),
    );
    assert!(close(mse(&t, &r).unwrap(), 5.0 / 3.0));
    assert!(close(
        rel_mse(&t, &r, 0.01).unwrap(),
        (1.0 / 4.01 + 4.0 / 16.01) / 3.0
    ));
    assert!(close(
        mape(&t, &r, 0.01).unwrap(),
        (1.0 / 2.01 + 2.0 / 4.01) / 3.0
    ));
}

#[test]
fn errors_average_over_pixels_and_maps_agree() {
    // Left half exact, right half off by 1 on a black reference: relMSE of an error pixel is 1/ε.
    let (w, h) = (8, 4);
    let y = vec![[0.0f32; 3]; w * h];
    let x: Vec<[f32; 3]> = (0..w * h)
        .map(|i| if i % w >= w / 2 { [1.0; 3] } else { [0.0; 3] })
        .collect();
    let (r, t) = (
        ImageView::new("ref", w, h, &y).unwrap(),
        ImageView::new("test", w, h, &x).unwrap(),
    );
    assert!(close(mse(&t, &r).unwrap(), 0.5));
    let rel = rel_mse(&t, &r, 0.01).unwrap();
    assert!(close(rel, 0.5 / 0.01));
    assert!(close(mape(&t, &r, 0.01).unwrap(), 0.5 / 0.01));
    let map = rel_mse_map(&t, &r, 0.01).unwrap();
    assert!((map.mean() - rel).abs() < 1e-4 * rel);
    assert_eq!(map.values[w - 1], 100.0);
    assert_eq!(map.values[0], 0.0);
    assert!((squared_error_map(&t, &r).unwrap().mean() - 0.5).abs() < 1e-12);
}

#[test]
fn identical_images_have_zero_error_everywhere() {
    let y: Vec<[f32; 3]> = (0..256)
        .map(|i| [i as f32 * 0.1, 1.0, (i % 7) as f32])
        .collect();
    let r = ImageView::new("ref", 16, 16, &y).unwrap();
    let m = compute_metrics(&r, &r, &MetricOptions::default()).unwrap();
    assert_eq!(
        (m.mse, m.rel_mse, m.mape, m.flip),
        (0.0, 0.0, 0.0, Some(0.0))
    );
}

#[test]
fn hdr_flip_grows_with_the_error() {
    // A smooth HDR ramp, and tests that scale it by a growing factor.
    let (w, h) = (24, 16);
    let y: Vec<[f32; 3]> = (0..w * h)
        .map(|i| {
            let u = (i % w) as f32 / w as f32;
            [0.1 + 3.0 * u, 0.2 + u, 0.3]
        })
        .collect();
    let r = ImageView::new("ref", w, h, &y).unwrap();
    let mut last = 0.0;
    for factor in [1.05f32, 1.3, 2.0, 6.0] {
        let x: Vec<[f32; 3]> = y.iter().map(|p| p.map(|v| v * factor)).collect();
        let f = hdr_flip(
            &ImageView::new("test", w, h, &x).unwrap(),
            &r,
            &HdrFlipParams::default(),
        )
        .unwrap()
        .mean;
        assert!(
            f > last && f <= 1.0,
            "factor {factor}: FLIP {f} after {last}"
        );
        last = f;
    }
}

#[test]
fn bad_input_gives_named_errors() {
    let y = vec![[1.0f32; 3]; 4];
    let r = ImageView::new("reference", 2, 2, &y).unwrap();

    let wrong_len = vec![[1.0f32; 3]; 5];
    let err = ImageView::new("render", 2, 2, &wrong_len).unwrap_err();
    assert!(
        matches!(err, EvalError::BadDimensions { .. }) && err.to_string().contains("render"),
        "{err}"
    );
    assert!(ImageView::new("empty", 0, 3, &[]).is_err());

    let other = vec![[1.0f32; 3]; 6];
    let err = mse(&ImageView::new("render", 3, 2, &other).unwrap(), &r).unwrap_err();
    assert!(
        matches!(err, EvalError::SizeMismatch { .. }) && err.to_string().contains("3x2"),
        "{err}"
    );

    let mut nan = y.clone();
    nan[3][1] = f32::NAN;
    let err = rel_mse(&ImageView::new("render", 2, 2, &nan).unwrap(), &r, 0.01).unwrap_err();
    assert!(err.to_string().contains("pixel (1, 1) channel 1"), "{err}");
    let err = hdr_flip(
        &r,
        &ImageView::new("nan-ref", 2, 2, &nan).unwrap(),
        &HdrFlipParams::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("nan-ref"), "{err}");

    let err = rel_mse(&r, &r, 0.0).unwrap_err();
    assert!(err.to_string().contains("epsilon"), "{err}");
    let mut negative = y.clone();
    negative[0][2] = -0.5;
    let err = mape(&r, &ImageView::new("neg", 2, 2, &negative).unwrap(), 0.01).unwrap_err();
    assert!(err.to_string().contains("negative"), "{err}");

    let params = HdrFlipParams {
        ppd: -1.0,
        ..HdrFlipParams::default()
    };
    assert!(
        hdr_flip(&r, &r, &params)
            .unwrap_err()
            .to_string()
            .contains("ppd")
    );
    let params = HdrFlipParams {
        start_exposure: Some(2.0),
        stop_exposure: Some(1.0),
        ..HdrFlipParams::default()
    };
    assert!(
        hdr_flip(&r, &r, &params)
            .unwrap_err()
            .to_string()
            .contains("start")
    );
}

#[test]
fn mostly_black_reference_uses_median_of_lit_pixels() {
    // 3 of 4 pixels black: the tool's median would be 0 (infinite stop exposure); ours falls
    // back to the median of the lit pixels, here the only one, so start == stop.
    let y = vec![[0.0f32; 3], [0.0; 3], [0.0; 3], [2.0; 3]];
    let r = ImageView::new("ref", 2, 2, &y).unwrap();
    let x = vec![[0.1f32; 3]; 4];
    let res = hdr_flip(
        &ImageView::new("test", 2, 2, &x).unwrap(),
        &r,
        &HdrFlipParams::default(),
    )
    .unwrap();
    assert_eq!(res.start_exposure, res.stop_exposure);
    assert_eq!(res.num_exposures, 2);
    assert!(res.mean > 0.0 && res.mean.is_finite());
}

#[test]
fn scene_images_are_viewed_without_copying() {
    use nrc_eval::RgbImage;
    let img = nrc_scene::image::Image::from_data(
        2,
        1,
        vec![
            glam::Vec3::new(1.0, 2.0, 3.0),
            glam::Vec3::new(4.0, 5.0, 6.0),
        ],
    )
    .unwrap();
    let v = ImageView::of_scene_image("frame", &img).unwrap();
    assert_eq!(v.pixels(), &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    assert_eq!(
        v.pixels().as_ptr() as *const u8,
        img.data.as_ptr() as *const u8
    );
    let back = RgbImage {
        width: 2,
        height: 1,
        pixels: v.pixels().to_vec(),
    }
    .into_scene_image();
    assert_eq!(back, img);
}
