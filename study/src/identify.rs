//! `scmpc identify` (issue 60, docs/robot.md): the base's lag and command delay measured
//! from the robot itself. A short excitation (steps, then a chirp, in forward speed and
//! in turn rate) is sent open loop, one command per inner tick; the poses measured on
//! the way give, per channel, the distance driven along the heading and the heading turned;
//! the lag and the delay are the pair whose model ([`protocol::actuator`]) driven by the
//! same commands reproduces those two curves best in the least-squares sense.

use protocol::actuator::{Actuator, BaseModel};
use protocol::{Scenario, Validated, wrap_angle};

/// How hard and how far the excitation drives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Excitation {
    /// Forward speed of the steps and the chirp's amplitude, m/s.
    pub speed_m_s: f64,
    /// Turn rate of the steps and the chirp's amplitude, rad/s.
    pub turn_rad_s: f64,
}

impl Default for Excitation {
    fn default() -> Self {
        Excitation {
            speed_m_s: 0.3,
            turn_rad_s: 1.0,
        }
    }
}

/// Length of each step of the excitation, s, and of each chirp.
const STEP_S: f64 = 0.8;
const REST_S: f64 = 0.6;
const CHIRP_S: f64 = 4.0;
/// The chirps' frequency sweeps from this to [`CHIRP_TO_HZ`].
const CHIRP_FROM_HZ: f64 = 0.2;
const CHIRP_TO_HZ: f64 = 3.0;
/// Room kept beyond the excitation's own reach, m: the lag and the delay move the robot
/// by less than this beyond where an ideal base would go.
pub const ROOM_MARGIN_M: f64 = 0.2;

impl Excitation {
    /// The commands `[u1, u2]`, one per inner tick of `dt_s`: forward steps (+, rest, -,
    /// rest), turn steps in place, then a forward chirp and a turn chirp, each from
    /// [`CHIRP_FROM_HZ`] to [`CHIRP_TO_HZ`], and a rest.
    pub fn commands(&self, dt_s: f64) -> Vec<[f64; 2]> {
        let (v, w) = (self.speed_m_s, self.turn_rad_s);
        let mut commands = Vec::new();
        let mut hold = |command: [f64; 2], seconds: f64| {
            commands.extend(std::iter::repeat_n(
                command,
                (seconds / dt_s).round() as usize,
            ));
        };
        for command in [[v, 0.0], [0.0, 0.0], [-v, 0.0], [0.0, 0.0]] {
            hold(command, if command == [0.0; 2] { REST_S } else { STEP_S });
        }
        for command in [[0.0, w], [0.0, 0.0], [0.0, -w], [0.0, 0.0]] {
            hold(command, if command == [0.0; 2] { REST_S } else { STEP_S });
        }
        let ticks = (CHIRP_S / dt_s).round() as usize;
        let chirp = |j: usize| {
            let t = j as f64 * dt_s;
            let rate = (CHIRP_TO_HZ - CHIRP_FROM_HZ) / CHIRP_S;
            (std::f64::consts::TAU * (CHIRP_FROM_HZ * t + 0.5 * rate * t * t)).sin()
        };
        commands.extend((0..ticks).map(|j| [v * chirp(j), 0.0]));
        commands.extend((0..ticks).map(|j| [0.0, w * chirp(j)]));
        commands.extend(std::iter::repeat_n(
            [0.0; 2],
            (REST_S / dt_s).round() as usize,
        ));
        commands
    }

    /// How long the excitation lasts, s.
    pub fn duration_s(&self, dt_s: f64) -> f64 {
        self.commands(dt_s).len() as f64 * dt_s
    }

    /// The farthest an ideal base driven by [`Excitation::commands`] gets from where it
    /// starts, m.
    pub fn reach_m(&self, dt_s: f64) -> f64 {
        let mut pose = [0.0; 3];
        let mut farthest: f64 = 0.0;
        for command in self.commands(dt_s) {
            pose = protocol::actuator::arc(pose, command, dt_s);
            farthest = farthest.max(pose[0].hypot(pose[1]));
        }
        farthest
    }
}

