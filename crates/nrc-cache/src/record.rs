//! Plain records exchanged with the cache: queries, training batches and the raw input vector.
//!
//! Producers and inference passes build these without knowing anything of burn.

/// One point of the radiance field to evaluate: where, in which direction, on what surface.
///
/// Laid out as 16 consecutive `f32` in field order (`repr(C)`, no padding), so that rows of a
/// `[N, 16]` float array are queries without a copy (`bytemuck::cast_slice`; the Python
/// module's query rows).
#[derive(Clone, Copy, Debug, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct CacheQuery {
    /// Position normalised to the scene box, in [0,1]³ (values outside are clamped).
    pub position: [f32; 3],
    /// Outgoing direction ω (need not be normalised; a zero or non-finite vector maps to +z).
    pub direction: [f32; 3],
    /// Surface normal (need not be normalised; a zero or non-finite vector maps to +z).
    pub normal: [f32; 3],
    /// Surface roughness r ≥ 0 (encoded as 1 − e^(−r)).
    pub roughness: f32,
    /// Diffuse reflectance α (RGB).
    pub diffuse: [f32; 3],
    /// Specular reflectance β (RGB).
    pub specular: [f32; 3],
}

/// Queries with their radiance targets (RGB, emission excluded) and optional per-sample weights.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainingBatch {
    /// Where the radiance was measured.
    pub queries: Vec<CacheQuery>,
    /// Measured outgoing radiance, one per query.
    pub targets: Vec<[f32; 3]>,
    /// Optional non-negative weight per query (1 when absent).
    pub weights: Option<Vec<f32>>,
}

impl TrainingBatch {
    /// Appends `other`'s records, keeping both batches' weights (a batch without weights
    /// counts 1 per record).
    pub fn append(&mut self, other: TrainingBatch) {
        let (n, m) = (self.queries.len(), other.queries.len());
        match (&mut self.weights, other.weights) {
            (None, None) => {}
            (Some(w), None) => w.resize(n + m, 1.0),
            (mine, Some(theirs)) => {
                let w = mine.get_or_insert_with(|| vec![1.0; n]);
                w.extend(theirs);
            }
        }
        self.queries.extend(other.queries);
        self.targets.extend(other.targets);
    }

    /// The records at `indices`, in that order, with their weights.
    pub fn select(&self, indices: &[usize]) -> TrainingBatch {
        TrainingBatch {
            queries: indices.iter().map(|&i| self.queries[i]).collect(),
            targets: indices.iter().map(|&i| self.targets[i]).collect(),
            weights: self
                .weights
                .as_ref()
                .map(|w| indices.iter().map(|&i| w[i]).collect()),
        }
    }
}

/// Number of raw input dimensions a query becomes before encoding (see [`raw_inputs`]).
pub const RAW_INPUT_DIMS: usize = 14;

/// Converts a query into the 14 raw network inputs, each in [0,1] (or the reflectances as given):
///
/// | dims    | meaning                                                        |
/// |---------|----------------------------------------------------------------|
/// | 0..3    | position (clamped to [0,1]³)                                   |
/// | 3, 4    | direction in spherical coordinates: θ/π, φ/(2π) wrapped to [0,1) |
/// | 5, 6    | normal in spherical coordinates, as the direction              |
/// | 7       | roughness as 1 − e^(−r)                                        |
/// | 8..11   | diffuse reflectance                                            |
/// | 11..14  | specular reflectance                                           |
///
/// Non-finite reflectances or roughness become 0; callers that need to know drop such queries
/// beforehand ([`query_is_finite`]).
pub fn raw_inputs(q: &CacheQuery) -> [f32; RAW_INPUT_DIMS] {
    raw_inputs_with(q, spherical(q.direction), spherical(q.normal))
}

/// [`raw_inputs`] of a group of queries: the spherical coordinates of all their directions and
/// normals are computed together ([`spherical_lanes`], which the compiler turns into vector
/// instructions), the same bits as one query at a time. `out` holds `stride ≥ 14` floats per
/// query, of which the first 14 are written.
pub fn raw_inputs_group(queries: &[CacheQuery; SPHERICAL_GROUP], out: &mut [f32], stride: usize) {
    let mut dirs = [[0f32; 3]; 2 * SPHERICAL_GROUP];
    for (i, q) in queries.iter().enumerate() {
        dirs[2 * i] = q.direction;
        dirs[2 * i + 1] = q.normal;
    }
    let angles = spherical_lanes(&dirs);
    for (i, q) in queries.iter().enumerate() {
        let [d, n] = [angles[2 * i], angles[2 * i + 1]];
        out[i * stride..i * stride + RAW_INPUT_DIMS].copy_from_slice(&raw_inputs_with(
            q,
            (d[0], d[1]),
            (n[0], n[1]),
        ));
    }
}

/// Queries per group of [`raw_inputs_group`].
pub const SPHERICAL_GROUP: usize = 8;

