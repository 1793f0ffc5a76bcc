//! The safety-critical linear MPC (the paper's problem of eqs. 51 to 47) on the
//! DFL-linearized model, solved as a sequence of convex conic programs with clarabel
//! ([`linear`]), and the nonlinear baseline it is compared with ([`nonlinear`]); [`MpcTask`]
//! is the role.
//!
//! Equations are cited by their labels in the paper's LaTeX source (`\label{eq:51}` is
//! eq. 51): the problem of eqs. 51 to 47 is the cost (51), the model (52), the state and
//! input constraints (53, 531), the CBF (54) and the terminal set (45-2, 47), in the
//! paper's order; the linear model is eq. mobile46-1.
//!
//! The crate by concern, each file importing only files listed above it (and `error`,
//! which names the layout's rows and the model's failures, only `layout` and `model`):
//! - [`error`]: why an MPC cannot be set up;
//! - [`model`]: the linear model (eq. mobile46-1, discretized), the DARE and the LQR gain;
//! - [`brake`]: the braking model shared with the DFL;
//! - [`layout`]: where each variable and row of the conic program sits;
//! - [`reach`]: where the states can be over the input box (which rows are implied);
//! - [`discs`]: the obstacles as the constraints see them;
//! - [`assembly`]: the program's matrices, row by row, sparse or condensed;
//! - [`terminal_set`]: the terminal set (eqs. 45-2, 47) about a sub-goal;
//! - [`terminal`]: the braking-safe terminal rows;
//! - [`program`]: every row of one step's program, in order;
//! - [`solver`]: clarabel, built once, values updated each step;
//! - [`follow`]: the reference along a route;
//! - [`linear`], [`nonlinear`]: the two MPCs; [`approach`]: the final approach's;
//!   [`task`]: the role.

pub mod approach;
pub mod assembly;
pub mod brake;
pub mod discs;
pub mod error;
pub mod follow;
pub mod give_way;
pub mod layout;
pub mod linear;
pub mod model;
pub mod nonlinear;
pub mod program;
pub mod reach;
pub mod solver;
pub mod task;
pub mod terminal;
pub mod terminal_set;

pub use linear::LinearMpc;
pub use task::MpcTask;

pub use error::MpcError;

use protocol::{Formulation, Plan, PlanStatus, Scenario};

/// The MPC role: the paper's linear scheme (with the MPC of its final approach,
/// [`approach`]), or the nonlinear baseline (`mpc.formulation`), which keeps the paper's
/// weights to the end.
pub enum Mpc {
    Linear(Box<LinearMpc>, Option<Box<approach::Approach>>),
    Nonlinear(Box<nonlinear::NonlinearMpc>),
}

impl Mpc {
    pub fn new(scenario: &Scenario) -> Result<Mpc, MpcError> {
        error::check_horizon(scenario.mpc.horizon)?;
        let without_obstacles;
        let scenario = if scenario.fault.mpc_ignore_obstacles {
            without_obstacles = Scenario {
                obstacles: Vec::new(),
                ..scenario.clone()
            };
            &without_obstacles
        } else {
            scenario
        };
        Ok(match scenario.mpc.formulation {
            Formulation::Linear => Mpc::Linear(
                Box::new(LinearMpc::new(scenario)?),
                approach::Approach::new(scenario)?.map(Box::new),
            ),
            Formulation::Nonlinear => Mpc::Nonlinear(Box::new(nonlinear::NonlinearMpc::new(
                scenario,
                &model::terminal_weight(scenario)?,
            ))),
        })
    }

    /// plan(k) from the estimate `x_bar = [x, y, theta, zeta]` and the standard deviation
    /// `position_sigma_m` of its position. The header is left for the caller to fill.
    pub fn step(&mut self, sample: u64, x_bar: [f64; 4], position_sigma_m: f64) -> Plan {
        self.step_on_route(sample, x_bar, position_sigma_m, None)
    }