/// Why the excitation was not driven.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RoomError {
    #[error(
        "the excitation reaches {reach_m:.2} m from the start, more than the {within_m} m \
         allowed (--within); lower --speed or allow more room"
    )]
    TooFar { reach_m: f64, within_m: f64 },
    #[error(
        "the excitation reaches {reach_m:.2} m (and {margin_m} m of room) from the start \
         {start:?}, beyond mpc.position_min/position_max"
    )]
    OutOfTheBox {
        reach_m: f64,
        margin_m: f64,
        start: [f64; 2],
    },
    #[error(
        "obstacles.{index} is {clearance_m:.2} m from the start's edge, and the excitation \
         needs {needed_m:.2} m of room: start elsewhere or lower --speed"
    )]
    NearObstacle {
        index: usize,
        clearance_m: f64,
        needed_m: f64,
    },
}

/// Whether the robot of `scenario` at its start has room for an excitation that reaches
/// `reach_m` (no farther than `within_m`) and lasts `duration_s`: with [`ROOM_MARGIN_M`]
/// more, inside the position box and clear of every known obstacle (grown by the robot's
/// radius) wherever it is meanwhile.
pub fn check_room(
    scenario: &Scenario,
    reach_m: f64,
    within_m: f64,
    duration_s: f64,
) -> Result<(), RoomError> {
    if reach_m > within_m {
        return Err(RoomError::TooFar { reach_m, within_m });
    }
    let needed_m = reach_m + ROOM_MARGIN_M;
    let start = [scenario.robot.start[0], scenario.robot.start[1]];
    let (low, high) = (scenario.mpc.position_min, scenario.mpc.position_max);
    if (0..2).any(|i| start[i] - needed_m < low[i] || start[i] + needed_m > high[i]) {
        return Err(RoomError::OutOfTheBox {
            reach_m,
            margin_m: ROOM_MARGIN_M,
            start,
        });
    }
    for (index, obstacle) in scenario.obstacles.iter().enumerate() {
        if !obstacle.is_known() {
            continue;
        }
        // Every 0.1 s of the excitation, for one that moves.
        let times = (0..=(duration_s / 0.1).ceil() as usize).map(|i| i as f64 * 0.1);
        let nearest_m = (times.map(|t| protocol::distance(obstacle.center_at(t), start)))
            .fold(f64::INFINITY, f64::min);
        let clearance_m = nearest_m - obstacle.radius - scenario.robot.radius_m;
        if clearance_m < needed_m {
            return Err(RoomError::NearObstacle {
                index,
                clearance_m,
                needed_m,
            });
        }
    }
    Ok(())
}

/// Why what was measured gives no lag and delay.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    #[error(
        "{poses} poses in {seconds:.1} s of excitation, fewer than one each {MOST_POSE_GAP_S} s: \
         the odometry stopped or came too slowly"
    )]
    TooFewPoses { poses: usize, seconds: f64 },
    #[error(
        "the {channel} did not follow the excitation (lag {lag_s:.3} s, delay {delay_s:.3} s, \
         at or beyond what is searched: {MOST_LAG_S} s, {MOST_DELAY_S} s): is the robot \
         driven by these commands, and free to move?"
    )]
    NoResponse {
        channel: &'static str,
        lag_s: f64,
        delay_s: f64,
    },
}

/// The longest a fit takes between two poses on average, s.
pub const MOST_POSE_GAP_S: f64 = 0.1;

/// One channel's lag and delay as fitted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelFit {
    pub lag_s: f64,
    pub delay_s: f64,
    /// Standard errors of both, s, from the fit's residual and its sensitivity to each
    /// (`sigma^2 (J'J)^-1`, the residuals taken as independent: they are not quite, so
    /// read these as a lower bound).
    pub lag_sigma_s: f64,
    pub delay_sigma_s: f64,
    /// Root mean square of the residual: m (forward) or rad (turn).
    pub rms: f64,
}

/// Both channels' fits, and how many poses they were fitted to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Identified {
    pub forward: ChannelFit,
    pub turn: ChannelFit,
    pub poses: usize,
}

