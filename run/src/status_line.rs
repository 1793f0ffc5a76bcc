//! The live status line of a run (docs/running.md), a [`Sink`]: on a terminal one line on
//! stdout, redrawn in place every [`REDRAW`] as ticks are recorded, wiped at the end;
//! elsewhere (a pipe, a file, CI's log) the same line printed anew every
//! [`progress_every`] of wall time. A fleet's run has one line for the fleet
//! ([`FleetStatus`]), drawn by its executor as it judges the robots' ticks.

use protocol::{CommandMode, Timing};
use record::fleet::FleetJudge;
use record::judge::Outcome;
use record::{RunStart, Sample, Sink, Summary, TickSample};
use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// How often the line is redrawn: often enough to follow, rarely enough to cost nothing.
const REDRAW: Duration = Duration::from_millis(250);
/// How often a command whose output is no terminal prints its progress line, by default.
pub const PROGRESS_EVERY: Duration = Duration::from_secs(5);
/// Seconds between two progress lines instead of [`PROGRESS_EVERY`]'s 5 (a positive
/// number; anything else is ignored).
pub const ENV_PROGRESS_S: &str = "SCMPC_PROGRESS_S";

/// How often a command whose output is no terminal prints its progress line:
/// [`ENV_PROGRESS_S`], else [`PROGRESS_EVERY`].
pub fn progress_every() -> Duration {
    (std::env::var(ENV_PROGRESS_S).ok())
        .and_then(|s| s.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s > 0.0)
        .map_or(PROGRESS_EVERY, Duration::from_secs_f64)
}

/// What the line shows.
#[derive(Debug, Default)]
struct Live {
    t_s: f64,
    duration_s: f64,
    deadline_misses: u64,
    /// Sensor to actuator of the newest tick that has one, µs.
    sensor_to_actuator_us: Option<f64>,
    clearance_m: Option<f64>,
    mode: &'static str,
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

    /// What `tick` shows: sensor to actuator is measured on a tick within a sample (no
    /// solve in between) whose measurement and estimate came.
    fn tick(&mut self, tick: &TickSample<'_>, timing: &Timing) {
        let (truth, act) = (tick.truth, tick.actuation);
        self.t_s = truth.header.time_s;
        self.clearance_m = Some(tick.clearance_m);
        self.mode = act.mode().unwrap_or(CommandMode::Brake).as_str();
        let within_sample = !timing.starts_sample(truth.header.tick);
        if let (Some(m), true, false) = (
            tick.measurement,
            within_sample,
            tick.estimate.state[0].is_nan(),
        ) {
            let ns = act.header.publish_ns.saturating_sub(m.header.publish_ns);
            self.sensor_to_actuator_us = Some(ns as f64 / 1e3);
        }
    }
}

/// Where a line goes and when: redrawn in place on a terminal every [`REDRAW`], printed
/// anew elsewhere every [`progress_every`] (the first one interval in).
struct Drawer {
    redraw: bool,
    every: Duration,
    /// When the line was last drawn (printed), or the run started.
    drawn: Option<Instant>,
}

impl Drawer {
    fn new() -> Drawer {
        let redraw = std::io::stdout().is_terminal();
        Drawer {
            redraw,
            every: if redraw { REDRAW } else { progress_every() },
            drawn: (!redraw).then(Instant::now),
        }
    }

    /// Draws `line()` if it is time to.
    fn draw(&mut self, line: impl FnOnce() -> String) {
        if self.drawn.is_some_and(|at| at.elapsed() < self.every) {
            return;
        }
        self.drawn = Some(Instant::now());
        // A line that cannot be drawn is no reason to stop the run.
        let mut out = std::io::stdout().lock();
        let _ = if self.redraw {
            write!(out, "\r\x1b[2K{}", line())
        } else {
            writeln!(out, "{}", line())
        };
        let _ = out.flush();
    }

    /// Wipes the line on a terminal, so what follows starts on a clean one.
    fn wipe(&self) {
        if self.redraw && self.drawn.is_some() {
            let mut out = std::io::stdout().lock();
            let _ = write!(out, "\r\x1b[2K");
            let _ = out.flush();
        }
    }
}

pub struct StatusLine {
    live: Live,
    timing: Timing,
    drawer: Drawer,
}

impl StatusLine {
    /// The sink's opener.
    pub fn open(run: &RunStart) -> std::io::Result<Option<Box<dyn Sink>>> {
        Ok(Some(Box::new(StatusLine {
            drawer: Drawer::new(),
            live: Live {
                duration_s: run.scenario.duration_s,
                mode: "-",
                ..Live::default()
            },
            timing: run.scenario.timing.clone(),
        })))
    }
}

