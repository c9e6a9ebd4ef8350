//! Shared test helpers: the PFM reader for the FLIP fixtures.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// Directory of the FLIP fixtures made by scripts/flip_fixtures.py.
pub fn flip_fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/flip")
}

/// A PFM image: row-major, top row first, 1 or 3 channels.
pub struct Pfm {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl Pfm {
    pub fn rgb(&self) -> Vec<[f32; 3]> {
        assert_eq!(self.channels, 3);
        self.data
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect()
    }
}

/// Reads a little-endian PFM ("PF" colour or "Pf" grey; bottom row first on disk).
pub fn read_pfm(path: &Path) -> Pfm {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    let mut lines = Vec::new();
    let mut pos = 0;
    while lines.len() < 3 {
        let end = pos
            + bytes[pos..]
                .iter()
                .position(|&b| b == b'\n')
                .expect("PFM header line");
        lines.push(
            std::str::from_utf8(&bytes[pos..end])
                .unwrap()
                .trim()
                .to_string(),
        );
        pos = end + 1;
    }
    let channels = match lines[0].as_str() {
        "PF" => 3,
        "Pf" => 1,
        m => panic!("{}: not a PFM (magic {m})", path.display()),
    };
    let mut dims = lines[1]
        .split_whitespace()
        .map(|v| v.parse::<usize>().unwrap());
    let (width, height) = (dims.next().unwrap(), dims.next().unwrap());
    assert!(
        lines[2].parse::<f32>().unwrap() < 0.0,
        "{}: only little-endian PFM",
        path.display()
    );
    let floats: Vec<f32> = bytes[pos..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(
        floats.len(),
        width * height * channels,
        "{}: pixel count",
        path.display()
    );
    let row = width * channels;
    let data = (0..height)
        .rev()
        .flat_map(|y| floats[y * row..(y + 1) * row].iter().copied())
        .collect();
    Pfm {
        width,
        height,
        channels,
        data,
    }
}
