//! Progress of a long run: a bar when stderr is a terminal, and otherwise a line every few
//! seconds (logs of batch jobs), so that a 20-minute reference is seen not to be stuck.
//! Counting is thread-safe and cheap (an atomic add; the bar redraws at its own rate and the
//! log writes at most one line per interval).

use std::io::IsTerminal;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// What a run counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unit {
    Frames,
    Pixels,
}

/// Seconds between two log lines where no terminal is attached.
pub const LOG_INTERVAL: Duration = Duration::from_secs(5);

/// A run's progress: `total` units of `what`.
pub struct Progress {
    bar: Option<ProgressBar>,
    log: Option<Log>,
    done: AtomicU64,
    total: u64,
    unit: Unit,
    what: String,
    message: Mutex<String>,
    start: Instant,
}

/// Where log lines go, and when the last one went.
struct Log {
    every: Duration,
    last: Mutex<Instant>,
    sink: Box<dyn Fn(&str) + Send + Sync>,
}

impl Progress {
    /// A bar on a terminal, log lines on stderr every [`LOG_INTERVAL`] elsewhere.
    pub fn new(total: u64, unit: Unit, what: &str) -> Self {
        if std::io::stderr().is_terminal() {
            let template = match unit {
                Unit::Frames => "{elapsed_precise} [{bar:30}] {pos}/{len} frames {msg}".to_string(),
                Unit::Pixels => {
                    format!("{what} {{elapsed_precise}} [{{bar:40}}] {{percent:>3}}% ETA {{eta}}")
                }
            };
            let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr())
                .with_style(
                    ProgressStyle::with_template(&template)
                        .expect("valid progress template")
                        .progress_chars("=> "),
                );
            Self::with(Some(bar), None, total, unit, what)
        } else {
            Self::logging(
                total,
                unit,
                what,
                LOG_INTERVAL,
                Box::new(|l| eprintln!("{l}")),
            )
        }
    }

    /// Log lines only, to `sink`, at most one per `every`.
    pub fn logging(
        total: u64,
        unit: Unit,
        what: &str,
        every: Duration,
        sink: Box<dyn Fn(&str) + Send + Sync>,
    ) -> Self {
        let log = Log {
            every,
            last: Mutex::new(Instant::now()),
            sink,
        };
        Self::with(None, Some(log), total, unit, what)
    }

    fn with(
        bar: Option<ProgressBar>,
        log: Option<Log>,
        total: u64,
        unit: Unit,
        what: &str,
    ) -> Self {
        Self {
            bar,
            log,
            done: AtomicU64::new(0),
            total,
            unit,
            what: what.to_string(),
            message: Mutex::new(String::new()),
            start: Instant::now(),
        }
    }

    /// The text after the count (the method being compared, the loss).
    pub fn set_message(&self, m: impl Into<String>) {
        let m = m.into();
        if let Some(b) = &self.bar {
            b.set_message(m.clone());
        }
        *self.message.lock().expect("progress message") = m;
    }

    /// `n` more units done.
    pub fn inc(&self, n: u64) {
        let done = self.done.fetch_add(n, Ordering::Relaxed) + n;
        if let Some(b) = &self.bar {
            b.set_position(done);
        }
        if let Some(log) = &self.log {
            let now = Instant::now();
            let mut last = log.last.lock().expect("progress log");
            if now.duration_since(*last) >= log.every {
                *last = now;
                drop(last);
                (log.sink)(&self.line(done));
            }
        }
    }

    /// A log line: what, how far, how long, how long left (by the rate so far).
    fn line(&self, done: u64) -> String {
        let elapsed = self.start.elapsed().as_secs_f64();
        let frac = done as f64 / self.total.max(1) as f64;
        let eta = if frac > 0.0 {
            format!(", ETA {:.0} s", elapsed * (1.0 - frac) / frac)
        } else {
            String::new()
        };
        let unit = match self.unit {
            Unit::Frames => "frames",
            Unit::Pixels => "pixels",
        };
        let msg = self.message.lock().expect("progress message").clone();
        let msg = if msg.is_empty() {
            msg
        } else {
            format!(" ({msg})")
        };
        format!(
            "{}: {done}/{} {unit}, {:.0} %, {elapsed:.0} s{eta}{msg}",
            self.what,
            self.total,
            100.0 * frac
        )
    }

    /// Clears the bar (the log needs no closing line: the command's own summary follows).
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    fn logged(every: Duration, steps: u64) -> Vec<String> {
        let lines = Arc::new(Mutex::new(Vec::new()));
        let sink = lines.clone();
        let p = Progress::logging(
            steps,
            Unit::Pixels,
            "reference",
            every,
            Box::new(move |l| sink.lock().unwrap().push(l.to_string())),
        );
        p.set_message("pt");
        for _ in 0..steps {
            p.inc(1);
        }
        p.finish();
        drop(p);
        Arc::try_unwrap(lines).unwrap().into_inner().unwrap()
    }

    #[test]
    fn without_a_terminal_a_line_is_logged_per_interval() {
        // Interval zero: every step logs, with its count, percentage and message.
        let lines = logged(Duration::ZERO, 4);
        assert_eq!(lines.len(), 4);
        assert!(
            lines[1].starts_with("reference: 2/4 pixels, 50 %"),
            "{}",
            lines[1]
        );
        assert!(lines[3].ends_with("(pt)"), "{}", lines[3]);
        // Negative control: an interval longer than the run logs nothing.
        assert!(logged(Duration::from_secs(3600), 4).is_empty());
    }
}
