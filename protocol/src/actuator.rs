//! The base's response to its commands (`robot.actuator_lag_s`, `robot.command_delay_s`,
//! docs/robot.md): a speed command `[u1 (m/s), u2 (rad/s)]` published at `t` takes effect
//! at `t + delay`, and the base's speeds follow the command in effect with a first-order
//! lag, `s' = (u - s) / lag`, on each channel. With both zero the base realizes each
//! command at once (the paper's unicycle). The plant simulates this model, the estimator
//! predicts with it and the DFL inverts it; `scmpc identify` fits it to a robot.

use crate::{AutoOr, Scenario};
use std::collections::VecDeque;

/// Largest actuator lag accepted, s: a base slower than this is no base the DFL can
/// shape commands for at its tick.
pub const MAX_ACTUATOR_LAG_S: f64 = 1.0;
/// Largest command delay accepted, s.
pub const MAX_COMMAND_DELAY_S: f64 = 0.5;

impl Scenario {
    /// The base as the controller models it (`robot.actuator_lag_s`,
    /// `robot.command_delay_s`).
    pub fn actuator(&self) -> Actuator {
        Actuator {
            lag_s: self.robot.actuator_lag_s,
            delay_s: self.robot.command_delay_s,
        }
    }

    /// How far a plan's timeline runs behind the clock, s: the whole inner ticks of the
    /// modelled command delay. Plan(k) is made from the state predicted for `t_k +
    /// command_lead_s`, and the DFL flies its element `i` with the commands that take effect
    /// from `t_k + i Ts + command_lead_s` on (docs/robot.md); the discs tracks predict are
    /// shifted likewise.
    pub fn command_lead_s(&self) -> f64 {
        let dt_s = self.timing.dt_s();
        CommandLine::whole_ticks(self.robot.command_delay_s, dt_s) as f64 * dt_s
    }

    /// The base the simulated plant is: `plant.actuator_lag_s` and
    /// `plant.command_delay_s` where set, else the model's.
    pub fn simulated_actuator(&self) -> Actuator {
        let model = self.actuator();
        let or_model = |value: AutoOr, model: f64| match value {
            AutoOr::Auto(_) => model,
            AutoOr::Value(value) => value,
        };
        Actuator {
            lag_s: or_model(self.plant.actuator_lag_s, model.lag_s),
            delay_s: or_model(self.plant.command_delay_s, model.delay_s),
        }
    }

    /// What is wrong with the lag and delay keys, each with its key: each in `[0, most]`.
    pub fn actuator_problems(&self) -> Vec<(&'static str, String)> {
        let simulated = |value: AutoOr| match value {
            AutoOr::Value(value) => Some(value),
            AutoOr::Auto(_) => None,
        };
        let (lag, delay) = (MAX_ACTUATOR_LAG_S, MAX_COMMAND_DELAY_S);
        let keys = [
            ("robot.actuator_lag_s", Some(self.robot.actuator_lag_s), lag),
            (
                "robot.command_delay_s",
                Some(self.robot.command_delay_s),
                delay,
            ),
            (
                "plant.actuator_lag_s",
                simulated(self.plant.actuator_lag_s),
                lag,
            ),
            (
                "plant.command_delay_s",
                simulated(self.plant.command_delay_s),
                delay,
            ),
        ];
        (keys.into_iter())
            .filter_map(|(key, value, most)| {
                let value = value?;
                let within = value.is_finite() && (0.0..=most).contains(&value);
                (!within).then(|| (key, format!("must be in [0, {most}] s, got {value}")))
            })
            .collect()
    }
}

/// How a base follows its speed commands.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Actuator {
    /// Time constant of the first-order lag of the base's speed loop, s.
    pub lag_s: f64,
    /// Time from a command's publication to its effect, s.
    pub delay_s: f64,
}

impl Actuator {
    /// A base that realizes every command at once.
    pub fn is_ideal(&self) -> bool {
        self.lag_s == 0.0 && self.delay_s == 0.0
    }

    /// The share of a speed step still to come after `duration_s`: `exp(-duration / lag)`
    /// (0 without lag).
    pub fn remaining(&self, duration_s: f64) -> f64 {
        if self.lag_s > 0.0 {
            (-duration_s / self.lag_s).exp()
        } else {
            0.0
        }
    }