/// [`raw_inputs`] with the spherical coordinates of the direction and normal given.
#[inline(always)]
fn raw_inputs_with(q: &CacheQuery, dir: (f32, f32), normal: (f32, f32)) -> [f32; RAW_INPUT_DIMS] {
    let mut out = [0.0; RAW_INPUT_DIMS];
    for (o, p) in out.iter_mut().zip(q.position) {
        *o = if p.is_finite() {
            p.clamp(0.0, 1.0)
        } else {
            0.0
        };
    }
    [out[3], out[4]] = [dir.0, dir.1];
    [out[5], out[6]] = [normal.0, normal.1];
    let r = if q.roughness.is_finite() {
        q.roughness.max(0.0)
    } else {
        0.0
    };
    out[7] = 1.0 - (-r).exp();
    for k in 0..3 {
        out[8 + k] = finite_or_zero(q.diffuse[k]);
        out[11 + k] = finite_or_zero(q.specular[k]);
    }
    out
}

/// Reflectance factor the network output is multiplied by: diffuse + specular, per channel,
/// clamped to be non-negative and finite.
pub fn reflectance_factor(q: &CacheQuery) -> [f32; 3] {
    std::array::from_fn(|k| (finite_or_zero(q.diffuse[k]) + finite_or_zero(q.specular[k])).max(0.0))
}

/// Whether every field of a query is finite (training drops queries that are not).
pub fn query_is_finite(q: &CacheQuery) -> bool {
    q.position
        .iter()
        .chain(&q.direction)
        .chain(&q.normal)
        .chain(&q.diffuse)
        .chain(&q.specular)
        .all(|v| v.is_finite())
        && q.roughness.is_finite()
}

fn finite_or_zero(v: f32) -> f32 {
    if v.is_finite() { v } else { 0.0 }
}

/// Spherical coordinates of a vector, normalised to [0,1]: (θ/π, φ/(2π) in [0,1)).
/// Zero-length or non-finite vectors map to +z, i.e. (0, 0).
pub fn spherical(v: [f32; 3]) -> (f32, f32) {
    let [[theta, phi]] = spherical_lanes(&[v]);
    (theta, phi)
}

/// [`spherical`] of `N` vectors, `[θ/π, φ/(2π)]` each, written lane by lane with selects
/// instead of branches, so the compiler can run the lanes in vector registers ([`spherical`]
/// is the one-lane case, so every `N` gives the same bits).
pub fn spherical_lanes<const N: usize>(v: &[[f32; 3]; N]) -> [[f32; 2]; N] {
    use std::f32::consts::FRAC_1_PI;
    let lanes = |f: &dyn Fn(usize) -> f32| -> [f32; N] { std::array::from_fn(f) };
    let (x, y, z) = (
        lanes(&|i| v[i][0]),
        lanes(&|i| v[i][1]),
        lanes(&|i| v[i][2]),
    );
    let len2 = lanes(&|i| x[i] * x[i] + y[i] * y[i] + z[i] * z[i]);
    let rho = lanes(&|i| (x[i] * x[i] + y[i] * y[i]).sqrt());
    let theta = atan2_lanes(&rho, &z);
    let phi = atan2_lanes(&y, &x);
    std::array::from_fn(|i| {
        let valid = len2[i].is_finite() && len2[i] >= 1e-30;
        let theta = theta[i] * FRAC_1_PI;
        let mut phi = phi[i] * (0.5 * FRAC_1_PI);
        phi = if phi < 0.0 { phi + 1.0 } else { phi };
        phi = if phi >= 1.0 { 0.0 } else { phi };
        if valid {
            [theta.clamp(0.0, 1.0), phi]
        } else {
            [0.0, 0.0]
        }
    })
}

/// [`atan2`] of `N` pairs, lane by lane (see [`spherical_lanes`]; [`atan2`] is the one-lane
/// case).
fn atan2_lanes<const N: usize>(y: &[f32; N], x: &[f32; N]) -> [f32; N] {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (mut a, mut s, mut p) = ([0f32; N], [0f32; N], [0f32; N]);
    for i in 0..N {
        let (ax, ay) = (x[i].abs(), y[i].abs());
        let (lo, hi) = (ax.min(ay), ax.max(ay));
        a[i] = if hi > 0.0 { lo / hi } else { 0.0 };
        s[i] = a[i] * a[i];
    }
    for c in ATAN_C.iter().rev() {
        for i in 0..N {
            p[i] = p[i] * s[i] + c;
        }
    }
    std::array::from_fn(|i| {
        let mut r = a[i] + a[i] * s[i] * p[i];
        r = if y[i].abs() > x[i].abs() {
            FRAC_PI_2 - r
        } else {
            r
        };
        r = if x[i] < 0.0 { PI - r } else { r };
        if y[i] < 0.0 { -r } else { r }
    })
}

/// `atan2(y, x)` in (−π, π] for finite arguments, within about 1e-7 rad of the correctly
/// rounded value: the octant's `atan(min/max)` as the polynomial of Abramowitz & Stegun 4.4.49
/// (error ≤ 2e-8 on [0, 1]), then the octant's symmetries. No branches the compiler cannot turn
/// into selects, and about a fifth of the time of the C library's `atan2f` and `acosf` that
/// the query packing called before. `atan2(±0, ±0)` is 0.
pub fn atan2(y: f32, x: f32) -> f32 {
    atan2_lanes(&[y], &[x])[0]
}

/// The coefficients of [`atan2`]'s polynomial in `s = a²`, lowest first.
const ATAN_C: [f32; 8] = [
    -0.333_331_45,
    0.199_935_51,
    -0.142_088_99,
    0.106_562_64,
    -0.075_289_64,
    0.042_909_614,
    -0.016_165_737,
    0.002_866_225_7,
];

/// Rec. 709 luminance of a linear RGB triple.
#[inline]
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}
