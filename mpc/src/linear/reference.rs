//! The references each program is linearized about: the previous plan shifted, a brake
//! from the estimate, and each solution in turn (sequential convex programming).

use super::LinearMpc;
use nalgebra::Vector4;

impl LinearMpc {
    /// The previous plan shifted by one sample and extended by one step: the candidate of
    /// the feasibility argument. The step is the LQR closed loop's (the paper's), or with
    /// terminal safety one braking sample ([`crate::brake::TerminalBrake::step`], recursive feasibility
    /// below). False when there is no plan of the previous sample.
    pub(super) fn shifted_reference(&mut self, sample: u64) -> bool {
        if self.last_sample.is_none_or(|last| sample != last + 1) {
            return false;
        }
        let z = &self.last_z;
        let n = self.layout.horizon;
        for i in 1..n {
            self.reference[i] = [z[i + 1][0], z[i + 1][2]];
        }
        let next = self.extension(z[n]);
        self.reference[n] = [next[0], next[2]];
        self.reference_velocity = [next[1], next[3]];
        true
    }

    /// The state one sample after the last state `z_n` of a plan, in its shifted
    /// successor: braking with terminal safety, the LQR closed loop without.
    fn extension(&self, z_n: [f64; 4]) -> [f64; 4] {
        match &self.layout.terminal {
            Some(brake) => brake.step(z_n),
            None => {
                let next = (self.statics.a + self.statics.b * self.statics.k) * Vector4::from(z_n);
                [next[0], next[1], next[2], next[3]]
            }
        }
    }

    /// Positions of the state braking from `z0` (held at rest): along its velocity at the
    /// brake's deceleration with terminal safety (so the rollout is braking-safe whenever
    /// the DFL's brake is), else each axis at the input limit.
    pub(super) fn braking_reference(&mut self, z0: [f64; 4]) {
        let (ts, v_max) = (self.ts_s, self.statics.v_max);
        let mut z = z0;
        for i in 1..=self.layout.horizon {
            match &self.layout.terminal {
                Some(brake) => z = brake.step(z),
                None => {
                    for (p, vel) in [(0, 1), (2, 3)] {
                        let acc = (-z[vel] / ts).clamp(-v_max, v_max);
                        z[p] += z[vel] * ts + 0.5 * acc * ts * ts;
                        z[vel] += acc * ts;
                    }
                }
            }
            self.reference[i] = [z[0], z[2]];
        }
        self.reference_velocity = [z[1], z[3]];
    }

    /// Moves the reference to the current solution; returns the largest move, m.
    pub(super) fn relinearize(&mut self) -> f64 {
        let (x, l) = (&self.solution, &self.layout);
        let mut moved: f64 = 0.0;
        for i in 1..=l.horizon {
            let p = [x[l.z(i, 0)], x[l.z(i, 2)]];
            moved = moved.max((p[0] - self.reference[i][0]).hypot(p[1] - self.reference[i][1]));
            self.reference[i] = p;
        }
        self.reference_velocity = [x[l.z(l.horizon, 1)], x[l.z(l.horizon, 3)]];
        moved
    }
}