    /// The speeds after `duration_s` of `command` from `speeds`, and their mean over that
    /// time (the exact solution of the lag: each channel approaches the command
    /// exponentially).
    pub fn follow(&self, speeds: [f64; 2], command: [f64; 2], duration_s: f64) -> Followed {
        self.decay(duration_s).follow(speeds, command)
    }

    /// How much of a speed step the lag leaves after `duration_s`, and on average over it.
    pub fn decay(&self, duration_s: f64) -> Decay {
        let left = self.remaining(duration_s);
        // Mean of exp(-t / lag) over [0, duration]; 0 without lag (a jump at t = 0).
        let mean_left = if self.lag_s > 0.0 && duration_s > 0.0 {
            self.lag_s / duration_s * (1.0 - left)
        } else {
            0.0
        };
        Decay { left, mean_left }
    }

    /// The command that brings the base from `speeds` to `target` in `dt_s` (held over
    /// `dt_s`, the inverse of [`Actuator::follow`]'s `end`): `s + (target - s) / (1 -
    /// exp(-dt / lag))`; the target itself without lag.
    pub fn command_reaching(&self, speeds: [f64; 2], target: [f64; 2], dt_s: f64) -> [f64; 2] {
        let gain = 1.0 / (1.0 - self.remaining(dt_s));
        std::array::from_fn(|i| speeds[i] + (target[i] - speeds[i]) * gain)
    }
}

/// How much of a speed step the lag leaves after a stretch of time (`exp(-t / lag)`), and
/// on average over it ([`Actuator::decay`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decay {
    left: f64,
    mean_left: f64,
}

impl Decay {
    /// The speeds at the end of the stretch with `command` in effect from `speeds`, and
    /// their mean over it.
    pub fn follow(&self, speeds: [f64; 2], command: [f64; 2]) -> Followed {
        let towards =
            |share: f64| std::array::from_fn(|i| command[i] + (speeds[i] - command[i]) * share);
        Followed {
            end: towards(self.left),
            mean: towards(self.mean_left),
        }
    }
}

/// The speeds at the end of a stretch of the lag, and their mean over it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Followed {
    pub end: [f64; 2],
    pub mean: [f64; 2],
}

/// The pose `[x_m, y_m, theta_rad]` after `duration_s` at the speeds `[u1, u2]`: the exact
/// circular arc ([`chord`]).
pub fn arc(pose: [f64; 3], speeds: [f64; 2], duration_s: f64) -> [f64; 3] {
    let [dx, dy] = chord(pose[2], speeds, duration_s);
    [pose[0] + dx, pose[1] + dy, pose[2] + speeds[1] * duration_s]
}

/// The displacement `[dx_m, dy_m]` over `duration_s` at the speeds `[u1, u2]` from heading
/// `theta_rad`: the chord of the circular arc, of length `u1 dt sinc(u2 dt / 2)`, along
/// the mid heading.
pub fn chord(theta_rad: f64, [u1, u2]: [f64; 2], duration_s: f64) -> [f64; 2] {
    let half_turn = 0.5 * u2 * duration_s;
    let sinc = if half_turn.abs() < 1e-9 {
        1.0
    } else {
        half_turn.sin() / half_turn
    };
    let length = u1 * duration_s * sinc;
    let (sin, cos) = (theta_rad + half_turn).sin_cos();
    [length * cos, length * sin]
}

/// A stretch of an inner tick with one command in effect: how long, s, and which.
pub type Piece = (f64, [f64; 2]);

/// The commands sent and not yet all in effect (the delay): with `delay = q dt + r`
/// (`0 <= r < dt`), during tick `j` (`[t_j, t_j + dt)`) the command of tick `j - q - 1` is
/// in effect for `r`, then that of tick `j - q`. Holds the last `q + 1` commands; it never
/// allocates after [`CommandLine::new`].
#[derive(Debug, Clone)]
pub struct CommandLine {
    dt_s: f64,
    /// `r`, s.
    rest_s: f64,
    /// Commands of ticks `j - q - 1 ..= j - 1`, oldest first, before tick `j` is sent.
    sent: VecDeque<[f64; 2]>,
}

