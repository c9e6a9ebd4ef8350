//! The Python tests (`test_*.py` in this folder, pytest) as one Rust test, so that the README's
//! test command, `cargo test --release --workspace`, runs every test, Rust and Python. The
//! module is this crate's cdylib from the same build (the crate is also an rlib, so cargo builds
//! its library, both kinds, before its integration tests), copied beside the package's Python files as `nrc/_nrc.abi3.so`: no
//! second build. `NRC_PYTEST` replaces pytest's arguments (e.g. `-s crates/nrc-py/tests/test_overhead.py`);
//! `NRC_BIN` (the `nrc` program of the same build) is given to the tests of the study drivers.

use std::path::Path;
use std::process::Command;

#[test]
fn python_tests() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let root = crate_dir.parent().and_then(Path::parent).unwrap();
    // This test runs as target/<profile>/deps/python-…; cargo builds the crate's cdylib into
    // that folder (its library, built before the integration tests), the `nrc` program into
    // target/<profile>.
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    let profile = deps.parent().unwrap();
    let library = deps.join(format!(
        "{}nrc_py{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    ));
    assert!(
        library.exists(),
        "error: the module {} was not built (run `cargo test --workspace`)",
        library.display()
    );
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let found = Command::new(&python)
        .args(["-c", "import numpy, pytest"])
        .status();
    assert!(
        found.is_ok_and(|s| s.success()),
        "error: the Python tests need numpy and pytest (and ray for the study driver's): {python} -m pip install numpy pytest ray"
    );

    let tmp = tempfile::tempdir().unwrap();
    let package = tmp.path().join("nrc");
    std::fs::create_dir_all(&package).unwrap();
    for entry in std::fs::read_dir(crate_dir.join("python/nrc")).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, package.join(path.file_name().unwrap())).unwrap();
    }
    std::fs::copy(&library, package.join("_nrc.abi3.so")).unwrap();

    let args: Vec<String> = match std::env::var("NRC_PYTEST") {
        Ok(a) => a.split_whitespace().map(String::from).collect(),
        Err(_) => vec!["-q".into(), crate_dir.join("tests").display().to_string()],
    };
    let status = Command::new(&python)
        .args(["-m", "pytest", "-p", "no:cacheprovider"])
        .args(&args)
        .current_dir(root)
        .env("PYTHONPATH", tmp.path())
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .env(
            "NRC_BIN",
            profile.join(format!("nrc{}", std::env::consts::EXE_SUFFIX)),
        )
        .status()
        .expect("python runs");
    assert!(status.success(), "the Python tests failed (output above)");
}