impl Identified {
    /// The one lag and delay the scenario's model takes (it has one for both channels):
    /// each the mean of the two channels', weighted by their inverse variances.
    pub fn model(&self) -> Actuator {
        let weighted = |a: f64, sa: f64, b: f64, sb: f64| {
            let (wa, wb) = (1.0 / sa.max(1e-6).powi(2), 1.0 / sb.max(1e-6).powi(2));
            (a * wa + b * wb) / (wa + wb)
        };
        let (f, t) = (self.forward, self.turn);
        Actuator {
            lag_s: weighted(f.lag_s, f.lag_sigma_s, t.lag_s, t.lag_sigma_s),
            delay_s: weighted(f.delay_s, f.delay_sigma_s, t.delay_s, t.delay_sigma_s),
        }
    }

    /// The scenario keys to paste, with what each channel measured as comments.
    pub fn as_toml(&self) -> String {
        let model = self.model();
        let channel = |name: &str, unit: &str, c: ChannelFit| {
            format!(
                "# {name}: lag {:.4} ± {:.4} s, delay {:.4} ± {:.4} s, residual {:.2e} {unit} rms\n",
                c.lag_s, c.lag_sigma_s, c.delay_s, c.delay_sigma_s, c.rms
            )
        };
        format!(
            "# scmpc identify: fitted to {} poses\n{}{}[robot]\nactuator_lag_s = {:.4}\ncommand_delay_s = {:.4}\n",
            self.poses,
            channel("forward speed", "m", self.forward),
            channel("turn rate", "rad", self.turn),
            model.lag_s,
            model.delay_s
        )
    }
}

/// The distance driven along the heading and the heading turned (unwrapped) from the
/// first pose to each, measured from consecutive poses `[x, y, theta]`.
pub fn travelled(poses: &[[f64; 3]]) -> [Vec<f64>; 2] {
    let mut along = vec![0.0];
    let mut turned = vec![0.0];
    for pair in poses.windows(2) {
        let [a, b] = [pair[0], pair[1]];
        let turn = wrap_angle(b[2] - a[2]);
        let (sin, cos) = (a[2] + 0.5 * turn).sin_cos();
        let step = (b[0] - a[0]) * cos + (b[1] - a[1]) * sin;
        along.push(along[along.len() - 1] + step);
        turned.push(turned[turned.len() - 1] + turn);
    }
    [along, turned]
}

/// What a base with `actuator` driven by `commands` (one per tick of `dt_s`, from rest,
/// the first sent at time 0) has driven and turned at each of `times` (s; nothing before
/// 0, held after the last tick): exact at the ticks, linear in between.
pub fn modelled(
    actuator: Actuator,
    commands: &[[f64; 2]],
    dt_s: f64,
    times: &[f64],
) -> [Vec<f64>; 2] {
    let mut base = BaseModel::new(actuator, dt_s, [0.0; 2]);
    let mut at_ticks = vec![[0.0; 2]];
    let mut at = [0.0; 2];
    for &command in commands {
        base.advance(command, |duration_s, mean| {
            at[0] += mean[0] * duration_s;
            at[1] += mean[1] * duration_s;
        });
        at_ticks.push(at);
    }
    let last = at_ticks.len() - 1;
    let interpolated = |t: f64, c: usize| {
        let ticks = (t / dt_s).clamp(0.0, last as f64);
        let j = (ticks.floor() as usize).min(last.saturating_sub(1));
        let share = ticks - j as f64;
        at_ticks[j][c] + share * (at_ticks[(j + 1).min(last)][c] - at_ticks[j][c])
    };
    std::array::from_fn(|c| times.iter().map(|&t| interpolated(t, c)).collect())
}

/// What the robot was measured to do: the times of its poses (s from the first command)
/// and what it had driven and turned by each ([`travelled`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    pub times: Vec<f64>,
    pub travelled: [Vec<f64>; 2],
}

impl Measured {
    /// Poses `[x, y, theta]` at `times` (the first before any command took effect).
    pub fn of(times: Vec<f64>, poses: &[[f64; 3]]) -> Measured {
        Measured {
            times,
            travelled: travelled(poses),
        }
    }
}

