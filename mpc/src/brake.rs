//! The braking model the MPC shares with the DFL's brake and check (docs/safety.md):
//! how far the brake takes the robot, and what the braking-safe terminal rows add to the
//! program (their variables, rows and cones; the rows are written by
//! [`crate::terminal::TerminalRows`]).

use clarabel::solver::SupportedConeT;

/// How the last state's stopping path is kept off the discs (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BrakeForm {
    /// The stopping segment stays in a half-plane: no standoff when passing a disc.
    Segment,
    /// The ball of radius the stopping distance stays outside: a standoff of `S`.
    Ball,
}

/// The braking model of the terminal rows, at the MPC's sample level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerminalBrake {
    /// The brake's deceleration `a`, m/s^2 (at most `v_max`, assumption (b)).
    pub decel: f64,
    pub ts_s: f64,
    pub form: BrakeForm,
    /// How long the stop must stay out of a moving obstacle's way once the robot is at
    /// rest, s (`mpc.rest_lookahead_s`, [`crate::terminal::TerminalRows`]).
    pub rest_lookahead_s: f64,
    /// Whether the rows can sweep a moving disc over the plan's own stop (one that stands
    /// still, a phantom, every disc of the escape plan; [`crate::terminal`]): two more
    /// variables, `tau >= |w_N|` and `sigma >= (Ts + tau / a)^2`, each with an SOC(3).
    /// Only a scenario that tracks obstacles has discs that move.
    pub sweeps: bool,
}

impl TerminalBrake {
    /// `S(s) = s^2 / (2 a) + Ts s / 2`, m: convex in the velocity, at least the distance the
    /// DFL's brake covers ([`protocol::stopping_distance`] with a hold of at most `Ts`) and
    /// the distance the MPC's braking samples cover ([`TerminalBrake::step`]), and it drops
    /// by at least the length of each braking sample (module docs).
    pub fn stop_distance_bound(&self, speed_m_s: f64) -> f64 {
        let s = speed_m_s.abs();
        s * s / (2.0 * self.decel) + 0.5 * self.ts_s * s
    }

    /// The input of one braking sample from velocity `w`: `-min(a, |w| / Ts) w / |w|`, so a
    /// robot slower than `a Ts` stops exactly at the end of the sample.
    pub fn input(&self, w: [f64; 2]) -> [f64; 2] {
        let speed = w[0].hypot(w[1]);
        if speed == 0.0 {
            return [0.0; 2];
        }
        let decel = self.decel.min(speed / self.ts_s);
        [-decel * w[0] / speed, -decel * w[1] / speed]
    }

    /// The state `z = [x, xdot, y, ydot]` one braking sample later (eq. 52 with
    /// [`TerminalBrake::input`]).
    pub fn step(&self, z: [f64; 4]) -> [f64; 4] {
        let v = self.input([z[1], z[3]]);
        let t = self.ts_s;
        [
            z[0] + z[1] * t + 0.5 * v[0] * t * t,
            z[1] + v[0] * t,
            z[2] + z[3] * t + 0.5 * v[1] * t * t,
            z[3] + v[1] * t,
        ]
    }

    /// Variables of the rows for `discs` discs, in column order: ball `tau`, then `sigma`
    /// with [`TerminalBrake::sweeps`]; segment one `e` per disc, then `tau` and `sigma`
    /// with [`TerminalBrake::sweeps`].
    pub fn variables(&self, discs: usize) -> usize {
        let sweep = usize::from(self.sweeps);
        match (discs, self.form) {
            (0, _) => 0,
            (_, BrakeForm::Ball) => 1 + sweep,
            (_, BrakeForm::Segment) => discs + 2 * sweep,
        }
    }

    /// Rows of the nonnegative cone: `e >= alpha` and `e >= 0` per disc (segment).
    pub fn nonnegative_rows(&self, discs: usize) -> usize {
        match self.form {
            BrakeForm::Ball => 0,
            BrakeForm::Segment => 2 * discs,
        }
    }

    /// Appends the rows' cones (after the CBF's).
    pub fn cones(&self, discs: usize, cones: &mut Vec<SupportedConeT<f64>>) {
        if discs == 0 {
            return;
        }
        let tau = self.form == BrakeForm::Ball || self.sweeps;
        let sigma = self.sweeps;
        for _ in 0..usize::from(tau) + usize::from(sigma) {
            cones.push(SupportedConeT::SecondOrderConeT(3));
        }
        let size = match self.form {
            BrakeForm::Ball => 4,
            BrakeForm::Segment => 5,
        };
        cones.extend((0..discs).map(|_| SupportedConeT::SecondOrderConeT(size)));
    }
}

impl TerminalBrake {
    /// The terminal rows of `mpc.terminal_safety`, if any, with the scenario's one braking
    /// model (`dfl.brake_decel`).
    pub fn of(scenario: &protocol::Scenario) -> Option<TerminalBrake> {
        let form = match scenario.mpc.terminal_safety {
            protocol::TerminalSafety::Brake => BrakeForm::Segment,
            protocol::TerminalSafety::BrakeBall => BrakeForm::Ball,
            protocol::TerminalSafety::None => return None,
        };
        Some(TerminalBrake {
            decel: scenario.brake_decel(),
            ts_s: scenario.timing.ts_s,
            form,
            rest_lookahead_s: scenario.mpc.rest_lookahead_s,
            sweeps: scenario.takes_tracks(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brake(form: BrakeForm) -> TerminalBrake {
        TerminalBrake {
            decel: 3.0,
            ts_s: 0.05,
            form,
            rest_lookahead_s: 0.0,
            sweeps: false,
        }
    }

    #[test]
    fn one_braking_sample_moves_no_farther_than_the_stopping_bound_drops() {
        let b = brake(BrakeForm::Segment);
        for k in 0..=400 {
            let speed = 0.01 * f64::from(k);
            let z = [0.0, speed * 0.6, 0.0, speed * 0.8];
            let next = b.step(z);
            let moved = next[0].hypot(next[2]);
            let speed_after = next[1].hypot(next[3]);
            let drop = b.stop_distance_bound(speed) - b.stop_distance_bound(speed_after);
            assert!(
                moved <= drop + 1e-12,
                "speed {speed}: moved {moved}, bound dropped {drop}"
            );
            // The input is within |v| <= a per axis and brakes along the velocity.
            let v = b.input([z[1], z[3]]);
            assert!(v[0].abs() <= 3.0 && v[1].abs() <= 3.0);
            // A robot slower than a Ts = 0.15 m/s stops within the sample.
            assert!(speed_after <= speed && (speed_after < 1e-12 || speed >= 0.15 - 1e-12));
        }
    }

    #[test]
    fn the_stopping_bound_covers_the_dfls_brake() {
        let b = brake(BrakeForm::Segment);
        for k in 0..=300 {
            let speed = 0.01 * f64::from(k);
            for hold in [0.005, 0.01, 0.05] {
                assert!(
                    protocol::stopping_distance(speed, 3.0, hold)
                        <= b.stop_distance_bound(speed) + 1e-15
                );
            }
        }
    }
}