impl CommandLine {
    /// The line of a base with `delay_s` driven every `dt_s`, which held `held` before the
    /// first command (the speeds it started with).
    pub fn new(delay_s: f64, dt_s: f64, held: [f64; 2]) -> CommandLine {
        let whole = Self::whole_ticks(delay_s, dt_s);
        let rest_s = (delay_s - whole as f64 * dt_s).clamp(0.0, dt_s);
        let mut sent = VecDeque::with_capacity(whole + 2);
        sent.extend(std::iter::repeat_n(held, whole + 1));
        CommandLine { dt_s, rest_s, sent }
    }

    /// The whole ticks `q` of a delay, rounded down (a delay within a nanosecond of a whole
    /// number of ticks counts as that number).
    pub fn whole_ticks(delay_s: f64, dt_s: f64) -> usize {
        if delay_s > 0.0 && dt_s > 0.0 {
            (delay_s / dt_s + 1e-9).floor() as usize
        } else {
            0
        }
    }

    /// How many ticks ahead the commands already sent decide (`q`).
    pub fn ticks_decided(&self) -> usize {
        self.sent.len() - 1
    }

    /// How long each of the two pieces of a tick lasts, s: `r`, then `dt - r`.
    pub fn durations(&self) -> [f64; 2] {
        [self.rest_s, self.dt_s - self.rest_s]
    }

    /// The pieces of tick `j + ahead` (`ahead < q`) from the commands already sent, before
    /// tick `j`'s.
    pub fn pieces_ahead(&self, ahead: usize) -> [Piece; 2] {
        let [rest, after] = self.durations();
        [(rest, self.sent[ahead]), (after, self.sent[ahead + 1])]
    }

    /// Sends the command of the tick that starts now; returns the pieces of this tick.
    pub fn send(&mut self, command: [f64; 2]) -> [Piece; 2] {
        self.sent.push_back(command);
        let pieces = self.pieces_ahead(0);
        self.sent.pop_front();
        pieces
    }
}

/// A model of a base: its commands in flight and its speeds, advanced one inner tick at a
/// time. The estimator and the DFL each keep one, driven by the commands.
#[derive(Debug, Clone)]
pub struct BaseModel {
    actuator: Actuator,
    line: CommandLine,
    /// The lag's decay over each of the two pieces of a tick ([`CommandLine::durations`]),
    /// computed once: every tick predicts over `q` ticks.
    decays: [Decay; 2],
    /// The base's speeds at the start of the coming tick.
    speeds: [f64; 2],
}

impl BaseModel {
    /// A base moving at `speeds` that was commanded them until now.
    pub fn new(actuator: Actuator, dt_s: f64, speeds: [f64; 2]) -> BaseModel {
        let line = CommandLine::new(actuator.delay_s, dt_s, speeds);
        BaseModel {
            actuator,
            decays: line
                .durations()
                .map(|duration_s| actuator.decay(duration_s)),
            line,
            speeds,
        }
    }

    /// The model of `actuator` for `scenario`'s robot, from its start (`robot.zeta0`,
    /// ticks of `timing.dt_s()`); `None` for a base that realizes each command at once.
    pub fn of(actuator: Actuator, scenario: &Scenario) -> Option<BaseModel> {
        let speeds = [scenario.robot.zeta0, 0.0];
        (!actuator.is_ideal()).then(|| BaseModel::new(actuator, scenario.timing.dt_s(), speeds))
    }

    /// The lag and the delay modelled.
    pub fn actuator(&self) -> Actuator {
        self.actuator
    }

    /// The base's speeds at the start of the coming tick.
    pub fn speeds(&self) -> [f64; 2] {
        self.speeds
    }

    /// How many ticks ahead the commands in flight decide.
    pub fn ticks_decided(&self) -> usize {
        self.line.ticks_decided()
    }

    /// Sends the command of the coming tick and advances over it; calls `each` with the
    /// duration and the mean speeds of each stretch of the tick.
    pub fn advance(&mut self, command: [f64; 2], mut each: impl FnMut(f64, [f64; 2])) {
        let pieces = self.line.send(command);
        self.speeds = self.through(self.speeds, pieces, &mut each);
    }