    /// Takes the tracker's newest tracks ([`LinearMpc::set_tracks`]; the nonlinear
    /// baseline runs with obstacles at rest only).
    pub fn set_tracks(&mut self, tracks: &protocol::Tracks) {
        if let Mpc::Linear(m, approach) = self {
            m.set_tracks(tracks);
            if let Some(a) = approach {
                a.mpc.set_tracks(tracks);
            }
        }
    }

    /// Warms the next step's memory (a process idle since its last step finds its working
    /// set in cache at the next one): the linear scheme steps the next sample dry when
    /// its last step took at most `dry_step_max_ns` ([`LinearMpc::warm_up`]), else, like
    /// the nonlinear one, solves its last program again; every solve stops once `cancel`
    /// holds. Changes no plan.
    pub fn warm_up(&mut self, dry_step_max_ns: u64, cancel: &protocol::task::Cancel) {
        match self {
            Mpc::Linear(m, approach) => active(m, approach).warm_up(dry_step_max_ns, cancel),
            Mpc::Nonlinear(m) => m.warm_up(cancel),
        }
    }

    /// Notes how long the last step took, ns ([`LinearMpc::took`]).
    pub fn took(&mut self, step_ns: u64) {
        if let Mpc::Linear(m, approach) = self {
            active(m, approach).took(step_ns);
        }
    }

    /// Forgets the previous plan: the next step starts cold.
    pub fn reset(&mut self) {
        match self {
            Mpc::Linear(m, approach) => {
                m.reset();
                if let Some(a) = approach {
                    a.mpc.reset();
                }
            }
            Mpc::Nonlinear(m) => m.reset(),
        }
    }

    /// plan(k) as [`Mpc::step`], driving along `route` ([`LinearMpc::follow`]) instead of
    /// to the goal; without a route (none yet, or the planner off), to the goal. The
    /// nonlinear baseline always drives to the goal (the validator refuses it with a
    /// planner).
    pub fn step_on_route(
        &mut self,
        sample: u64,
        x_bar: [f64; 4],
        position_sigma_m: f64,
        route: Option<&protocol::Route>,
    ) -> Plan {
        match self {
            Mpc::Linear(m, approach) => {
                let position = [x_bar[0], x_bar[1]];
                if let Some(a) = approach
                    && a.update(position, route)
                {
                    // The MPC handed over to starts cold: its last plan is of another time.
                    a.mpc.reset();
                    m.reset();
                }
                let plan = {
                    let active = active(m, approach);
                    active.follow(route, position);
                    active.step(sample, x_bar, position_sigma_m)
                };
                if plan.is_solved() || !approach.as_ref().is_some_and(|a| a.on) {
                    return plan;
                }
                // The approach's program failed (its terminal set about the goal is out
                // of reach: a person drives the robot off it): the paper's weights plan.
                m.follow(route, position);
                m.step(sample, x_bar, position_sigma_m)
            }
            Mpc::Nonlinear(m) => m.step(sample, x_bar, position_sigma_m),
        }
    }

    /// Applies the scenario's injected faults to plan(k): a forced failure (reported as
    /// `numerical_error`, and the MPC starts cold next time, as after a real failure) and
    /// the delay to add before publishing.
    pub fn inject_faults(&mut self, plan: &mut Plan, faults: &protocol::FaultConfig) {
        if faults.mpc_fails(plan.sample) {
            plan.status = PlanStatus::NumericalError as u32;
            self.reset();
        }
        plan.injected_delay_ns = faults.mpc_delay_ns(plan.sample);
    }
}

/// The linear MPC that steps next: the final approach's while the robot is on it.
fn active<'a>(
    m: &'a mut LinearMpc,
    approach: &'a mut Option<Box<approach::Approach>>,
) -> &'a mut LinearMpc {
    match approach {
        Some(a) if a.on => &mut a.mpc,
        _ => m,
    }
}
