//! Deterministic per-pixel random numbers.
//!
//! A counter-based generator: every number is a hash of `(seed, pixel, sample, dimension)`,
//! so a pixel's samples do not depend on which thread renders it, in which order, or how the
//! image is cut into tiles. Renders are therefore identical for a seed whatever the thread
//! count. The hash is the SplitMix64 finaliser (Stafford's "mix13"), which passes BigCrush
//! when fed a Weyl sequence, the way it is fed here (key + dimension · golden ratio).

use glam::Vec2;

/// 2⁶⁴ / φ, the Weyl increment of SplitMix64.
const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// Salt of [`PixelSampler::split`]'s keys.
const SPLIT: u64 = 0x5851_F42D_4C95_7F2D;
/// The largest f32 below 1.
const BELOW_ONE: f32 = 1.0 - f32::EPSILON / 2.0;
/// Points a stratified set ([`stratified`], [`stratified_1d`]) holds at most.
pub const MAX_STRATA: u32 = 256;

/// SplitMix64 finaliser: a bijective 64-bit mix with full avalanche.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Random numbers for one sample of one pixel: a stream of uniform numbers in `[0, 1)`
/// indexed by dimension. Copying a sampler copies its position in the stream.
#[derive(Clone, Copy, Debug)]
pub struct PixelSampler {
    key: u64,
    dimension: u64,
}

impl PixelSampler {
    /// The stream of sample `sample` of pixel `pixel` (any unique pixel index, e.g.
    /// `y · width + x`) for render seed `seed`.
    #[inline]
    pub fn new(seed: u64, pixel: u64, sample: u64) -> Self {
        let key =
            mix64(mix64(seed.wrapping_add(GOLDEN)) ^ pixel.wrapping_mul(0xD1B5_4A32_D192_ED03))
                ^ mix64(sample.wrapping_mul(0xA24B_AED4_963E_E407).wrapping_add(1));
        Self {
            key: mix64(key),
            dimension: 0,
        }
    }

    /// The next uniform number in `[0, 1)` (24 random bits, so never 1.0 in f32).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        self.dimension += 1;
        let h = mix64(self.key.wrapping_add(self.dimension.wrapping_mul(GOLDEN)));
        (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// The next two uniform numbers in `[0, 1)²`.
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let u = self.next_1d();
        Vec2::new(u, self.next_1d())
    }

    /// How many dimensions this stream has handed out.
    pub fn dimension(&self) -> u64 {
        self.dimension
    }

    /// A new stream, independent of this one's numbers, keyed by this stream's position (which
    /// advances by one number): for a set of draws whose count or structure is its own (the
    /// stratified sets below), so that this stream's later numbers stay where they were.
    #[inline]
    pub fn split(&mut self) -> PixelSampler {
        self.dimension += 1;
        let h = mix64(self.key.wrapping_add(self.dimension.wrapping_mul(GOLDEN)));
        Self {
            key: mix64(h ^ SPLIT),
            dimension: 0,
        }
    }
}

/// `n` (at most [`MAX_STRATA`]) points of the unit square: one in each of `n`
/// distinct cells of a `g × g` grid, `g = ⌈√n⌉`, the cells a uniformly random subset (the
/// whole grid when `n = g²`), each point uniform in its cell; no two share a cell. Where
/// `n < g²` every point is uniform over the square; where `n = g²` the `k`-th point lies in cell
/// `k`, and the set (a point at a random index) is uniform. `s` gives the numbers.
pub fn stratified(n: u32, s: PixelSampler) -> impl Iterator<Item = Vec2> {
    stratified_cells(n, s, true)
}

