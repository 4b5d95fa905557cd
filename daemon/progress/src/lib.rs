//! Progress of long commands (`record`, `index build`, `classify`, the
//! lab's studies): an indicatif bar with ETA when standard error is a
//! terminal, plain lines at most every few seconds otherwise (logs, CI),
//! so that long work always shows it is alive without flooding a log.
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// Shortest interval between two plain lines.
pub const PLAIN_EVERY: Duration = Duration::from_secs(5);

type Sink = Box<dyn Write + Send>;

struct Plain {
    sink: Sink,
    done: u64,
    started: Instant,
    last: Option<Instant>,
    message: String,
}

/// A progress display (see the crate docs). Cheap to update from a loop.
pub struct Progress {
    label: String,
    unit: String,
    total: u64,
    bar: Option<ProgressBar>,
    plain: Option<Mutex<Plain>>,
}

impl Progress {
    /// Progress of `total` `unit`s of work named `label`, on standard
    /// error: a bar on a terminal, plain lines otherwise.
    pub fn new(label: &str, total: u64, unit: &str) -> Progress {
        if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(total);
            let style = ProgressStyle::with_template(&format!(
                "{label} [{{bar:30}}] {{pos}}/{{len}} {unit} ({{percent}} %), {{elapsed}} elapsed, ETA {{eta}} {{msg}}"
            ))
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
            bar.set_style(style);
            return Progress {
                label: label.into(),
                unit: unit.into(),
                total,
                bar: Some(bar),
                plain: None,
            };
        }
        Progress::plain(label, total, unit, Box::new(std::io::stderr()))
    }

    /// Plain lines to `sink` (what a log gets).
    pub fn plain(label: &str, total: u64, unit: &str, sink: Box<dyn Write + Send>) -> Progress {
        Progress {
            label: label.into(),
            unit: unit.into(),
            total,
            bar: None,
            plain: Some(Mutex::new(Plain {
                sink,
                done: 0,
                started: Instant::now(),
                last: None,
                message: String::new(),
            })),
        }
    }

    /// `n` more units done.
    pub fn inc(&self, n: u64) {
        if let Some(b) = &self.bar {
            b.inc(n);
        }
        if let Some(p) = &self.plain {
            let mut p = p.lock().unwrap_or_else(|e| e.into_inner());
            p.done += n;
            let now = Instant::now();
            let due = p.last.is_none_or(|t| now.duration_since(t) >= PLAIN_EVERY);
            if due || p.done >= self.total {
                p.last = Some(now);
                let line = plain_line(
                    &self.label,
                    p.done,
                    self.total,
                    &self.unit,
                    now.duration_since(p.started),
                    &p.message,
                );
                let _ = writeln!(p.sink, "{line}");
            }
        }
    }

    /// A note shown with the counts (e.g. the item being worked on).
    pub fn set_message(&self, msg: &str) {
        if let Some(b) = &self.bar {
            b.set_message(msg.to_string());
        }
        if let Some(p) = &self.plain {
            p.lock().unwrap_or_else(|e| e.into_inner()).message = msg.to_string();
        }
    }

    /// Print a line without breaking the bar.
    pub fn println(&self, line: &str) {
        match (&self.bar, &self.plain) {
            (Some(b), _) => b.println(line),
            (None, Some(p)) => {
                let _ = writeln!(p.lock().unwrap_or_else(|e| e.into_inner()).sink, "{line}");
            }
            _ => {}
        }
    }

    /// Done: the bar stays on screen with its final count.
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish();
        }
    }
}

/// One plain progress line: `label: 12/32 presses (38 %), 4 s elapsed, ETA 7 s`.
pub fn plain_line(
    label: &str,
    done: u64,
    total: u64,
    unit: &str,
    elapsed: Duration,
    message: &str,
) -> String {
    let pct = if total > 0 {
        (done as f64 * 100.0 / total as f64).min(100.0)
    } else {
        100.0
    };
    let secs = elapsed.as_secs_f64();
    let eta = if done > 0 && done < total {
        format!(", ETA {:.0} s", secs / done as f64 * (total - done) as f64)
    } else {
        String::new()
    };
    let msg = if message.is_empty() {
        String::new()
    } else {
        format!(" ({message})")
    };
    format!("{label}: {done}/{total} {unit} ({pct:.0} %), {secs:.0} s elapsed{eta}{msg}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[derive(Clone, Default)]
    struct Buf(Arc<Mutex<Vec<u8>>>);
    impl Write for Buf {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn plain_lines_are_rate_limited_and_the_last_one_always_shows() {
        let buf = Buf::default();
        let p = Progress::plain("index build", 1000, "presses", Box::new(buf.clone()));
        p.set_message("T030");
        for _ in 0..1000 {
            p.inc(1);
        }
        let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        // The first update and the completion; the loop is far shorter
        // than the interval, so nothing in between.
        assert_eq!(lines.len(), 2, "{text}");
        assert!(
            lines[0].starts_with("index build: 1/1000 presses (0 %)"),
            "{text}"
        );
        assert!(
            lines[0].contains("ETA") && lines[0].ends_with("(T030)"),
            "{text}"
        );
        assert!(
            lines[1].starts_with("index build: 1000/1000 presses (100 %)"),
            "{text}"
        );
        assert!(!lines[1].contains("ETA"), "{text}");
    }

    #[test]
    fn eta_scales_with_the_work_left() {
        let l = plain_line("x", 25, 100, "frames", Duration::from_secs(10), "");
        assert_eq!(l, "x: 25/100 frames (25 %), 10 s elapsed, ETA 30 s");
        let z = plain_line("x", 0, 0, "frames", Duration::ZERO, "");
        assert_eq!(z, "x: 0/0 frames (100 %), 0 s elapsed");
    }
}
