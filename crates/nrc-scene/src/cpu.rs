//! The CPU this runs on: the features this build was compiled for, checked against it, and
//! the CPU time this process has used (for figures per CPU-second on a shared machine).
//!
//! The workspace builds for x86-64-v3 (`.cargo/config.toml`: AVX2, FMA, BMI1/2, F16C, LZCNT,
//! MOVBE). On a CPU without them the first such instruction would kill the process with
//! SIGILL; `nrc` and the Python module call [`check`] before anything else runs so that the
//! user gets one line naming what is missing and how to build for that CPU instead.

/// The x86 features a build may have been compiled with, by their `target_feature` names.
#[cfg(target_arch = "x86_64")]
const COMPILED: [(&str, bool); 9] = [
    ("avx", cfg!(target_feature = "avx")),
    ("avx2", cfg!(target_feature = "avx2")),
    ("fma", cfg!(target_feature = "fma")),
    ("bmi1", cfg!(target_feature = "bmi1")),
    ("bmi2", cfg!(target_feature = "bmi2")),
    ("f16c", cfg!(target_feature = "f16c")),
    ("lzcnt", cfg!(target_feature = "lzcnt")),
    ("movbe", cfg!(target_feature = "movbe")),
    ("avx512f", cfg!(target_feature = "avx512f")),
];

/// The features this binary was compiled to use (empty off x86-64 or in a baseline build).
pub fn compiled_features() -> Vec<&'static str> {
    #[cfg(target_arch = "x86_64")]
    {
        COMPILED
            .iter()
            .filter(|(_, on)| *on)
            .map(|(name, _)| *name)
            .collect()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Vec::new()
    }
}

/// Whether the running CPU has the feature `name` (one of [`compiled_features`]' names).
fn detected(name: &str) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        match name {
            "avx" => std::arch::is_x86_feature_detected!("avx"),
            "avx2" => std::arch::is_x86_feature_detected!("avx2"),
            "fma" => std::arch::is_x86_feature_detected!("fma"),
            "bmi1" => std::arch::is_x86_feature_detected!("bmi1"),
            "bmi2" => std::arch::is_x86_feature_detected!("bmi2"),
            "f16c" => std::arch::is_x86_feature_detected!("f16c"),
            "lzcnt" => std::arch::is_x86_feature_detected!("lzcnt"),
            "movbe" => std::arch::is_x86_feature_detected!("movbe"),
            "avx512f" => std::arch::is_x86_feature_detected!("avx512f"),
            _ => false,
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = name;
        true
    }
}

/// The message for a CPU that lacks `missing` of the `compiled` features, or `None` when it
/// lacks none. `has` says whether the CPU has a feature (the real detector in [`check`]).
pub fn missing_message(compiled: &[&str], has: impl Fn(&str) -> bool) -> Option<String> {
    let missing: Vec<&str> = compiled.iter().copied().filter(|f| !has(f)).collect();
    (!missing.is_empty()).then(|| {
        format!(
            "this CPU lacks {} that this build of nrc was compiled for (x86-64-v3, set in \
             .cargo/config.toml); rebuild for it with RUSTFLAGS=\"-C target-cpu=native\"",
            missing.join(", ")
        )
    })
}

/// `Err(message)` when the running CPU lacks a feature this binary was compiled for.
pub fn check() -> Result<(), String> {
    match missing_message(&compiled_features(), detected) {
        Some(m) => Err(m),
        None => Ok(()),
    }
}

/// CPU time (user + system) used so far by all threads of this process, where the system
/// tells it (`/proc/self/stat` on Linux, in clock ticks of 1/100 s), or `None` elsewhere.
pub fn process_cpu_time() -> Option<std::time::Duration> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let mut fields = rest.split_whitespace().skip(11);
    let utime: u64 = fields.next()?.parse().ok()?;
    let stime: u64 = fields.next()?.parse().ok()?;
    Some(std::time::Duration::from_millis((utime + stime) * 10))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cpu_without_avx2_is_named() {
        let compiled = ["avx", "avx2", "fma"];
        let m = missing_message(&compiled, |f| f != "avx2").expect("avx2 is missing");
        assert!(m.contains("lacks avx2 that"), "{m}");
        let m = missing_message(&compiled, |f| f == "avx").expect("two are missing");
        assert!(m.contains("lacks avx2, fma that"), "{m}");
        assert_eq!(missing_message(&compiled, |_| true), None);
    }

    #[test]
    fn this_build_targets_x86_64_v3_and_this_cpu_runs_it() {
        if cfg!(target_arch = "x86_64") {
            let compiled = compiled_features();
            // `.cargo/config.toml` is in effect (a build without it would pass the check
            // below trivially and be 1.3-1.5x slower).
            for f in ["avx2", "fma", "bmi2"] {
                assert!(compiled.contains(&f), "{f} not compiled in: {compiled:?}");
            }
        }
        assert_eq!(check(), Ok(()));
    }

    #[test]
    fn cpu_time_counts_work() {
        let t0 = process_cpu_time().expect("Linux reports CPU time");
        let start = std::time::Instant::now();
        let mut x = 1u64;
        while start.elapsed() < std::time::Duration::from_millis(200) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let spent = process_cpu_time().unwrap() - t0;
        // 200 ms of busy wall time on this thread: at least some of it on the CPU even on
        // a loaded machine, and not more than the wall time of every thread there is.
        assert!(spent >= std::time::Duration::from_millis(20), "{spent:?}");
    }
}
