//! The live status line of a multi-process run on a terminal (docs/running.md): one line
//! on stdout, redrawn in place every [`REDRAW`], wiped at the end. Nothing is written when
//! stdout is not a terminal.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// How often the line is redrawn: often enough to follow, rarely enough to cost nothing.
const REDRAW: Duration = Duration::from_millis(250);

/// What the line shows.
pub(super) struct Live {
    pub t_s: f64,
    pub duration_s: f64,
    pub deadline_misses: u64,
    /// Sensor to actuator of the newest tick recorded, µs.
    pub sensor_to_actuator_us: Option<f64>,
    pub clearance_m: Option<f64>,
    pub mode: &'static str,
}

impl Live {
    fn line(&self) -> String {
        let latency = self
            .sensor_to_actuator_us
            .map_or_else(|| "-".into(), |us| format!("{us:.0} µs"));
        let clearance = self
            .clearance_m
            .map_or_else(|| "-".into(), |m| format!("{m:.3} m"));
        format!(
            "t {:5.1} / {:.1} s | deadline misses {} | sensor→actuator {latency} | clearance {clearance} | {}",
            self.t_s, self.duration_s, self.deadline_misses, self.mode
        )
    }
}

pub(super) struct StatusLine {
    enabled: bool,
    drawn: Option<Instant>,
}

impl StatusLine {
    pub fn new() -> StatusLine {
        StatusLine {
            enabled: std::io::stdout().is_terminal(),
            drawn: None,
        }
    }

    /// Redraws the line with `live()` if it is due.
    pub fn update(&mut self, live: impl FnOnce() -> Live) {
        if !self.enabled || self.drawn.is_some_and(|at| at.elapsed() < REDRAW) {
            return;
        }
        self.drawn = Some(Instant::now());
        let mut out = std::io::stdout().lock();
        let _ = write!(out, "\r\x1b[2K{}", live().line());
        let _ = out.flush();
    }

    /// Wipes the line, so what follows starts on a clean one.
    pub fn clear(&mut self) {
        if self.drawn.take().is_some() {
            let mut out = std::io::stdout().lock();
            let _ = write!(out, "\r\x1b[2K");
            let _ = out.flush();
        }
    }
}
