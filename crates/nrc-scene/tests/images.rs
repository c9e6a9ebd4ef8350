//! EXR round trips bit for bit; the PNG preview is a valid, correctly sized PNG; writes are
//! atomic (no temporary file left behind).

use glam::Vec3;
use nrc_scene::Image;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn test_image() -> Image {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let (w, h) = (37, 23);
    let mut data: Vec<Vec3> = (0..w * h)
        .map(|_| {
            Vec3::new(
                rng.random::<f32>() * 1e3,
                rng.random::<f32>() * 1e-3,
                f32::from_bits(rng.random::<u32>() & 0x7f7f_ffff), // any finite positive
            )
        })
        .collect();
    data[0] = Vec3::new(0.0, -0.0, -5.5);
    data[1] = Vec3::new(f32::MIN_POSITIVE / 4.0, f32::MAX, 1.0);
    Image::from_data(w, h, data).unwrap()
}

#[test]
fn exr_round_trip_is_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.exr");
    let img = test_image();
    img.write_exr(&path).unwrap();
    let back = Image::read_exr(&path).unwrap();
    assert_eq!((back.width, back.height), (img.width, img.height));
    for (a, b) in img.data.iter().zip(&back.data) {
        for c in 0..3 {
            assert_eq!(a[c].to_bits(), b[c].to_bits(), "{a} vs {b}");
        }
    }
    // Only the file itself is left: the temporary was renamed.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("frame.exr")]);
    // Overwriting works too.
    Image::new(2, 2).write_exr(&path).unwrap();
    assert_eq!(Image::read_exr(&path).unwrap(), Image::new(2, 2));
}

#[test]
fn exr_errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nothing_here.exr");
    assert!(
        Image::read_exr(&missing)
            .unwrap_err()
            .to_string()
            .contains("nothing_here.exr")
    );
    let garbage = dir.path().join("garbage.exr");
    std::fs::write(&garbage, b"definitely not an OpenEXR file").unwrap();
    assert!(
        Image::read_exr(&garbage)
            .unwrap_err()
            .to_string()
            .contains("garbage.exr")
    );
    let no_dir = dir.path().join("no/such/folder/out.exr");
    assert!(
        Image::new(1, 1)
            .write_exr(&no_dir)
            .unwrap_err()
            .to_string()
            .contains("out.exr")
    );
    assert!(
        Image::new(0, 0)
            .write_exr(&dir.path().join("empty.exr"))
            .is_err()
    );
}

#[test]
fn png_preview_is_valid() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("preview.png");
    let mut img = Image::new(5, 3);
    img.set(1, 0, Vec3::splat(0.18));
    img.set(2, 0, Vec3::splat(1e6));
    img.set(3, 2, Vec3::new(1.0, 0.0, 0.0));
    img.write_png_preview(&path, 0.0).unwrap();
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (5, 3));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    let px = |x: usize, y: usize| &buf[(y * 5 + x) * 3..(y * 5 + x) * 3 + 3];
    assert_eq!(px(0, 0), [0, 0, 0]);
    assert!(
        px(1, 0)[0] > 40 && px(1, 0)[0] < 200,
        "mid grey stays mid grey: {:?}",
        px(1, 0)
    );
    assert_eq!(px(2, 0), [255, 255, 255]);
    assert!(px(3, 2)[0] > 150 && px(3, 2)[1] == 0 && px(3, 2)[2] == 0);
    // Exposure brightens monotonically.
    let darker = img.to_srgb8(-2.0);
    let brighter = img.to_srgb8(2.0);
    assert!(darker[3] < px(1, 0)[0] && brighter[3] > px(1, 0)[0]);
}
