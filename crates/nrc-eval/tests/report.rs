//! Reports, plots and false-colour images are written (atomically), parseable and readable.

use std::path::Path;

use nrc_eval::metrics::{ErrorMetrics, Metric};
use nrc_eval::plot::{PLOT_SIZE, plot_error_vs_time};
use nrc_eval::png_output::{ColorMap, Scale, write_false_color_png, write_srgb_png};
use nrc_eval::report::{PassCost, fmt_num, read_report_json};
use nrc_eval::sweep::time_to_error_table;
use nrc_eval::{
    BiasVariance, ErrorConcentration, EvalError, ImageView, Report, ReportRow, ScalarImage,
    SweepPoint, SweepSeries, TemporalStats, write_report,
};

fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn only_final_files(dir: &Path, expected: &[&str]) {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    let mut want: Vec<String> = expected.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(names, want, "temporary files left behind?");
}

fn sweeps() -> Vec<SweepSeries> {
    let series = |method: &str, c: f64| SweepSeries {
        method: method.to_string(),
        points: [1.0, 2.0, 4.0, 8.0]
            .iter()
            .map(|&spp| SweepPoint {
                time_ms: 3.0 * spp,
                samples_per_pixel: spp,
                metrics: ErrorMetrics {
                    mse: c / spp,
                    rel_mse: 0.1 * c / spp,
                    mape: 0.3 / spp.sqrt(),
                    flip: Some(0.2 / spp.sqrt()),
                },
            })
            .collect(),
    };
    vec![series("pt-nee", 0.5), series("pt-bsdf", 2.0)]
}

fn sample_report() -> Report {
    let mut report = Report::new("Cornell box, equal spp", 64, 48);
    report.scene = Some("cornell_box.glb".into());
    report.reference = Some("path tracer, 4096 spp".into());
    report.rows = vec![
        ReportRow {
            method: "pt-1spp".into(),
            time_per_frame_ms: 3.25,
            samples_per_pixel: 1.0,
            metrics: ErrorMetrics {
                mse: 0.5,
                rel_mse: 0.05,
                mape: 0.3,
                flip: Some(0.2),
            },
            bias_variance: Some(BiasVariance {
                renders: 32,
                bias_sq: -1e-5,
                bias_sq_raw: 0.0156,
                variance: 0.5,
            }),
            temporal: None,
            concentration: Some(ErrorConcentration {
                top_percent: 0.64,
                emitters: Some(0.5),
                p999: 12.5,
            }),
            cost: Some(PassCost {
                ms_per_pass: 3.25,
                rays_per_pixel: 4.0,
                // Below a twentieth of a millisecond: not shown.
                phases: vec![("source".into(), 0.01)],
            }),
        },
        ReportRow {
            method: "pt-16spp".into(),
            time_per_frame_ms: 51.0,
            samples_per_pixel: 16.0,
            metrics: ErrorMetrics {
                mse: 0.031,
                rel_mse: 0.0031,
                mape: 0.075,
                flip: Some(0.05),
            },
            bias_variance: None,
            concentration: None,
            // Not a path tracer's cost: the table's second row, in units of the first.
            cost: Some(PassCost {
                ms_per_pass: 6.5,
                rays_per_pixel: 9.3,
                phases: vec![("candidates".into(), 1.5), ("temporal".into(), 0.0)],
            }),
            temporal: Some(TemporalStats {
                frames: 3,
                mean_abs_change: 0.1,
                mean_abs_error: Some(0.2),
                mean_abs_error_change: Some(0.05),
                reference_mean_abs_change: Some(0.08),
                per_frame_change: vec![0.1, 0.1],
                per_frame_error: vec![0.2, 0.2, 0.2],
            }),
        },
    ];
    report.sweeps = sweeps();
    report.time_to_error =
        vec![time_to_error_table(&report.sweeps, Metric::Mse, "pt-bsdf", 24.0).unwrap()];
    report.notes.push("Equal-spp comparison.".into());
    report
}