/// [`stratified`], with the cells drawn at random (`shuffle`) or the first `n` in row order
/// (the tests' negative control: not uniform where `n < g²`).
fn stratified_cells(n: u32, mut s: PixelSampler, shuffle: bool) -> impl Iterator<Item = Vec2> {
    let n = n.min(MAX_STRATA) as usize;
    let g = (n as f64).sqrt().ceil() as usize;
    let cells = g * g;
    // A partial Fisher–Yates shuffle picks the n cells.
    let mut order = [0u16; MAX_STRATA as usize];
    for (i, c) in order.iter_mut().enumerate().take(cells) {
        *c = i as u16;
    }
    if shuffle && n < cells {
        for i in 0..n {
            let j = i + ((s.next_1d() * (cells - i) as f32) as usize).min(cells - i - 1);
            order.swap(i, j);
        }
    }
    let inv = 1.0 / g as f32;
    (0..n).map(move |k| {
        let c = order[k] as usize;
        // A point jittered into the last row or column may round up to 1.0: keep it below.
        ((Vec2::new((c % g) as f32, (c / g) as f32) + s.next_2d()) * inv)
            .min(Vec2::splat(BELOW_ONE))
    })
}

/// `n` (at most [`MAX_STRATA`]) numbers of `[0, 1)`: one in each of the `n` equal strata, in
/// a uniformly random order, each uniform in its stratum. Every number is uniform over
/// `[0, 1)`, and no two share a stratum. `s` gives the numbers.
pub fn stratified_1d(n: u32, s: PixelSampler) -> impl Iterator<Item = f32> {
    strata_1d(n, s, true)
}

/// [`stratified_1d`], in random order (`shuffle`) or in the strata's order (the tests'
/// negative control: the `k`-th number is not uniform).
fn strata_1d(n: u32, mut s: PixelSampler, shuffle: bool) -> impl Iterator<Item = f32> {
    let n = n.min(MAX_STRATA) as usize;
    let mut order = [0u16; MAX_STRATA as usize];
    for (i, c) in order.iter_mut().enumerate().take(n) {
        *c = i as u16;
    }
    if shuffle {
        for i in 0..n.saturating_sub(1) {
            let j = i + ((s.next_1d() * (n - i) as f32) as usize).min(n - i - 1);
            order.swap(i, j);
        }
    }
    // In f64, so that a value near a stratum's top does not round onto the next stratum; the
    // last stratum's may still round up to 1.0 in f32: keep it below.
    (0..n).map(move |k| (((order[k] as f64 + s.next_1d() as f64) / n as f64) as f32).min(BELOW_ONE))
}

/// `n` (at most [`MAX_STRATA`]) triples of numbers for `n` samples drawn together, each a
/// number of `[0, 1)` and a point of the unit square: the numbers [`stratified_1d`], the points
/// [`stratified`], each set from its own stream split off `s` (which advances by two numbers),
/// and the numbers in random order, so the `k`-th number is independent of the `k`-th point and
/// a triple at a random index is uniform over the unit cube: a sum of one function over the
/// triples estimates `n` times its mean.
pub fn stratified_pairs(n: u32, s: &mut PixelSampler) -> impl Iterator<Item = (f32, Vec2)> {
    let points = stratified(n, s.split());
    stratified_1d(n, s.split()).zip(points)
}

/// Where a frame's camera rays lie in their pixels' low-discrepancy sequences: the frames of
/// one run share `seed`, so that each pixel's camera offsets over the run are consecutive
/// points of one Owen-scrambled Sobol sequence ([`owen_sobol_2d`]) and stratify the pixel's
/// footprint together, as a real-time renderer's jitter sequence or a progressive renderer's
/// low-discrepancy sampler does. Every offset is still uniform over the pixel (the scramble is
/// random per run and pixel), so each frame stays an unbiased estimate; only the frames'
/// errors are no longer independent: their mean's is lower where the image varies within a
/// pixel (edges, textures, a glossy reflection of a window's bars).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelSequence {
    /// Seed of the pixels' scrambles: the same for all frames that stratify together.
    pub seed: u64,
    /// Index in the sequence of this frame's first sample (the run's samples per pixel
    /// before it).
    pub first: u32,
}

