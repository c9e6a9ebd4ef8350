//! Temporal stability on constructed sequences with known frame-to-frame change and error.

use nrc_eval::{ImageView, TemporalAccumulator, temporal_stats};

const W: usize = 6;
const H: usize = 4;
const T: usize = 5;

type Frames = Vec<Vec<[f32; 3]>>;

/// References brighten by 0.1 per frame (a moving light); `error(t)` is added to each frame.
fn sequence(error: impl Fn(usize) -> f32) -> (Frames, Frames) {
    let base: Vec<[f32; 3]> = (0..W * H)
        .map(|i| [1.0 + i as f32 * 0.01, 2.0, 0.5])
        .collect();
    let refs: Frames = (0..T)
        .map(|t| base.iter().map(|p| p.map(|v| v + 0.1 * t as f32)).collect())
        .collect();
    let frames = refs
        .iter()
        .enumerate()
        .map(|(t, r)| r.iter().map(|p| p.map(|v| v + error(t))).collect())
        .collect();
    (frames, refs)
}

fn views(images: &[Vec<[f32; 3]>]) -> Vec<ImageView<'_>> {
    images
        .iter()
        .map(|p| ImageView::new("frame", W, H, p).unwrap())
        .collect()
}

fn near(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-5
}

#[test]
fn steady_bias_costs_accuracy_but_not_stability() {
    let (frames, refs) = sequence(|_| 0.2);
    let s = temporal_stats(&views(&frames), Some(&views(&refs))).unwrap();
    assert_eq!(s.frames, T);
    assert!(near(s.mean_abs_change, 0.1), "{s:?}");
    assert!(near(s.mean_abs_error.unwrap(), 0.2));
    assert!(near(s.mean_abs_error_change.unwrap(), 0.0));
    assert!(near(s.reference_mean_abs_change.unwrap(), 0.1));
    assert_eq!(s.per_frame_change.len(), T - 1);
    assert_eq!(s.per_frame_error.len(), T);
}

#[test]
fn flicker_shows_in_error_change() {
    // Error alternates ±0.2: |E| = 0.2, |E′| = 0.4; the raw change alternates |0.1 ∓ 0.4|.
    let (frames, refs) = sequence(|t| if t % 2 == 0 { 0.2 } else { -0.2 });
    let s = temporal_stats(&views(&frames), Some(&views(&refs))).unwrap();
    assert!(near(s.mean_abs_error.unwrap(), 0.2));
    assert!(near(s.mean_abs_error_change.unwrap(), 0.4), "{s:?}");
    assert!(near(s.mean_abs_change, 0.4));
    for (i, c) in s.per_frame_change.iter().enumerate() {
        assert!(
            near(*c, if i % 2 == 0 { 0.3 } else { 0.5 }),
            "frame {}: {c}",
            i + 1
        );
    }
}

#[test]
fn without_references_only_change_is_reported() {
    let (frames, _) = sequence(|_| 0.0);
    let s = temporal_stats(&views(&frames), None).unwrap();
    assert!(near(s.mean_abs_change, 0.1));
    assert_eq!((s.mean_abs_error, s.mean_abs_error_change), (None, None));
    let one = temporal_stats(&views(&frames[..1]), None).unwrap();
    assert_eq!(one.mean_abs_change, 0.0);
}

#[test]
fn inconsistent_sequences_are_errors() {
    let (frames, refs) = sequence(|_| 0.0);
    let (f, r) = (views(&frames), views(&refs));
    assert!(
        temporal_stats(&f, Some(&r[..2]))
            .unwrap_err()
            .to_string()
            .contains("references")
    );
    let mut acc = TemporalAccumulator::new();
    acc.push(&f[0], Some(&r[0])).unwrap();
    assert!(
        acc.push(&f[1], None)
            .unwrap_err()
            .to_string()
            .contains("reference")
    );
    let small = vec![[0.0f32; 3]; 4];
    assert!(
        acc.push(
            &ImageView::new("small", 2, 2, &small).unwrap(),
            Some(&ImageView::new("small ref", 2, 2, &small).unwrap())
        )
        .is_err()
    );
    assert!(TemporalAccumulator::new().finish().is_err());
}

/// The paper's measure on tracked pixels: a sequence whose frames equal its references but for
/// one tracked pixel that is wrong by a known tone-mapped step every other frame gives the known
/// |E| and |E′|; frames equal to a static reference give |E′| = 0 exactly.
#[test]
fn tracked_luminance_gives_the_known_error_and_change() {
    use nrc_eval::TrackedLuminance;
    let (_, refs) = sequence(|_| 0.0);
    let views_r = views(&refs);
    let tracker = TrackedLuminance::from_reference(&views_r[0], 4);
    assert_eq!(tracker.pixels.len(), 4);
    // A static, exact sequence: no error, no change of it.
    let mut acc = TemporalAccumulator::new();
    for _ in 0..T {
        let a = tracker.apply(&views_r[0]);
        let r = tracker.apply(&views_r[0]);
        acc.push(
            &ImageView::new("f", a.len(), 1, &a).unwrap(),
            Some(&ImageView::new("r", r.len(), 1, &r).unwrap()),
        )
        .unwrap();
    }
    let s = acc.finish().unwrap();
    assert_eq!(s.mean_abs_error_change, Some(0.0));
    assert_eq!(s.mean_abs_error, Some(0.0));
    // The first tracked pixel's tone-mapped luminance off by +d on odd frames: |E| = d/4 · (2/5)
    // (two of five frames, one of four pixels), |E′| = d/4 (every pair differs by d at one pixel).
    let mut acc = TemporalAccumulator::new();
    let mut step = 0.0f64;
    for (t, r) in views_r.iter().enumerate() {
        let rt = tracker.apply(r);
        let mut ft = rt.clone();
        if t % 2 == 1 {
            ft[0] = [ft[0][0] + 0.05; 3];
            step = (ft[0][0] - rt[0][0]) as f64;
        }
        acc.push(
            &ImageView::new("f", ft.len(), 1, &ft).unwrap(),
            Some(&ImageView::new("r", rt.len(), 1, &rt).unwrap()),
        )
        .unwrap();
    }
    let s = acc.finish().unwrap();
    assert!(
        near(s.mean_abs_error.unwrap(), step / 4.0 * 2.0 / 5.0),
        "{s:?}"
    );
    assert!(near(s.mean_abs_error_change.unwrap(), step / 4.0), "{s:?}");
}