    /// The speeds `ahead` whole ticks from now (at most [`BaseModel::ticks_decided`]) under
    /// the commands already sent, calling `each` as [`BaseModel::advance`] does.
    pub fn predict(&self, ahead: usize, mut each: impl FnMut(f64, [f64; 2])) -> [f64; 2] {
        (0..ahead.min(self.ticks_decided())).fold(self.speeds, |speeds, tick| {
            self.through(speeds, self.line.pieces_ahead(tick), &mut each)
        })
    }

    /// The speeds after the two `pieces` of a tick from `speeds`; `each` is called with
    /// each piece's duration and mean speeds, unless it lasts no time.
    fn through(
        &self,
        mut speeds: [f64; 2],
        pieces: [Piece; 2],
        each: &mut impl FnMut(f64, [f64; 2]),
    ) -> [f64; 2] {
        for ((duration_s, command), decay) in pieces.into_iter().zip(&self.decays) {
            let followed = decay.follow(speeds, command);
            if duration_s > 0.0 {
                each(duration_s, followed.mean);
            }
            speeds = followed.end;
        }
        speeds
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_command_takes_effect_after_the_delay_split_within_its_tick() {
        // 12 ms at 5 ms ticks: two whole ticks and 2 ms.
        let mut line = CommandLine::new(0.012, 0.005, [0.0; 2]);
        assert_eq!(line.ticks_decided(), 2);
        let mut effects = Vec::new();
        for j in 1..=5 {
            effects.push(line.send([j as f64, 0.0]));
        }
        // Tick 3 (the third sent): command 0 for 2 ms (rest), then command 1.
        let [(first_s, first), (second_s, second)] = effects[2];
        assert!((first_s - 0.002).abs() < 1e-12 && (second_s - 0.003).abs() < 1e-12);
        assert_eq!((first[0], second[0]), (0.0, 1.0));
        assert_eq!((effects[4][0].1[0], effects[4][1].1[0]), (2.0, 3.0));
    }

    #[test]
    fn the_lag_follows_its_exact_solution_and_its_inverse_reaches_the_target() {
        let base = Actuator {
            lag_s: 0.05,
            delay_s: 0.0,
        };
        let followed = base.follow([0.0, 1.0], [1.0, 0.0], 0.05);
        let e = (-1.0f64).exp();
        assert!((followed.end[0] - (1.0 - e)).abs() < 1e-12);
        assert!((followed.end[1] - e).abs() < 1e-12);
        // The mean of 1 - exp(-t / lag) over one lag.
        assert!((followed.mean[0] - e).abs() < 1e-12, "{followed:?}");
        let command = base.command_reaching([0.2, -0.1], [0.5, 0.3], 0.005);
        let reached = base.follow([0.2, -0.1], command, 0.005).end;
        assert!((reached[0] - 0.5).abs() < 1e-12 && (reached[1] - 0.3).abs() < 1e-12);
        let ideal = Actuator::default();
        assert_eq!(
            ideal.command_reaching([0.2, 0.0], [0.5, 0.3], 0.005),
            [0.5, 0.3]
        );
        assert_eq!(ideal.follow([0.2, 0.0], [0.5, 0.3], 0.005).mean, [0.5, 0.3]);
    }

    #[test]
    fn prediction_over_the_commands_in_flight_is_what_advancing_would_do() {
        let actuator = Actuator {
            lag_s: 0.03,
            delay_s: 0.02,
        };
        let mut base = BaseModel::new(actuator, 0.005, [0.0; 2]);
        for j in 0..6 {
            base.advance([0.1 * j as f64, -0.2], |_, _| {});
        }
        let mut predicted_distance = 0.0;
        let predicted = base.predict(4, |s, mean| predicted_distance += s * mean[0]);
        let mut advanced_distance = 0.0;
        for _ in 0..4 {
            // Commands sent now take effect only after the 4 ticks predicted.
            base.advance([9.0, 9.0], |s, mean| advanced_distance += s * mean[0]);
        }
        assert!((predicted[0] - base.speeds()[0]).abs() < 1e-12);
        assert!((predicted_distance - advanced_distance).abs() < 1e-12);
    }
}