#[test]
fn report_files_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let report = sample_report();
    let files = write_report(&out, &report).unwrap();
    only_final_files(&out, &["report.json", "report.md"]);
    assert_eq!(read_report_json(&files.json).unwrap(), report);

    let md = std::fs::read_to_string(&files.markdown).unwrap();
    assert!(md.starts_with("# Cornell box, equal spp"));
    assert!(
        md.contains(
            "| method | time/frame (ms) | spp | MSE | relMSE | MAPE | FLIP | bias² | variance |"
        ),
        "{md}"
    );
    // Best (smallest) MSE is pt-16spp's, in bold; bias² is present for pt-1spp only.
    assert!(
        md.contains("| pt-16spp | 51.00 | 16.00 | **0.03100** |"),
        "{md}"
    );
    assert!(md.contains("| pt-1spp | 3.250 | 1.000 | 0.5000 |"), "{md}");
    assert!(md.contains("## Temporal stability"));
    // The concentration table holds the rows that have one.
    assert!(md.contains("## Where the error is"), "{md}");
    assert!(
        md.contains("| pt-1spp | 0.5000 | 64 % | 50 % | 12.50 |"),
        "{md}"
    );
    assert!(!md.contains("| pt-16spp | 0.03100 | "), "{md}");
    // The cost table counts passes in samples of the first path tracer (3.25 ms each) and
    // names only the phases that took time.
    assert!(md.contains("## Where the time goes"), "{md}");
    assert!(md.contains("| pt-1spp | 3.250 | 1.00 | 4.0 | – |"), "{md}");
    assert!(
        md.contains("| pt-16spp | 6.500 | 2.00 | 9.3 | candidates 1.5; rest 5.0 |"),
        "{md}"
    );
    assert!(md.contains("one sample of `pt-1spp`, 3.250 ms"), "{md}");
    assert!(
        md.contains("## Time to reach the MSE of pt-bsdf at 24.00 ms"),
        "{md}"
    );
    assert!(md.contains("| pt-nee | 6.000 | 4.00× |"), "{md}");
    assert!(md.contains("## Sweep: error against time"));

    // Rewriting replaces the files in place.
    let mut changed = report.clone();
    changed.title = "second".into();
    write_report(&out, &changed).unwrap();
    assert_eq!(read_report_json(&files.json).unwrap().title, "second");
    only_final_files(&out, &["report.json", "report.md"]);
}

#[test]
fn malformed_report_json_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("report.json");
    std::fs::write(&path, "{\"title\": 3}").unwrap();
    let err = read_report_json(&path).unwrap_err();
    assert!(
        matches!(err, EvalError::Json { .. }) && err.to_string().contains("report.json"),
        "{err}"
    );
    let err = read_report_json(&dir.path().join("absent.json")).unwrap_err();
    assert!(matches!(err, EvalError::Io { .. }), "{err}");
}

#[test]
fn error_against_time_plot_is_written_as_png_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let (png_path, svg_path) = (dir.path().join("error.png"), dir.path().join("error.svg"));
    plot_error_vs_time(
        &sweeps(),
        Metric::RelMse,
        "relMSE against time",
        &png_path,
        &svg_path,
    )
    .unwrap();
    only_final_files(dir.path(), &["error.png", "error.svg"]);

    let (w, h, rgb) = decode_png(&png_path);
    assert_eq!((w, h), PLOT_SIZE);
    // The first method's line colour (Tableau blue) is drawn, and so is text (dark pixels).
    let blue = colorous::TABLEAU10[0];
    assert!(rgb.chunks(3).any(|p| p == [blue.r, blue.g, blue.b]));
    assert!(rgb.chunks(3).filter(|p| p.iter().all(|&c| c < 60)).count() > 500);

    let svg = std::fs::read_to_string(&svg_path).unwrap();
    assert!(svg.starts_with("<svg"));
    for text in ["pt-nee", "pt-bsdf", "relMSE", "time per frame (ms)"] {
        assert!(svg.contains(text), "SVG lacks {text}");
    }
    let err = plot_error_vs_time(&sweeps(), Metric::Flip, "x", &png_path, &svg_path);
    assert!(err.is_ok(), "FLIP is in the sweeps");
    let mut no_flip = sweeps();
    no_flip
        .iter_mut()
        .flat_map(|s| s.points.iter_mut())
        .for_each(|p| p.metrics.flip = None);
    assert!(matches!(
        plot_error_vs_time(&no_flip, Metric::Flip, "x", &png_path, &svg_path),
        Err(EvalError::NotEnoughData(_))
    ));
}

