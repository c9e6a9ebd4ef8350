//! Colour spaces used by FLIP: sRGB transfer, linear sRGB ↔ CIE XYZ (D65), the opponent space
//! YCxCz (linearised CIELab, in which the contrast-sensitivity filters act), CIELab, the Hunt
//! adjustment and the HyAB colour distance. Constants follow the FLIP papers and NVIDIA's tool
//! (f32 arithmetic), so results agree with the tool to float rounding.

/// D65 reference white in XYZ.
const ILLUMINANT: [f32; 3] = [0.950_428_55, 1.0, 1.088_900_4];
/// 1 / D65 reference white.
const INV_ILLUMINANT: [f32; 3] = [1.052_156_9, 1.0, 0.918_357_7];

/// sRGB electro-optical transfer: encoded value → linear.
pub(crate) fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Luminance of linear sRGB (Rec. 709 weights).
pub(crate) fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Linear sRGB → CIE XYZ (D65).
pub(crate) fn linear_rgb_to_xyz(c: [f32; 3]) -> [f32; 3] {
    const A: [[f32; 3]; 3] = [
        [
            10135552.0 / 24577794.0,
            8788810.0 / 24577794.0,
            4435075.0 / 24577794.0,
        ],
        [
            2613072.0 / 12288897.0,
            8788810.0 / 12288897.0,
            887015.0 / 12288897.0,
        ],
        [
            1425312.0 / 73733382.0,
            8788810.0 / 73733382.0,
            70074185.0 / 73733382.0,
        ],
    ];
    mat_mul(&A, c)
}

/// CIE XYZ (D65) → linear sRGB.
pub(crate) fn xyz_to_linear_rgb(c: [f32; 3]) -> [f32; 3] {
    const A: [[f32; 3]; 3] = [
        [3.241_003_3, -1.537_398_9, -0.498_615_87],
        [-0.969_224_3, 1.875_930_1, 0.041_554_224],
        [0.055_639_423, -0.204_011_2, 1.057_148_9],
    ];
    mat_mul(&A, c)
}

/// CIE XYZ → YCxCz (the opponent space of FLIP's spatial filtering).
pub(crate) fn xyz_to_ycxcz(c: [f32; 3]) -> [f32; 3] {
    let x = c[0] * INV_ILLUMINANT[0];
    let y = c[1] * INV_ILLUMINANT[1];
    let z = c[2] * INV_ILLUMINANT[2];
    [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
}

/// YCxCz → CIE XYZ.
pub(crate) fn ycxcz_to_xyz(c: [f32; 3]) -> [f32; 3] {
    let y = (c[0] + 16.0) / 116.0;
    let cx = c[1] / 500.0;
    let cz = c[2] / 200.0;
    [
        (y + cx) * ILLUMINANT[0],
        y * ILLUMINANT[1],
        (y - cz) * ILLUMINANT[2],
    ]
}

/// CIE XYZ → CIELab.
pub(crate) fn xyz_to_cielab(c: [f32; 3]) -> [f32; 3] {
    const DELTA: f32 = 6.0 / 29.0;
    const DELTA_CUBE: f32 = DELTA * DELTA * DELTA;
    const FACTOR: f32 = 1.0 / (3.0 * DELTA * DELTA);
    const TERM: f32 = 4.0 / 29.0;
    let f = |v: f32| {
        if v > DELTA_CUBE {
            v.powf(1.0 / 3.0)
        } else {
            FACTOR * v + TERM
        }
    };
    let x = f(c[0] * INV_ILLUMINANT[0]);
    let y = f(c[1] * INV_ILLUMINANT[1]);
    let z = f(c[2] * INV_ILLUMINANT[2]);
    [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
}

/// Hunt adjustment: chroma scaled by 0.01·L (colours look less saturated in the dark).
pub(crate) fn hunt(lab: [f32; 3]) -> [f32; 3] {
    [lab[0], 0.01 * lab[0] * lab[1], 0.01 * lab[0] * lab[2]]
}

/// HyAB distance: city-block on lightness plus Euclidean on the chromatic plane.
pub(crate) fn hyab(a: [f32; 3], b: [f32; 3]) -> f32 {
    let da = a[1] - b[1];
    let db = a[2] - b[2];
    (a[0] - b[0]).abs() + (da * da + db * db).sqrt()
}

/// Linear sRGB → YCxCz.
pub(crate) fn linear_rgb_to_ycxcz(c: [f32; 3]) -> [f32; 3] {
    xyz_to_ycxcz(linear_rgb_to_xyz(c))
}

/// Linear sRGB → Hunt-adjusted CIELab.
pub(crate) fn linear_rgb_to_hunt_lab(c: [f32; 3]) -> [f32; 3] {
    hunt(xyz_to_cielab(linear_rgb_to_xyz(c)))
}

fn mat_mul(a: &[[f32; 3]; 3], c: [f32; 3]) -> [f32; 3] {
    [
        a[0][0] * c[0] + a[0][1] * c[1] + a[0][2] * c[2],
        a[1][0] * c[0] + a[1][1] * c[1] + a[1][2] * c[2],
        a[2][0] * c[0] + a[2][1] * c[1] + a[2][2] * c[2],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_maps_to_lab_100_and_back() {
        let lab = xyz_to_cielab(linear_rgb_to_xyz([1.0, 1.0, 1.0]));
        assert!(
            (lab[0] - 100.0).abs() < 1e-3 && lab[1].abs() < 1e-2 && lab[2].abs() < 1e-2,
            "{lab:?}"
        );
        let rgb = xyz_to_linear_rgb(ycxcz_to_xyz(linear_rgb_to_ycxcz([0.2, 0.5, 0.9])));
        for (a, b) in rgb.iter().zip([0.2, 0.5, 0.9]) {
            assert!((a - b).abs() < 1e-5, "{rgb:?}");
        }
    }
}