impl PixelSequence {
    /// The same frame's place in the sequence of a split's extra camera ray `k`
    /// ([`Stream::SplitSequence`]): scrambled independently of this one, so that a pixel
    /// sample's extra rays stratify over a run's frames among themselves.
    pub fn for_split_ray(self, k: u32) -> Self {
        Self {
            seed: Stream::SplitSequence(k).seed(self.seed),
            ..self
        }
    }

    /// The camera offset in its pixel of sample `s` of pixel `pixel` (any unique index).
    pub fn offset(&self, pixel: u64, s: u32) -> Vec2 {
        let scramble = mix64(mix64(self.seed ^ SOBOL) ^ pixel.wrapping_mul(0xD1B5_4A32_D192_ED03));
        owen_sobol_2d(self.first.wrapping_add(s), scramble)
    }
}

/// A camera ray's offset in its pixel: `sequence`'s point for sample `s` of `pixel`, or
/// `independent` (the pass's own random numbers, already drawn so that its later numbers stay
/// where they were) without a sequence.
pub fn camera_offset(
    sequence: Option<PixelSequence>,
    pixel: u64,
    s: u32,
    independent: Vec2,
) -> Vec2 {
    match sequence {
        Some(q) => q.offset(pixel, s),
        None => independent,
    }
}

/// Point `index` of the first two dimensions of Sobol's sequence, Owen-scrambled by
/// `scramble` (Burley 2020, "Practical Hash-based Owen Scrambling": a hash on the reversed
/// bits stands for the nested uniform permutation). Each point is uniform over the unit square
/// whatever the index, and points `0..2^m` of one scramble form a `(0, m, 2)`-net: one point
/// in each elementary interval of area `2^-m` (`m`-strata in x, y, and every split between).
/// So a pixel's camera offsets drawn with one scramble at consecutive indices (its frames)
/// stratify its footprint over the frames, where independent offsets do not.
pub fn owen_sobol_2d(index: u32, scramble: u64) -> Vec2 {
    // Dimension 0: the van der Corput sequence (bit reversal); dimension 1: the direction
    // numbers of the polynomial x + 1 (v_1 = 2^31, v_k = v_(k-1) ^ (v_(k-1) >> 1)).
    let (mut y, mut v) = (0u32, 1u32 << 31);
    let mut i = index;
    while i != 0 {
        if i & 1 == 1 {
            y ^= v;
        }
        i >>= 1;
        v ^= v >> 1;
    }
    let seeds = mix64(scramble ^ SOBOL);
    let to_unit = |x: u32| ((x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)).min(BELOW_ONE);
    Vec2::new(
        to_unit(owen_scramble(index.reverse_bits(), seeds as u32)),
        to_unit(owen_scramble(y, (seeds >> 32) as u32)),
    )
}

/// Salt of [`owen_sobol_2d`]'s scramble seeds.
const SOBOL: u64 = 0x2545_F491_4F6C_DD1D;

/// A nested uniform scramble of `x`'s bits (most significant first): each bit is flipped by a
/// hash of `seed` and the bits above it (Laine and Karras 2011's permutation on the reversed
/// bits, with Burley's constants), so intervals `[k 2^-m, (k+1) 2^-m)` map onto each other.
fn owen_scramble(x: u32, seed: u32) -> u32 {
    let mut x = x.reverse_bits();
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x.reverse_bits()
}

/// The seed of pass (or frame) `pass` of a run seeded `seed`: a bijective mix (SplitMix64's
/// finaliser) of both, so passes of a frame, and frames of nearby seeds, get unrelated random
/// streams.
pub fn pass_seed(seed: u64, pass: u32) -> u64 {
    mix64(seed ^ (pass as u64 + 1).wrapping_mul(GOLDEN))
}