/// Largest lag and delay searched, s.
const MOST_LAG_S: f64 = 0.5;
const MOST_DELAY_S: f64 = 0.3;

/// Fits each channel's lag and delay to what was `measured` for `commands` (one per tick
/// of `dt_s`): a grid over both, then a finer grid around each channel's best.
pub fn fit(commands: &[[f64; 2]], dt_s: f64, measured: &Measured) -> [ChannelFit; 2] {
    let cost = |actuator: Actuator| -> [f64; 2] {
        let model = modelled(actuator, commands, dt_s, &measured.times);
        std::array::from_fn(|c| {
            (model[c].iter().zip(&measured.travelled[c]))
                .map(|(m, y)| (m - y).powi(2))
                .sum()
        })
    };
    let grid = |lags: &[f64], delays: &[f64], best: &mut [(f64, Actuator); 2]| {
        for &lag_s in lags {
            for &delay_s in delays {
                let actuator = Actuator { lag_s, delay_s };
                for (c, sum) in cost(actuator).into_iter().enumerate() {
                    if sum < best[c].0 {
                        best[c] = (sum, actuator);
                    }
                }
            }
        }
    };
    let steps = |from: f64, to: f64, step: f64| -> Vec<f64> {
        let n = ((to - from) / step).round() as usize;
        (0..=n).map(|i| (from + i as f64 * step).max(0.0)).collect()
    };
    let mut best = [(f64::INFINITY, Actuator::default()); 2];
    grid(
        &steps(0.0, MOST_LAG_S, 0.01),
        &steps(0.0, MOST_DELAY_S, 0.005),
        &mut best,
    );
    std::array::from_fn(|c| {
        let coarse = best[c].1;
        let mut fine = [best[c]; 2];
        grid(
            &steps(coarse.lag_s - 0.01, coarse.lag_s + 0.01, 0.0004),
            &steps(coarse.delay_s - 0.005, coarse.delay_s + 0.005, 0.0002),
            &mut fine,
        );
        let (sum, actuator) = fine[c];
        confidence(actuator, sum, commands, dt_s, &measured.times, c)
    })
}

/// The fit of channel `c` at `actuator`, with residual sum of squares `sum` over the
/// poses at `times`, with its standard errors from a finite-difference Jacobian.
fn confidence(
    actuator: Actuator,
    sum: f64,
    commands: &[[f64; 2]],
    dt_s: f64,
    times: &[f64],
    c: usize,
) -> ChannelFit {
    let h = 1e-4;
    let at =
        |lag_s: f64, delay_s: f64| modelled(Actuator { lag_s, delay_s }, commands, dt_s, times);
    let (lag, delay) = (actuator.lag_s, actuator.delay_s);
    // Central differences, one-sided at zero: neither goes below it.
    let derivative = |plus: [Vec<f64>; 2], minus: [Vec<f64>; 2], step: f64| -> Vec<f64> {
        (plus[c].iter().zip(&minus[c]))
            .map(|(p, m)| (p - m) / step)
            .collect()
    };
    let below = |x: f64| (x - h).max(0.0);
    let d_lag = derivative(
        at(lag + h, delay),
        at(below(lag), delay),
        lag + h - below(lag),
    );
    let d_delay = derivative(
        at(lag, delay + h),
        at(lag, below(delay)),
        delay + h - below(delay),
    );
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let (a, b, d) = (
        dot(&d_lag, &d_lag),
        dot(&d_lag, &d_delay),
        dot(&d_delay, &d_delay),
    );
    let n = times.len();
    let variance = sum / (n.saturating_sub(2).max(1)) as f64;
    let determinant = a * d - b * b;
    let (lag_sigma_s, delay_sigma_s) = if determinant > 0.0 {
        (
            (variance * d / determinant).sqrt(),
            (variance * a / determinant).sqrt(),
        )
    } else {
        (f64::INFINITY, f64::INFINITY)
    };
    ChannelFit {
        lag_s: lag,
        delay_s: delay,
        lag_sigma_s,
        delay_sigma_s,
        rms: (sum / n.max(1) as f64).sqrt(),
    }
}

