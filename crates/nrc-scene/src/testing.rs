//! Support for tests that cannot run on every machine (no AVX-512, no Vulkan adapter, no
//! `../shared/scenes`): a skip is said, not silent.

use std::io::Write;
use std::path::Path;

/// Reports that test `test` did not run here, and why: a `SKIPPED` line on stderr (seen with
/// `--nocapture`) and, where the environment names a file in `NRC_SKIP_LOG`, a line appended to
/// it: `.ci/run` prints those lines as its summary and fails if the wgpu tests are among them.
pub fn skipped(test: &str, reason: &str) {
    let log = std::env::var_os("NRC_SKIP_LOG");
    skipped_to(log.as_deref().map(Path::new), test, reason);
}

/// [`skipped`] with the log file given.
pub fn skipped_to(log: Option<&Path>, test: &str, reason: &str) {
    eprintln!("SKIPPED {test}: {reason}");
    if let Some(path) = log {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path);
        if let Ok(mut f) = file {
            let _ = writeln!(f, "{test}: {reason}");
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn skips_are_appended_to_the_log() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("skipped.log");
        super::skipped_to(Some(&log), "a_wgpu_test", "no adapter");
        super::skipped_to(Some(&log), "an_avx512_test", "no AVX-512F");
        assert_eq!(
            std::fs::read_to_string(&log).unwrap(),
            "a_wgpu_test: no adapter\nan_avx512_test: no AVX-512F\n"
        );
    }
}