/// Named seeds derived from a frame's or a run's seed. Every seed that is not the frame's own
/// comes from one of these (never from a raw XOR salt), so that two uses cannot share random
/// numbers by accident and each draw says what it is for. Per-pixel streams within a frame
/// are the resampling passes' [`crate::passes::screen::Phase`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stream {
    /// A DDGI volume's probe rays of a frame.
    ProbeRays,
    /// Instant radiosity's light paths, candidates and camera-visible points of a frame.
    Vpls,
    /// Training rays re-entering along the previous frame's terminations.
    TerminationRays,
    /// The inference render inside an online training frame.
    TrainingRender,
    /// Producer `k` of a mixture, within a training frame.
    Producer(u32),
    /// Frame `k` of an animated sequence.
    SequenceFrame(u32),
    /// Step `k` of `nrc compare --sweep`.
    SweepStep(u32),
    /// The fresh state of a `nrc compare --converge` run.
    ConvergeRestart,
    /// Frame `k` of a `nrc compare --converge` run.
    ConvergeFrame(u32),
    /// Instant radiosity's warm-up iteration `k` before its first frame.
    VplWarmup(u32),
    /// Extra camera ray `k` of a frame's split (`split=N` of the ReSTIR GI passes): the
    /// pass's own per-pixel streams under it.
    SplitRay(u32),
    /// The camera offsets' sequence of a split's extra camera ray `k`
    /// ([`PixelSequence::for_split_ray`]), from the run's sequence seed.
    SplitSequence(u32),
}

