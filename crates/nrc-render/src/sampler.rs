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
}