impl Sink for StatusLine {
    fn sample(&mut self, sample: &Sample<'_>) -> std::io::Result<()> {
        match sample {
            Sample::Tick(tick) => self.live.tick(tick, &self.timing),
            Sample::Verdict(v) => self.live.deadline_misses += u64::from(v.met == 0),
            _ => return Ok(()),
        }
        let live = &self.live;
        self.drawer.draw(|| live.line());
        Ok(())
    }

    fn end(self: Box<Self>, _summary: &Summary, _whole: bool) -> std::io::Result<()> {
        self.drawer.wipe();
        Ok(())
    }
}

/// The status line of a fleet's run (`scmpc run` of a scenario with `[[robots]]`, without
/// `-q`): the time its robots have been judged to, how many ended their record at their
/// goal, the deadlines their records counted as missed (in all, then the robots that
/// missed any, [`misses_by_robot`]), and their smallest clearance to each other so far and their contacts.
pub struct FleetStatus {
    drawer: Drawer,
    duration_s: f64,
    robots: usize,
}

impl FleetStatus {
    /// The line of a fleet of `robots` run for `duration_s`, if the run has one.
    pub fn of(status_line: bool, duration_s: f64, robots: usize) -> Option<FleetStatus> {
        status_line.then(|| FleetStatus {
            drawer: Drawer::new(),
            duration_s,
            robots,
        })
    }

    /// The fleet judged to `t_s`, with each robot's `outcomes` so far and the deadline
    /// misses of each robot's record, in the robots' order.
    pub fn show(
        &mut self,
        t_s: f64,
        outcomes: impl Iterator<Item = Option<Outcome>>,
        deadline_misses: impl Iterator<Item = u64>,
        judge: &FleetJudge,
    ) {
        let (duration_s, robots) = (self.duration_s, self.robots);
        self.drawer.draw(|| {
            let reached = outcomes.filter(|o| *o == Some(Outcome::Reached)).count();
            let misses = misses_by_robot(deadline_misses);
            fleet_line(t_s, duration_s, (reached, robots), &misses, judge)
        });
    }
}

/// Wiped on a terminal once the fleet's run ends, whichever way: before the end table or
/// an error.
impl Drop for FleetStatus {
    fn drop(&mut self) {
        self.drawer.wipe();
    }
}

/// Most robots the status line names as having missed deadlines: the line stays within a
/// terminal's width, where a redraw in place can wipe it.
const MISSING_ROBOTS_SHOWN: usize = 3;

/// The deadline misses of a fleet's robots (`misses`, in their order): in all, then the
/// first [`MISSING_ROBOTS_SHOWN`] robots that missed any, as `3 (robot 1: 2, robot 4: 1)`
/// (`, …` when more did); `0` when none missed.
fn misses_by_robot(misses: impl Iterator<Item = u64>) -> String {
    let (mut all, mut robots) = (0, Vec::new());
    for (id, n) in misses.enumerate().filter(|(_, n)| *n > 0) {
        all += n;
        robots.push(format!("robot {id}: {n}"));
    }
    if robots.len() > MISSING_ROBOTS_SHOWN {
        robots.truncate(MISSING_ROBOTS_SHOWN);
        robots.push("…".into());
    }
    match robots.is_empty() {
        true => "0".into(),
        false => format!("{all} ({})", robots.join(", ")),
    }
}

/// The line of a fleet judged to `t_s` of `duration_s`, `(reached, robots)` of its robots
/// at their goals, `deadline_misses` as [`misses_by_robot`] writes them.
fn fleet_line(
    t_s: f64,
    duration_s: f64,
    (reached, robots): (usize, usize),
    deadline_misses: &str,
    judge: &FleetJudge,
) -> String {
    let clearance = match judge.min_clearance_m.is_finite() {
        true => format!("{:.3} m", judge.min_clearance_m),
        false => "none".into(),
    };
    let (moving, at_rest): (u64, u64) = (
        judge.contacts_moving.iter().sum(),
        judge.contacts_at_rest.iter().sum(),
    );
    format!(
        "t {t_s:5.1} / {duration_s:.1} s | at their goals {reached} of {robots} | deadline misses {deadline_misses} | robot-robot clearance {clearance} | contacts {moving} moving, {at_rest} at rest"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fleets_misses_name_the_robots_that_missed_in_the_robots_order() {
        assert_eq!(misses_by_robot([0, 0, 0].into_iter()), "0");
        assert_eq!(
            misses_by_robot([0, 2, 0, 0, 1].into_iter()),
            "3 (robot 1: 2, robot 4: 1)"
        );
        assert_eq!(
            misses_by_robot([1, 1, 1, 1, 0, 1].into_iter()),
            "5 (robot 0: 1, robot 1: 1, robot 2: 1, …)"
        );
    }
}