/// Drives the excitation on the simulated plant of `scenario` (its lag and delay:
/// `plant.actuator_lag_s`, `plant.command_delay_s`, its noise and its wheels), from its
/// start at rest, and fits what it measured at every tick.
pub fn identify_simulated(
    scenario: &Validated,
    excitation: Excitation,
) -> Result<Identified, FitError> {
    let dt_s = scenario.timing.dt_s();
    let commands = excitation.commands(dt_s);
    let mut at_rest = (**scenario).clone();
    at_rest.robot.zeta0 = 0.0;
    let mut plant = plant::Plant::new(&at_rest);
    let mut poses = Vec::with_capacity(commands.len() + 1);
    poses.push(plant.measure());
    let mut applied = Vec::with_capacity(commands.len());
    for &[u1, u2] in &commands {
        applied.push(plant.step(u1, u2, dt_s));
        poses.push(plant.measure());
    }
    let times = (0..poses.len()).map(|j| j as f64 * dt_s).collect();
    fitted(&applied, dt_s, &Measured::of(times, &poses))
}

/// Both channels fitted, or why they say nothing: too few poses, or a fit at the edge of
/// the search (a robot that did not move).
fn fitted(commands: &[[f64; 2]], dt_s: f64, measured: &Measured) -> Result<Identified, FitError> {
    let (poses, seconds) = (measured.times.len(), commands.len() as f64 * dt_s);
    if (poses as f64) < seconds / MOST_POSE_GAP_S {
        return Err(FitError::TooFewPoses { poses, seconds });
    }
    let [forward, turn] = fit(commands, dt_s, measured);
    for (channel, c) in [("forward speed", forward), ("turn rate", turn)] {
        let inside = c.lag_s < MOST_LAG_S && c.delay_s < MOST_DELAY_S;
        if !(inside && c.lag_sigma_s.is_finite() && c.delay_sigma_s.is_finite()) {
            return Err(FitError::NoResponse {
                channel,
                lag_s: c.lag_s,
                delay_s: c.delay_s,
            });
        }
    }
    Ok(Identified {
        forward,
        turn,
        poses,
    })
}

/// How long the robot's odometry is watched at rest after the excitation, s: the lag and
/// the delay it ends with.
const SETTLE_S: f64 = 0.5;

/// Drives the excitation on the ROS 2 robot of `scenario` (`plant.kind = "ros2"`): from
/// where its first odometry puts it (which must have room, `within_m`), one command per
/// inner tick on `cmd_vel` in real time, its odometry taken as its stamps say it was
/// measured (this host's clock: its arrival less its age). A zero twist ends it, whatever
/// happens.
pub fn identify_ros2(
    scenario: &Validated,
    excitation: Excitation,
    within_m: f64,
    stop: &std::sync::atomic::AtomicBool,
) -> anyhow::Result<Identified> {
    use anyhow::Context;
    let mut link = robot::Link::open(&scenario.ros2, &net::Security::from_env(), false)?;
    let first = link.first_odometry(stop)?;
    let mut from_there = (**scenario).clone();
    from_there.robot.start = first.pose;
    let dt_s = scenario.timing.dt_s();
    let (reach_m, duration_s) = (excitation.reach_m(dt_s), excitation.duration_s(dt_s));
    let driven = check_room(&from_there, reach_m, within_m, duration_s)
        .context("the robot's first odometry")
        .and_then(|()| excite(&mut link, excitation, dt_s, stop));
    let stopped = link.stop_and_close();
    let (commands, measured) = driven?;
    stopped?;
    Ok(fitted(&commands, dt_s, &measured)?)
}

