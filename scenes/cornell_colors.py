"""Converts the Cornell box's measured spectra to the linear sRGB values used by
`crates/nrc-scene/examples/make_scenes/cornell_box.rs` (see scenes/README.md).

Data: "Cornell Box Data", Cornell University Program of Computer Graphics
(graphics.cornell.edu/online/box/data.html): reflectances of the white, green and red
surfaces at 400, 404, ..., 700 nm; light emission 0, 8, 15.6, 18.4 at 400, 500, 600, 700 nm.

Method: spectra linearly interpolated to 1 nm over 360-830 nm (reflectances held constant
beyond the measured range, emission zero outside it, as Mitsuba and pbrt treat sampled
emission); CIE 1931 2-degree colour-matching functions; XYZ to linear sRGB with the sRGB
(IEC 61966-2-1) matrix.
  reflectance:  XYZ = sum(rho * D65 * cmf) / sum(D65 * ybar)   (a perfect white gives D65, RGB 1)
  emission:     XYZ = sum(L * cmf) / sum(ybar)                   (Y is the spectrum's luminance-weighted mean)
Cross-check: the same code with an equal-energy illuminant and no white balance agrees within
0.003 with the RGB values of Mitsuba 3's built-in Cornell box (`mi.cornell_box()`: white
0.8858 0.6989 0.6664, red 0.5701 0.0430 0.0444, green 0.1054 0.3780 0.0764), printed last.

Run:  pip install colour-science && python3 scenes/cornell_colors.py
"""

import warnings

import numpy as np

warnings.filterwarnings("ignore")
import colour  # noqa: E402  (colour-science, for the CIE tables)

WAVELENGTHS = np.arange(400, 701, 4)
WHITE = [0.343, 0.445, 0.551, 0.624, 0.665, 0.687, 0.708, 0.723, 0.715, 0.710, 0.745, 0.758, 0.739, 0.767, 0.777, 0.765,
         0.751, 0.745, 0.748, 0.729, 0.745, 0.757, 0.753, 0.750, 0.746, 0.747, 0.735, 0.732, 0.739, 0.734, 0.725, 0.721,
         0.733, 0.725, 0.732, 0.743, 0.744, 0.748, 0.728, 0.716, 0.733, 0.726, 0.713, 0.740, 0.754, 0.764, 0.752, 0.736,
         0.734, 0.741, 0.740, 0.732, 0.745, 0.755, 0.751, 0.744, 0.731, 0.733, 0.744, 0.731, 0.712, 0.708, 0.729, 0.730,
         0.727, 0.707, 0.703, 0.729, 0.750, 0.760, 0.751, 0.739, 0.724, 0.730, 0.740, 0.737]
GREEN = [0.092, 0.096, 0.098, 0.097, 0.098, 0.095, 0.095, 0.097, 0.095, 0.094, 0.097, 0.098, 0.096, 0.101, 0.103, 0.104,
         0.107, 0.109, 0.112, 0.115, 0.125, 0.140, 0.160, 0.187, 0.229, 0.285, 0.343, 0.390, 0.435, 0.464, 0.472, 0.476,
         0.481, 0.462, 0.447, 0.441, 0.426, 0.406, 0.373, 0.347, 0.337, 0.314, 0.285, 0.277, 0.266, 0.250, 0.230, 0.207,
         0.186, 0.171, 0.160, 0.148, 0.141, 0.136, 0.130, 0.126, 0.123, 0.121, 0.122, 0.119, 0.114, 0.115, 0.117, 0.117,
         0.118, 0.120, 0.122, 0.128, 0.132, 0.139, 0.144, 0.146, 0.150, 0.152, 0.157, 0.159]
RED = [0.040, 0.046, 0.048, 0.053, 0.049, 0.050, 0.053, 0.055, 0.057, 0.056, 0.059, 0.057, 0.061, 0.061, 0.060, 0.062,
       0.062, 0.062, 0.061, 0.062, 0.060, 0.059, 0.057, 0.058, 0.058, 0.058, 0.056, 0.055, 0.056, 0.059, 0.057, 0.055,
       0.059, 0.059, 0.058, 0.059, 0.061, 0.061, 0.063, 0.063, 0.067, 0.068, 0.072, 0.080, 0.090, 0.099, 0.124, 0.154,
       0.192, 0.255, 0.287, 0.349, 0.402, 0.443, 0.487, 0.513, 0.558, 0.584, 0.620, 0.606, 0.609, 0.651, 0.612, 0.610,
       0.650, 0.638, 0.627, 0.620, 0.630, 0.628, 0.642, 0.639, 0.657, 0.639, 0.635, 0.642]
LIGHT_WAVELENGTHS = [400, 500, 600, 700]
LIGHT = [0.0, 8.0, 15.6, 18.4]

assert len(WHITE) == len(GREEN) == len(RED) == len(WAVELENGTHS) == 76

LAM = np.arange(360, 831, 1.0)
_cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
CMF = np.array([_cmfs[l] for l in LAM])  # (n, 3): xbar, ybar, zbar
D65 = np.array([colour.SDS_ILLUMINANTS["D65"][l] for l in LAM])
XYZ_TO_SRGB = colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB


def reflectance_rgb(values, illuminant=D65):
    rho = np.interp(LAM, WAVELENGTHS, values)  # constant beyond the measured range
    xyz = (rho * illuminant) @ CMF / (illuminant @ CMF[:, 1])
    return XYZ_TO_SRGB @ xyz


def emission_rgb():
    radiance = np.interp(LAM, LIGHT_WAVELENGTHS, LIGHT, left=0.0, right=0.0)
    xyz = radiance @ CMF / CMF[:, 1].sum()
    return xyz, XYZ_TO_SRGB @ xyz


if __name__ == "__main__":
    print("perfect white ->", np.round(reflectance_rgb([1.0] * 76), 4))
    for name, values in (("white", WHITE), ("red", RED), ("green", GREEN)):
        print(f"{name:6} {np.round(reflectance_rgb(values), 4)}")
    xyz, rgb = emission_rgb()
    print(f"light  XYZ {np.round(xyz, 4)}  linear sRGB {np.round(rgb, 4)}")
    print("cross-check, equal-energy illuminant, no white balance (compare Mitsuba 3's cornell_box()):")
    for name, values in (("white", WHITE), ("red", RED), ("green", GREEN)):
        print(f"  {name:6} {np.round(reflectance_rgb(values, np.ones_like(LAM)), 4)}")