impl Stream {
    /// The seed of this stream within `seed`.
    pub fn seed(self, seed: u64) -> u64 {
        let (id, k) = match self {
            Self::ProbeRays => (1, 0),
            Self::Vpls => (2, 0),
            Self::TerminationRays => (3, 0),
            Self::TrainingRender => (4, 0),
            Self::Producer(k) => (5, k),
            Self::SequenceFrame(k) => (6, k),
            Self::SweepStep(k) => (7, k),
            Self::ConvergeRestart => (8, 0),
            Self::ConvergeFrame(k) => (9, k),
            Self::VplWarmup(k) => (10, k),
            Self::SplitRay(k) => (11, k),
            Self::SplitSequence(k) => (12, k),
        };
        mix64(mix64(seed ^ (id as u64).wrapping_mul(0xD1B5_4A32_D192_ED03)) ^ k as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every named stream of a seed is its own: none repeats another, nor the seed itself (the
    /// first warm-up iteration of instant radiosity once drew the frame's own numbers).
    #[test]
    fn named_streams_differ_from_each_other_and_the_seed() {
        for seed in [0u64, 1, 12345, u64::MAX] {
            let mut all: Vec<u64> = vec![seed];
            all.extend(
                [
                    Stream::ProbeRays,
                    Stream::Vpls,
                    Stream::TerminationRays,
                    Stream::TrainingRender,
                    Stream::ConvergeRestart,
                ]
                .map(|s| s.seed(seed)),
            );
            for k in 0..4 {
                all.extend(
                    [
                        Stream::Producer(k),
                        Stream::SequenceFrame(k),
                        Stream::SweepStep(k),
                        Stream::ConvergeFrame(k),
                        Stream::VplWarmup(k),
                        Stream::SplitRay(k),
                        Stream::SplitSequence(k),
                    ]
                    .map(|s| s.seed(seed)),
                );
            }
            let n = all.len();
            all.sort_unstable();
            all.dedup();
            assert_eq!(all.len(), n, "seed {seed}: two streams coincide");
        }
    }

    /// Whether `points` (2^m of them) form a (0, m, 2)-net: one point in every elementary
    /// interval of area 2^-m (2^a × 2^(m−a) cells, every a).
    fn is_net(points: &[Vec2], m: u32) -> bool {
        (0..=m).all(|a| {
            let (nx, ny) = (1usize << a, 1usize << (m - a));
            let mut seen = vec![false; nx * ny];
            points.iter().all(|p| {
                let c = (p.y * ny as f32) as usize * nx + (p.x * nx as f32) as usize;
                !std::mem::replace(&mut seen[c], true)
            })
        })
    }

    /// A pixel's first 2^m offsets of one scramble form a net (stratified in x, y and every
    /// split between), for every m up to 8 and several scrambles; independent offsets (the
    /// control) do not.
    #[test]
    fn owen_sobol_points_of_one_scramble_form_nets() {
        for scramble in [0u64, 1, 0xDEAD_BEEF, u64::MAX] {
            for m in 0..=8 {
                let pts: Vec<Vec2> = (0..1u32 << m).map(|i| owen_sobol_2d(i, scramble)).collect();
                assert!(is_net(&pts, m), "scramble {scramble}, m {m}");
                // Any aligned block of 2^m consecutive indices is a net too (a run's later
                // frames keep stratifying).
                let later: Vec<Vec2> = (0..1u32 << m)
                    .map(|i| owen_sobol_2d((5 << m) + i, scramble))
                    .collect();
                assert!(is_net(&later, m), "scramble {scramble}, m {m}, block 5");
            }
        }
        let mut s = PixelSampler::new(3, 4, 5);
        let random: Vec<Vec2> = (0..16).map(|_| s.next_2d()).collect();
        assert!(!is_net(&random, 4), "independent points are not a net");
    }

    /// χ² on an 8 × 8 grid of one index's point over 8,192 scrambles (63 degrees of freedom).
    fn chi2_over_scrambles(index: u32, scramble: impl Fn(u64) -> u64) -> f64 {
        const N: usize = 8192;
        let mut cells = [0u32; 64];
        for k in 0..N as u64 {
            let p = owen_sobol_2d(index, scramble(k));
            cells[(p.y * 8.0) as usize * 8 + (p.x * 8.0) as usize] += 1;
        }
        let e = N as f64 / 64.0;
        cells.iter().map(|&c| (c as f64 - e).powi(2) / e).sum()
    }

    /// Each offset is uniform over the pixel whatever its index (so a frame at any point of
    /// the sequence is unbiased): χ² over scrambles below the 10⁻⁴ critical value of 63
    /// degrees of freedom (113.6, Bonferroni over the 5 indices: 10⁻³ overall). The control,
    /// scrambles drawn from only 16 seeds (a scramble too narrow to randomise), fails.
    #[test]
    fn owen_sobol_points_are_uniform_over_scrambles() {
        const CRITICAL: f64 = 113.6;
        for index in [0u32, 1, 7, 100, 65_537] {
            let chi2 = chi2_over_scrambles(index, |k| mix64(k ^ 0x1234));
            assert!(chi2 < CRITICAL, "index {index}: χ² {chi2:.1}");
        }
        let narrow = chi2_over_scrambles(7, |k| k % 16);
        assert!(
            narrow > CRITICAL,
            "the narrow scramble's χ² {narrow:.1} should fail"
        );
    }

    /// A pixel sequence's offsets are its scrambled Sobol points at `first + s`, a new scramble
    /// per pixel and per seed, and `camera_offset` without one passes the independent offset
    /// through.
    #[test]
    fn pixel_sequences_index_and_scramble_by_pixel_and_seed() {
        let q = PixelSequence { seed: 9, first: 12 };
        let later = PixelSequence { seed: 9, first: 14 };
        assert_eq!(q.offset(3, 2), later.offset(3, 0));
        assert_ne!(q.offset(3, 0), q.offset(4, 0));
        assert_ne!(
            q.offset(3, 0),
            PixelSequence {
                seed: 10,
                first: 12
            }
            .offset(3, 0)
        );
        let own = Vec2::new(0.25, 0.75);
        assert_eq!(camera_offset(None, 3, 0, own), own);
        assert_eq!(camera_offset(Some(q), 3, 0, own), q.offset(3, 0));
    }

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let mut a = PixelSampler::new(7, 10, 3);
        let mut b = PixelSampler::new(7, 10, 3);
        let mut c = PixelSampler::new(7, 10, 4);
        let mut d = PixelSampler::new(8, 10, 3);
        let xs: Vec<f32> = (0..8).map(|_| a.next_1d()).collect();
        let ys: Vec<f32> = (0..8).map(|_| b.next_1d()).collect();
        let zs: Vec<f32> = (0..8).map(|_| c.next_1d()).collect();
        let ws: Vec<f32> = (0..8).map(|_| d.next_1d()).collect();
        assert_eq!(xs, ys);
        assert_ne!(xs, zs);
        assert_ne!(xs, ws);
    }

    /// χ² test of uniformity over 64 bins of the first dimensions of many (pixel, sample)
    /// streams, and of the joint distribution of consecutive dimensions over 16×16 bins.
    /// The 99.99% quantile of χ²(63) is 115.6 and of χ²(255) is 346.
    #[test]
    fn uniform_chi_square() {
        const N: usize = 256_000;
        let mut bins1 = [0u32; 64];
        let mut bins2 = [0u32; 256];
        for i in 0..N as u64 {
            let mut s = PixelSampler::new(42, i % 4096, i / 4096);
            let u = s.next_1d();
            let v = s.next_2d();
            assert!((0.0..1.0).contains(&u));
            bins1[(u * 64.0) as usize] += 1;
            bins2[(v.x * 16.0) as usize * 16 + (v.y * 16.0) as usize] += 1;
        }
        let chi2 = |bins: &[u32]| {
            let e = N as f64 / bins.len() as f64;
            bins.iter()
                .map(|&o| (o as f64 - e).powi(2) / e)
                .sum::<f64>()
        };
        let c1 = chi2(&bins1);
        let c2 = chi2(&bins2);
        assert!(c1 < 115.6, "1-D chi2 {c1}");
        assert!(c2 < 346.0, "2-D chi2 {c2}");
    }

    fn points(n: u32, seed: u64, shuffle: bool) -> Vec<Vec2> {
        stratified_cells(n, PixelSampler::new(seed, 7, 3), shuffle).collect()
    }

    #[test]
    fn every_point_has_its_own_cell() {
        for n in [1, 2, 3, 5, 8, 9, 16, 17, 100, MAX_STRATA] {
            let g = (n as f64).sqrt().ceil() as usize;
            for seed in 0..20 {
                let p = points(n, seed, true);
                assert_eq!(p.len(), n as usize);
                let mut used = vec![false; g * g];
                for q in &p {
                    assert!(q.x >= 0.0 && q.x < 1.0 && q.y >= 0.0 && q.y < 1.0, "{q}");
                    let c = (q.y * g as f32) as usize * g + (q.x * g as f32) as usize;
                    assert!(!used[c], "n {n}: cell {c} twice");
                    used[c] = true;
                }
            }
        }
    }

    /// χ² of where the `k`-th of `n` points falls, over a 6 × 6 histogram of `draws` draws.
    fn chi2(n: u32, k: usize, shuffle: bool, draws: u64) -> f64 {
        let mut bins = [0u64; 36];
        for seed in 0..draws {
            let q = points(n, seed, shuffle)[k];
            bins[(q.y * 6.0) as usize * 6 + (q.x * 6.0) as usize] += 1;
        }
        let e = draws as f64 / 36.0;
        bins.iter().map(|&b| (b as f64 - e).powi(2) / e).sum()
    }

    #[test]
    fn each_point_is_uniform_over_the_pixel_and_the_unshuffled_cells_are_not() {
        // 35 degrees of freedom: P(χ² > 80) ≈ 2e-5.
        let bound = 80.0;
        for (n, k) in [(8, 0), (8, 7), (5, 4), (12, 3)] {
            let x = chi2(n, k, true, 36_000);
            assert!(x < bound, "n {n}, point {k}: χ² {x:.1}");
        }
        // Negative control: the first 8 of 9 cells in row order never reach the last one.
        let x = chi2(8, 7, false, 36_000);
        assert!(x > bound, "the unshuffled cells passed: χ² {x:.1}");
    }

    #[test]
    fn an_edge_through_the_pixel_costs_far_less_variance_than_independent_rays() {
        // The half-plane x + 0.3 y < 0.6 covers 0.6 − 0.15 = 0.45 of the unit square.
        let inside = |q: Vec2| q.x + 0.3 * q.y < 0.6;
        let (n, runs, c) = (16u32, 4_000u64, 0.45f64);
        let estimate = |q: &[Vec2]| q.iter().filter(|&&q| inside(q)).count() as f64 / n as f64;
        let stats = |est: Vec<f64>| {
            let m = est.iter().sum::<f64>() / est.len() as f64;
            let v = est.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (est.len() - 1) as f64;
            (m, v)
        };
        let (m, v) = stats(
            (0..runs)
                .map(|seed| estimate(&points(n, seed, true)))
                .collect(),
        );
        let independent = c * (1.0 - c) / n as f64;
        assert!(
            (m - c).abs() < 4.0 * (v / runs as f64).sqrt() + 1e-9,
            "mean {m} against {c}"
        );
        assert!(
            v < 0.25 * independent,
            "variance {v:.2e} against {independent:.2e}"
        );
        // The control: the same count of independent rays has the binomial variance.
        let (_, vi) = stats(
            (0..runs)
                .map(|seed| {
                    let mut s = PixelSampler::new(seed, 7, 3);
                    estimate(&(0..n).map(|_| s.next_2d()).collect::<Vec<_>>())
                })
                .collect(),
        );
        assert!(vi > 0.25 * independent, "independent rays: {vi:.2e}");
    }

    fn numbers(n: u32, seed: u64, shuffle: bool) -> Vec<f32> {
        strata_1d(n, PixelSampler::new(seed, 5, 9), shuffle).collect()
    }

    #[test]
    fn every_number_has_its_own_stratum_and_each_is_uniform() {
        for n in [1, 2, 3, 5, 16, 17, MAX_STRATA] {
            for seed in 0..20 {
                let x = numbers(n, seed, true);
                assert_eq!(x.len(), n as usize);
                let mut used = vec![false; n as usize];
                for &v in &x {
                    assert!((0.0..1.0).contains(&v), "{v}");
                    let c = (v * n as f32) as usize;
                    assert!(!used[c], "n {n}: stratum {c} twice");
                    used[c] = true;
                }
            }
        }
        assert_eq!(numbers(0, 1, true).len(), 0);
        // χ² of where the k-th of n numbers falls, 20 bins: 19 degrees of freedom,
        // P(χ² > 55) ≈ 2e-5.
        let chi2 = |n: u32, k: usize, shuffle: bool| {
            let draws = 20_000u64;
            let mut bins = [0u64; 20];
            for seed in 0..draws {
                bins[(numbers(n, seed, shuffle)[k] * 20.0) as usize] += 1;
            }
            let e = draws as f64 / 20.0;
            bins.iter()
                .map(|&b| (b as f64 - e).powi(2) / e)
                .sum::<f64>()
        };
        for (n, k) in [(4, 0), (4, 3), (5, 2), (16, 15)] {
            let x = chi2(n, k, true);
            assert!(x < 55.0, "n {n}, number {k}: χ² {x:.1}");
        }
        // Negative control: in the strata's order the first of four numbers is below 1/4.
        let x = chi2(4, 0, false);
        assert!(x > 55.0, "the unshuffled strata passed: χ² {x:.1}");
    }

    /// A split stream's numbers are not its parent's: over many streams, the split's first
    /// number is uncorrelated with the parent's next ones, and the parent's later numbers are
    /// where they would be after one draw.
    #[test]
    fn a_split_stream_is_independent_of_its_parent() {
        let n = 20_000u64;
        let (mut sxy, mut sx, mut sy, mut sxx, mut syy) = (0f64, 0f64, 0f64, 0f64, 0f64);
        let mut same_as_parent = 0;
        for seed in 0..n {
            let mut parent = PixelSampler::new(seed, 3, 4);
            let mut copy = parent;
            let mut child = parent.split();
            copy.next_1d();
            let (x, y) = (child.next_1d() as f64, parent.next_1d() as f64);
            assert_eq!(parent.next_1d(), {
                copy.next_1d();
                copy.next_1d()
            });
            same_as_parent += (x == y) as u32;
            sxy += x * y;
            sx += x;
            sy += y;
            sxx += x * x;
            syy += y * y;
        }
        let nf = n as f64;
        let cov = sxy / nf - sx * sy / nf / nf;
        let r = cov / ((sxx / nf - (sx / nf).powi(2)) * (syy / nf - (sy / nf).powi(2))).sqrt();
        // |r| of independent numbers: about 1/√n = 0.007; 5 of those.
        assert!(r.abs() < 5.0 / nf.sqrt(), "correlation {r:.4}");
        assert!(same_as_parent < 5, "{same_as_parent} equal numbers");
        // No number of a split stream is one of its parent's (the first 64 of each, from a
        // parent 10 numbers in); the control, a "split" that copies the parent, shares them all.
        let shared = |split: fn(&mut PixelSampler) -> PixelSampler| {
            (0..200u64)
                .map(|seed| {
                    let mut parent = PixelSampler::new(seed, 1, 2);
                    let mut before = parent;
                    for _ in 0..10 {
                        parent.next_1d();
                    }
                    let mut child = split(&mut parent);
                    let parents: Vec<f32> = (0..80).map(|_| before.next_1d()).collect();
                    (0..64)
                        .filter(|_| parents.contains(&child.next_1d()))
                        .count()
                })
                .sum::<usize>()
        };
        // 24-bit numbers: 64 × 80 × 200 pairs meet by chance about 0.06 times.
        let own = shared(PixelSampler::split);
        assert!(
            own <= 2,
            "{own} numbers of split streams are their parents'"
        );
        let copied = shared(|p| {
            let c = *p;
            p.dimension += 1;
            c
        });
        assert!(copied > 1000, "the copying control shares only {copied}");
    }

    /// A triple of [`stratified_pairs`] at a random index is uniform over the unit cube (its
    /// number's quarter against its point's quadrant, 16 bins), for a full grid of cells (n = 4,
    /// where the k-th point lies in cell k) and a partial one (n = 5): the numbers' random order
    /// keeps a lobe choice independent of its direction. The control, both sets in order, pairs
    /// the k-th stratum with the k-th cell.
    #[test]
    fn stratified_pairs_are_jointly_uniform() {
        let bin = |(u, p): (f32, Vec2)| {
            (u * 4.0) as usize * 4 + (p.y * 2.0) as usize * 2 + (p.x * 2.0) as usize
        };
        let chi2 = |n: u32, ordered: bool| {
            let draws = 16_000u64;
            let mut bins = [0u64; 16];
            for seed in 0..draws {
                let mut s = PixelSampler::new(seed, 2, 5);
                let k = (seed % n as u64) as usize;
                let t = if ordered {
                    let points: Vec<Vec2> = stratified_cells(n, s.split(), false).collect();
                    strata_1d(n, s.split(), false).zip(points).nth(k)
                } else {
                    stratified_pairs(n, &mut s).nth(k)
                };
                bins[bin(t.unwrap())] += 1;
            }
            let e = draws as f64 / 16.0;
            bins.iter()
                .map(|&b| (b as f64 - e).powi(2) / e)
                .sum::<f64>()
        };
        // 15 degrees of freedom: P(χ² > 45) ≈ 7e-5.
        for n in [4, 5] {
            let x = chi2(n, false);
            assert!(x < 45.0, "n {n}: χ² {x:.1}");
        }
        let x = chi2(4, true);
        assert!(x > 45.0, "the ordered sets passed: χ² {x:.1}");
    }
}
