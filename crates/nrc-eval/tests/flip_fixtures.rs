//! HDR-FLIP and LDR-FLIP against NVIDIA's published tool (PyPI `flip-evaluator`) on the
//! fixtures made by scripts/flip_fixtures.py: the mean must agree within 1e-3, the exposure
//! range within 1e-4 stops, and every pixel of the error map within 1e-3.

mod common;

use common::{flip_fixture_dir, read_pfm};
use nrc_eval::flip::ldr_flip;
use nrc_eval::{HdrFlipParams, ImageView, ToneMapper, hdr_flip};
use serde_json::Value;

const MEAN_TOLERANCE: f64 = 1e-3;
const EXPOSURE_TOLERANCE: f64 = 1e-4;
const PIXEL_TOLERANCE: f32 = 1e-3;

#[test]
fn flip_matches_published_tool_on_fixtures() {
    let dir = flip_fixture_dir();
    let expected: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("expected.json")).unwrap()).unwrap();
    let cases = expected["cases"].as_array().unwrap();
    assert!(cases.len() >= 8, "fixture set is incomplete");
    let mut failures = Vec::new();
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let reference = read_pfm(&dir.join(case["reference"].as_str().unwrap()));
        let test = read_pfm(&dir.join(case["test"].as_str().unwrap()));
        let tool_map = read_pfm(&dir.join(case["error_map"].as_str().unwrap()));
        let (w, h) = (reference.width, reference.height);
        assert_eq!(
            (w, h),
            (
                case["width"].as_u64().unwrap() as usize,
                case["height"].as_u64().unwrap() as usize
            )
        );
        let (ref_px, test_px) = (reference.rgb(), test.rgb());
        let r = ImageView::new("reference", w, h, &ref_px).unwrap();
        let t = ImageView::new("test", w, h, &test_px).unwrap();
        let ppd = case["ppd"].as_f64().unwrap() as f32;
        let tool_mean = case["mean_flip"].as_f64().unwrap();

        let map = match case["mode"].as_str().unwrap() {
            "HDR" => {
                let given = &case["given"];
                let params = HdrFlipParams {
                    ppd,
                    tone_mapper: match case["tone_mapper"].as_str().unwrap() {
                        "aces" => ToneMapper::Aces,
                        "hable" => ToneMapper::Hable,
                        "reinhard" => ToneMapper::Reinhard,
                        other => panic!("unknown tone mapper {other}"),
                    },
                    start_exposure: given["startExposure"].as_f64().map(|v| v as f32),
                    stop_exposure: given["stopExposure"].as_f64().map(|v| v as f32),
                    num_exposures: given["numExposures"].as_u64().map(|v| v as usize),
                };
                let result = hdr_flip(&t, &r, &params).unwrap();
                let start = case["start_exposure"].as_f64().unwrap();
                let stop = case["stop_exposure"].as_f64().unwrap();
                if (result.start_exposure as f64 - start).abs() > EXPOSURE_TOLERANCE
                    || (result.stop_exposure as f64 - stop).abs() > EXPOSURE_TOLERANCE
                    || result.num_exposures as u64 != case["num_exposures"].as_u64().unwrap()
                {
                    failures.push(format!(
                        "{name}: exposures ours {}..{} ({}), tool {start}..{stop} ({})",
                        result.start_exposure,
                        result.stop_exposure,
                        result.num_exposures,
                        case["num_exposures"]
                    ));
                }
                result.error_map
            }
            "LDR" => ldr_flip(&t, &r, ppd).unwrap(),
            other => panic!("unknown mode {other}"),
        };
        let ours = map.mean();
        let max_pixel_diff = map
            .values
            .iter()
            .zip(&tool_map.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        println!(
            "{name:>20}: tool {tool_mean:.6}, ours {ours:.6}, |Δmean| {:.2e}, max |Δpixel| {max_pixel_diff:.2e}",
            (ours - tool_mean).abs()
        );
        if (ours - tool_mean).abs() > MEAN_TOLERANCE {
            failures.push(format!("{name}: mean FLIP ours {ours}, tool {tool_mean}"));
        }
        if max_pixel_diff > PIXEL_TOLERANCE {
            failures.push(format!("{name}: a pixel differs by {max_pixel_diff}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