/// Sends the excitation's commands through `link` every `dt_s` and keeps each new
/// odometry, then watches the robot at rest for [`SETTLE_S`].
fn excite(
    link: &mut robot::Link,
    excitation: Excitation,
    dt_s: f64,
    stop: &std::sync::atomic::AtomicBool,
) -> anyhow::Result<(Vec<[f64; 2]>, Measured)> {
    let commands = excitation.commands(dt_s);
    let settle = (SETTLE_S / dt_s).round() as usize;
    let start_ns = runtime::clock::monotonic_ns();
    let measured_s = |heard: &robot::Heard| {
        (heard.arrived_ns.saturating_sub(heard.age_at_arrival_ns) as f64 - start_ns as f64) / 1e9
    };
    let first = (link.newest_odometry()).ok_or_else(|| anyhow::anyhow!("no odometry"))?;
    let (mut times, mut poses) = (vec![measured_s(&first).min(0.0)], vec![first.pose]);
    let mut newest = first.arrived_ns;
    for j in 0..commands.len() + settle {
        if stop.load(std::sync::atomic::Ordering::Relaxed) {
            anyhow::bail!("stopped");
        }
        let due_ns = start_ns + (j as f64 * dt_s * 1e9) as u64;
        let now_ns = runtime::clock::monotonic_ns();
        if due_ns > now_ns {
            std::thread::sleep(std::time::Duration::from_nanos(due_ns - now_ns));
        }
        let [u1, u2] = commands.get(j).copied().unwrap_or([0.0; 2]);
        link.command(u1, u2)?;
        if let Some(heard) = link.newest_odometry().filter(|h| h.arrived_ns != newest) {
            newest = heard.arrived_ns;
            times.push(measured_s(&heard));
            poses.push(heard.pose);
        }
    }
    let mut sent = commands;
    sent.resize(sent.len() + settle, [0.0; 2]);
    Ok((sent, Measured::of(times, &poses)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fit_recovers_the_lag_and_the_delay_of_the_model_itself() {
        let dt = 0.005;
        let commands = Excitation::default().commands(dt);
        let truth = Actuator {
            lag_s: 0.073,
            delay_s: 0.031,
        };
        let times: Vec<f64> = (0..=commands.len()).map(|j| j as f64 * dt).collect();
        let travelled = modelled(truth, &commands, dt, &times);
        let [forward, turn] = fit(&commands, dt, &Measured { times, travelled });
        for channel in [forward, turn] {
            assert!((channel.lag_s - 0.073).abs() < 5e-4, "{channel:?}");
            assert!((channel.delay_s - 0.031).abs() < 3e-4, "{channel:?}");
            assert!(channel.rms < 1e-4, "{channel:?}");
        }
    }

    #[test]
    fn a_robot_that_does_not_move_or_whose_odometry_stops_gives_no_fit() {
        let dt = 0.005;
        let commands = Excitation::default().commands(dt);
        let times: Vec<f64> = (0..=commands.len()).map(|j| j as f64 * dt).collect();
        let n = times.len();
        let still = Measured {
            times: times.clone(),
            travelled: [vec![0.0; n], vec![0.0; n]],
        };
        assert!(matches!(
            fitted(&commands, dt, &still),
            Err(FitError::NoResponse { .. })
        ));
        let few = Measured {
            times: times[..10].to_vec(),
            travelled: [vec![0.0; 10], vec![0.0; 10]],
        };
        assert!(matches!(
            fitted(&commands, dt, &few),
            Err(FitError::TooFewPoses { poses: 10, .. })
        ));
    }

    #[test]
    fn the_excitation_is_refused_where_it_would_leave_the_box_or_come_near_an_obstacle() {
        let mut s = Scenario::default();
        let reach = Excitation::default().reach_m(s.timing.dt_s());
        assert!(reach > 0.1 && reach < 1.0, "reach {reach}");
        s.robot.start = [0.0, 0.0, 0.0];
        s.obstacles.clear();
        assert_eq!(check_room(&s, reach, 1.0, 15.0), Ok(()));
        assert!(matches!(
            check_room(&s, reach, 0.05, 15.0),
            Err(RoomError::TooFar { .. })
        ));
        s.robot.start = [9.8, 0.0, 0.0];
        assert!(matches!(
            check_room(&s, reach, 1.0, 15.0),
            Err(RoomError::OutOfTheBox { .. })
        ));
        s.robot.start = [0.0, 0.0, 0.0];
        s.obstacles = vec![protocol::Obstacle::fixed(0.8, 0.0, 0.5)];
        assert!(matches!(
            check_room(&s, reach, 1.0, 15.0),
            Err(RoomError::NearObstacle { index: 0, .. })
        ));
    }
}