#[test]
fn false_colour_and_srgb_pngs() {
    let dir = tempfile::tempdir().unwrap();
    let map = ScalarImage {
        width: 4,
        height: 2,
        values: vec![0.0, 0.25, 0.5, 1.0, 2.0, 0.75, 0.1, 0.0],
    };
    let path = dir.path().join("flip.png");
    write_false_color_png(
        &path,
        &map,
        ColorMap::Magma,
        Scale::Linear { min: 0.0, max: 1.0 },
    )
    .unwrap();
    let (w, h, rgb) = decode_png(&path);
    assert_eq!((w, h), (4, 2));
    let magma = |t: f64| {
        let c = colorous::MAGMA.eval_continuous(t);
        vec![c.r, c.g, c.b]
    };
    assert_eq!(rgb[0..3].to_vec(), magma(0.0));
    assert_eq!(rgb[9..12].to_vec(), magma(1.0));
    assert_eq!(
        rgb[12..15].to_vec(),
        magma(1.0),
        "values above the range clamp"
    );

    let log_path = dir.path().join("relmse.png");
    let log_map = ScalarImage {
        width: 3,
        height: 1,
        values: vec![1e-4, 1e-2, 1.0],
    };
    write_false_color_png(
        &log_path,
        &log_map,
        ColorMap::Viridis,
        Scale::Log {
            min: 1e-4,
            max: 1.0,
        },
    )
    .unwrap();
    let (_, _, rgb) = decode_png(&log_path);
    let viridis = colorous::VIRIDIS.eval_continuous(0.5);
    assert_eq!(
        rgb[3..6].to_vec(),
        vec![viridis.r, viridis.g, viridis.b],
        "1e-2 sits mid-way on a 1e-4..1 log scale"
    );
    assert!(
        matches!(Scale::auto_log(&log_map), Scale::Log { min, max } if min == 1e-4 && max == 1.0)
    );
    assert!(
        write_false_color_png(
            &log_path,
            &log_map,
            ColorMap::Viridis,
            Scale::Log { min: 0.0, max: 1.0 }
        )
        .is_err()
    );

    let img = vec![[0.0f32, 0.5, 1.0], [4.0, f32::NAN, 0.2]];
    let srgb_path = dir.path().join("render.png");
    write_srgb_png(
        &srgb_path,
        &ImageView::new("render", 2, 1, &img).unwrap(),
        0.0,
    )
    .unwrap();
    let (_, _, rgb) = decode_png(&srgb_path);
    assert_eq!(rgb, vec![0, 188, 255, 255, 0, 124]);
    only_final_files(dir.path(), &["flip.png", "relmse.png", "render.png"]);

    // Writing into a missing directory names the path.
    let err = write_false_color_png(
        &dir.path().join("missing/x.png"),
        &map,
        ColorMap::Magma,
        Scale::Linear { min: 0.0, max: 1.0 },
    )
    .unwrap_err();
    assert!(
        matches!(err, EvalError::Io { .. }) && err.to_string().contains("missing"),
        "{err}"
    );
}

#[test]
fn numbers_are_formatted_for_reading() {
    assert_eq!(fmt_num(0.0), "0");
    assert_eq!(fmt_num(0.031), "0.03100");
    assert_eq!(fmt_num(51.0), "51.00");
    assert_eq!(fmt_num(12345.0), "12345");
    assert_eq!(fmt_num(1.5e-5), "1.500e-5");
    assert_eq!(fmt_num(2.5e6), "2.500e6");
}
