//! Support for tests: skips that are said, not silent (a test that cannot run on this machine:
//! no AVX-512, no Vulkan adapter, no `../shared/scenes`), and the seeded mutator and guarded
//! runner of the loaders' mutation tests.

use std::io::Write;
use std::path::Path;

use rand::Rng;

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

/// Runs `f` on its own thread: its value, or an error naming a panic or a hang (no answer
/// within `limit`; the thread is left behind).
pub fn guarded<T: Send + 'static>(
    limit: std::time::Duration,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, String> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(limit) {
        Ok(v) => Ok(v),
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
            Err(format!("no answer within {limit:?}"))
        }
        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => Err("panicked".into()),
    }
}

/// A global allocator (the system's) that records the largest single request, allocation or
/// reallocation, since [`reset_largest_allocation`], and the most bytes live at once since
/// [`reset_peak_live`]: a test binary installs it
/// (`#[global_allocator] static A: LargestAllocation = LargestAllocation;`) to bound what an
/// absurd count in a file may make a loader allocate, or what loading a large scene holds at
/// its peak. It sees every thread of the process, so a bound is checked by a test that runs
/// its cases one at a time.
pub struct LargestAllocation;

static LARGEST: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
static LIVE: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
static PEAK: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Counts `size` more bytes live (and the request as a candidate for the largest).
fn grew(request: usize, size: usize) {
    use std::sync::atomic::Ordering::Relaxed;
    LARGEST.fetch_max(request, Relaxed);
    let live = LIVE.fetch_add(size, Relaxed) + size;
    PEAK.fetch_max(live, Relaxed);
}

// SAFETY: every call is forwarded unchanged to the system allocator; only counters are kept.
unsafe impl std::alloc::GlobalAlloc for LargestAllocation {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: the caller's contract is the system allocator's.
        let p = unsafe { std::alloc::System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size(), layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { std::alloc::System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size(), layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        LIVE.fetch_sub(layout.size(), std::sync::atomic::Ordering::Relaxed);
        // SAFETY: as above.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { std::alloc::System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            // The old block counts until the new one exists (a moving realloc holds both).
            grew(new_size, new_size);
            LIVE.fetch_sub(layout.size(), std::sync::atomic::Ordering::Relaxed);
        }
        p
    }
}

/// The largest request [`LargestAllocation`] saw since the last reset, in bytes.
pub fn largest_allocation() -> usize {
    LARGEST.load(std::sync::atomic::Ordering::Relaxed)
}

/// Starts [`largest_allocation`] again from zero.
pub fn reset_largest_allocation() {
    LARGEST.store(0, std::sync::atomic::Ordering::Relaxed);
}

/// The bytes live now through [`LargestAllocation`].
pub fn live_bytes() -> usize {
    LIVE.load(std::sync::atomic::Ordering::Relaxed)
}

/// The most bytes live at once through [`LargestAllocation`] since [`reset_peak_live`].
pub fn peak_live_bytes() -> usize {
    PEAK.load(std::sync::atomic::Ordering::Relaxed)
}

/// Starts [`peak_live_bytes`] again from the bytes live now.
pub fn reset_peak_live() {
    PEAK.store(live_bytes(), std::sync::atomic::Ordering::Relaxed);
}

/// The outcome of one mutated input.
#[derive(Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Loaded (and, where the test checks it, usable).
    Loaded,
    /// Refused with an error.
    Refused,
    /// A failure of the property: a panic, a hang, an allocation beyond the bound or a loaded
    /// result that is not usable; the text says which.
    Failed(String),
}

/// A tally of mutated inputs per kind of file, and the failures with the files kept for them.
#[derive(Default)]
pub struct Tally {
    /// kind → (cases, loaded, refused).
    pub kinds: std::collections::BTreeMap<String, (u32, u32, u32)>,
    pub failures: Vec<String>,
}

impl Tally {
    /// Runs one case: `load` on its own thread within `limit`, its largest allocation at most
    /// `max_bytes`; `Some(true)` a usable result, `Some(false)` one that is not, `None` an
    /// error. A failing input (`bytes`) is written to the system's temporary folder as
    /// `nrc-mutated-<label>` and named in the failure, to be kept as a regression fixture.
    pub fn case(
        &mut self,
        kind: &str,
        label: &str,
        bytes: &[u8],
        (limit, max_bytes): (std::time::Duration, usize),
        load: impl FnOnce() -> Option<bool> + Send + 'static,
    ) -> Outcome {
        reset_largest_allocation();
        let r = guarded(limit, load);
        let largest = largest_allocation();
        let outcome = match r {
            Err(why) => Outcome::Failed(why),
            Ok(_) if largest > max_bytes => Outcome::Failed(format!(
                "allocated {largest} bytes at once, beyond the bound of {max_bytes}"
            )),
            Ok(Some(true)) => Outcome::Loaded,
            Ok(Some(false)) => Outcome::Failed("loaded but not usable".into()),
            Ok(None) => Outcome::Refused,
        };
        let k = self.kinds.entry(kind.to_string()).or_default();
        k.0 += 1;
        match &outcome {
            Outcome::Loaded => k.1 += 1,
            Outcome::Refused => k.2 += 1,
            Outcome::Failed(why) => {
                let keep = std::env::temp_dir().join(format!("nrc-mutated-{label}"));
                let _ = std::fs::write(&keep, bytes);
                self.failures
                    .push(format!("{label}: {why}; kept as {}", keep.display()));
            }
        }
        outcome
    }

    /// One line per kind: cases, loaded, refused.
    pub fn summary(&self) -> String {
        self.kinds
            .iter()
            .map(|(k, (n, ok, err))| format!("{k}: {n} cases, {ok} loaded, {err} clean errors"))
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// Panics naming every failure.
    pub fn assert_clean(&self) {
        let total: u32 = self.kinds.values().map(|k| k.0).sum();
        assert!(
            self.failures.is_empty(),
            "{} of {total} mutated inputs failed:\n{}",
            self.failures.len(),
            self.failures.join("\n")
        );
    }
}

/// Cases per file of a long mutation run: `NRC_MUTATIONS` from the environment, else `default`.
pub fn mutation_cases(default: u32) -> u32 {
    std::env::var("NRC_MUTATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// One mutation of `bytes` (JSON-aware when `json`).
pub fn mutate(bytes: &[u8], json: bool, rng: &mut impl Rng) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let kind = rng.random_range(0..if json { 6 } else { 3 });
    match kind {
        // Flip a few bytes.
        0 => {
            for _ in 0..rng.random_range(1..8) {
                let i = rng.random_range(0..b.len());
                b[i] ^= 1 << rng.random_range(0..8);
            }
        }
        // Truncate.
        1 => b.truncate(rng.random_range(0..b.len())),
        // Repeat a range.
        2 => {
            let i = rng.random_range(0..b.len());
            let j = (i + rng.random_range(1..256)).min(b.len());
            let piece = b[i..j].to_vec();
            let at = rng.random_range(0..b.len());
            b.splice(at..at, piece);
        }
        // A number replaced by NaN, ±Inf, a huge or a negative value, or a broken index.
        _ => {
            let text = String::from_utf8_lossy(&b).into_owned();
            let numbers: Vec<(usize, usize)> = number_spans(&text);
            if numbers.is_empty() {
                return b;
            }
            let (s, e) = numbers[rng.random_range(0..numbers.len())];
            let replacement = [
                "NaN",
                "Infinity",
                "-Infinity",
                "1e39",
                "-1",
                "4294967296",
                "18446744073709551615",
                "99999999",
                "-0.5",
                "0",
            ][rng.random_range(0..10)];
            let mut t = text;
            t.replace_range(s..e, replacement);
            b = t.into_bytes();
        }
    }
    b
}

/// Byte spans of the JSON numbers in `text` (digits with sign, point and exponent).
pub fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let bytes = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    let mut in_string = false;
    while i < bytes.len() {
        let c = bytes[i];
        if c == b'"' && (i == 0 || bytes[i - 1] != b'\\') {
            in_string = !in_string;
        }
        if !in_string && (c.is_ascii_digit() || c == b'-') {
            let s = i;
            while i < bytes.len()
                && matches!(bytes[i], b'0'..=b'9' | b'-' | b'+' | b'.' | b'e' | b'E')
            {
                i += 1;
            }
            out.push((s, i));
            continue;
        }
        i += 1;
    }
    out
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
