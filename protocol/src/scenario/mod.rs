//! The scenario schema: everything a run is configured with, one validator, and the
//! dotted-key overrides of `--set`.
//!
//! Every key has a default, and the defaults are the paper's canonical scenario
//! (docs/running.md, "Scenario keys"): a file only has to name what it changes. Unknown keys are
//! refused everywhere (`deny_unknown_fields`), so a typo never silently falls back to a
//! default.

use serde::{Deserialize, Serialize};
use std::fmt;

use crate::messages::MAX_HORIZON;

/// Largest constraint-checking horizon `Nc` accepted (terminal rows grow linearly in it).
pub const MAX_CONSTRAINT_HORIZON: usize = 200;
/// Largest number of inner (DFL and plant) ticks per MPC sample.
pub const MAX_INNER_STEPS: usize = 1000;
/// Largest number of RK4 substeps per inner tick.
pub const MAX_RK4_SUBSTEPS: usize = 1000;

/// A scenario [`Scenario::validate`] has accepted: the only kind a run, a sweep, a figure,
/// a role process or the in-process loop takes, so validation cannot be skipped. It reads
/// as a [`Scenario`] (`Deref`); a changed copy is validated again
/// ([`Validated::with_overrides`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Validated(Scenario);

impl std::ops::Deref for Validated {
    type Target = Scenario;
    fn deref(&self) -> &Scenario {
        &self.0
    }
}

impl Validated {
    /// A copy with `KEY=VALUE` overrides ([`Scenario::with_overrides`]), validated;
    /// `origin` names it in errors.
    pub fn with_overrides(
        &self,
        overrides: &[String],
        origin: &str,
    ) -> Result<Validated, ScenarioErrors> {
        self.0
            .with_overrides_from(overrides, origin)?
            .validated(origin)
    }

    /// The scenario, to change it (it must be validated again to run).
    pub fn into_inner(self) -> Scenario {
        self.0
    }
}

/// The most discs of a lidar's tracks and phantoms the MPC keeps clear of at once: the
/// nearest to the robot (its program is built for every number of discs up to its most;
/// the DFL's check takes every track).
pub const MAX_SEEN_DISCS: usize = 8;

/// A whole run's configuration. Defaults reproduce the paper's scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Scenario {
    /// Free-form name, copied into the summary.
    pub name: String,
    /// Seed of every random generator of the run (output noise, disturbance).
    pub seed: u64,
    /// Simulated length of the run, seconds.
    pub duration_s: f64,
    /// The optional roles this run runs, by name ([`RoleDecl::optional`]: a role added
    /// as an example, such as `odometer`); none by default.
    ///
    /// [`RoleDecl::optional`]: crate::graph::RoleDecl::optional
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub extra_roles: Vec<String>,
    pub timing: Timing,
    pub robot: Robot,
    pub plant: PlantConfig,
    pub estimator: EstimatorConfig,
    pub mpc: MpcConfig,
    pub dfl: DflConfig,
    pub planner: PlannerConfig,
    /// The tracker of moving obstacles (docs/running.md, "Moving obstacles").
    pub perception: PerceptionConfig,
    /// The robot's lidar (`[lidar]`; none by default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar: Option<LidarConfig>,
    /// Circular obstacles, at rest or moving; collisions are judged against these true
    /// radii and positions.
    pub obstacles: Vec<Obstacle>,
    /// Injected faults, for tests and demonstrations (none by default).
    pub fault: FaultConfig,
    pub supervision: Supervision,
    /// Scheduled swap-in replacements (`[[swap]]`), in any order.
    pub swap: Vec<SwapConfig>,
    /// Roles on other hosts (docs/hosts.md).
    pub hosts: HostsConfig,
    /// The ROS 2 robot of `plant.kind = "ros2"` (docs/ros2.md).
    pub ros2: Ros2Config,
    /// How a real-time run's processes are scheduled (docs/running.md, "Real-time
    /// scheduling").
    pub realtime: RealtimeConfig,
    /// The robots of a fleet (`[[robots]]`, docs/fleet.md); none: the one robot `robot`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub robots: Vec<FleetRobot>,
    /// The live view (`[live]`, `scmpc run --live`; docs/foxglove.md): never written out
    /// ([`live`]).
    #[serde(default, skip_serializing)]
    pub live: Option<LiveConfig>,
    /// Which of `robots` this scenario drives, when it is a fleet's member
    /// ([`Scenario::member`]); never a key of a file: each process of a fleet's run reads
    /// the fleet's scenario and takes its member by its robot id.
    #[serde(skip)]
    #[schemars(skip)]
    pub fleet_id: Option<usize>,
}

/// One scheduled replacement of a role process, make-before-break (docs/design.md, "Supervision").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SwapConfig {
    /// Simulated time the replacement is started at, s; it takes over at a later sample
    /// boundary, once it has warmed up.
    pub time_s: f64,
    /// `estimator`, `mpc`, `dfl` or `planner` (the plant is the simulated robot: not
    /// swappable; the planner only runs with `planner.kind = "route"`).
    pub role: String,
    /// Program and arguments of the replacement; empty: a fresh built-in process of the
    /// role. A program named `scmpc` is the running `scmpc` executable itself.
    #[serde(default)]
    pub command: Vec<String>,
}

impl SwapConfig {
    /// The role swapped, if the name is one that can be.
    pub fn swappable_role(&self) -> Option<crate::Role> {
        crate::Role::from_name(&self.role).filter(|r| *r != crate::Role::Plant)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Timing {
    /// MPC sample period `Ts`, seconds.
    pub ts_s: f64,
    /// Inner ticks per sample `M`: the DFL and the plant run every `Ts / M`.
    pub inner_steps: usize,
}

impl Timing {
    /// Inner (DFL, plant) tick `Ts / M`, s.
    pub fn dt_s(&self) -> f64 {
        self.ts_s / self.inner_steps as f64
    }

    /// Time of inner tick `tick`, s since the start of the run.
    pub fn tick_time_s(&self, tick: u64) -> f64 {
        tick as f64 * self.dt_s()
    }

    /// Inner ticks per sample, `M`.
    pub fn ticks_per_sample(&self) -> u64 {
        self.inner_steps as u64
    }

    /// The sample inner tick `tick` belongs to: `k = floor(j / M)`.
    pub fn sample_of(&self, tick: u64) -> u64 {
        tick / self.ticks_per_sample()
    }

    /// Whether inner tick `tick` is the first of its sample (`t_j = k Ts`).
    pub fn starts_sample(&self, tick: u64) -> bool {
        tick.is_multiple_of(self.ticks_per_sample())
    }

    /// The first inner tick of sample `sample`: `j = k M`.
    pub fn first_tick(&self, sample: u64) -> u64 {
        sample * self.ticks_per_sample()
    }

    /// Time of sample `sample` (of its first inner tick), s since the start of the run.
    pub fn sample_time_s(&self, sample: u64) -> f64 {
        self.tick_time_s(self.first_tick(sample))
    }

    /// How far inner tick `tick` is into its sample, s.
    pub fn time_into_sample_s(&self, tick: u64) -> f64 {
        (tick % self.ticks_per_sample()) as f64 * self.dt_s()
    }

    /// The first inner tick of a sample at or after `tick`.
    pub fn next_sample_start(&self, tick: u64) -> u64 {
        tick.div_ceil(self.ticks_per_sample()) * self.ticks_per_sample()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Robot {
    /// Initial pose `[x_m, y_m, theta_rad]`.
    pub start: [f64; 3],
    /// Initial value of the dynamic extension `zeta` (the forward speed), m/s.
    pub zeta0: f64,
    /// The goal, `[x_m, y_m]` or `[x_m, y_m, theta_rad]`: the MPC regulates `z` to its
    /// position at rest; a robot held there turns in place to its heading, if it has one.
    #[schemars(with = "Vec<f64>")]
    pub goal: Goal,
    /// The robot has reached the goal while its centre stays within this distance, m.
    pub goal_tolerance_m: f64,
    /// With a goal heading: how near it the robot turns, rad.
    pub goal_yaw_tolerance_rad: f64,
    /// Radius of the robot's footprint, m (0: the paper's point robot). Every obstacle is
    /// inflated by it in the MPC, the DFL's safety check and the judge, so clearances are
    /// measured from the robot's edge.
    pub radius_m: f64,
    /// How the robot ends its run at the goal (docs/reach.md, "Arriving and coming to
    /// rest").
    pub final_approach: FinalApproach,
    /// With `final_approach = "settle"`: the robot held at its goal keeps holding until
    /// `duration_s` instead of ending the run there.
    pub hold_at_goal: bool,
    /// Time constant of the first-order lag with which the base's speeds follow their
    /// commands, s (0: at once). The estimator predicts with it and the DFL shapes its
    /// commands for it ([`crate::actuator`]); `scmpc identify` measures it.
    pub actuator_lag_s: f64,
    /// Time from a command's publication to its effect on the base, s (0: at once). The
    /// estimator predicts with it; the DFL commands for the state the robot will be in
    /// when its command takes effect ([`crate::actuator`]).
    pub command_delay_s: f64,
}

/// The goal of a run (`robot.goal`): a position and, if given, a heading. In a file,
/// `[x, y]` or `[x, y, theta]`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Goal {
    /// `[x_m, y_m]`.
    pub position: [f64; 2],
    /// The heading to turn to at the goal, rad (`robot.final_approach = "settle"`).
    pub yaw_rad: Option<f64>,
}

impl Goal {
    /// A goal without a heading.
    pub fn at(position: [f64; 2]) -> Goal {
        Goal {
            position,
            yaw_rad: None,
        }
    }
}

impl Serialize for Goal {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let [x, y] = self.position;
        match self.yaw_rad {
            Some(yaw) => [x, y, yaw].serialize(serializer),
            None => [x, y].serialize(serializer),
        }
    }
}

impl<'de> Deserialize<'de> for Goal {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Goal, D::Error> {
        match Vec::<f64>::deserialize(deserializer)?[..] {
            [x, y] => Ok(Goal::at([x, y])),
            [x, y, yaw] => Ok(Goal {
                position: [x, y],
                yaw_rad: Some(yaw),
            }),
            ref other => Err(serde::de::Error::custom(format!(
                "a goal is [x, y] or [x, y, theta], got {} numbers",
                other.len()
            ))),
        }
    }
}

/// How the robot ends its run at the goal (`robot.final_approach`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum FinalApproach {
    /// Within [`APPROACH_RADIUS_M`] of the goal (along the route, with a planner) the MPC
    /// weighs the state by `mpc.approach_q_diag` and the input by `mpc.approach_r_diag`,
    /// driving the robot to rest at the goal without passing it; once within
    /// `robot.goal_tolerance_m` and slower than [`HOLD_SPEED_M_S`], the DFL brakes to rest
    /// and holds it there, and the run ends `reached` (`robot.hold_at_goal`: it goes on).
    Settle,
    /// The paper's formulation to the end: the paper's weights all the way, no hold; the
    /// run goes on to `duration_s`.
    Paper,
}

/// How near the goal the final approach begins (`robot.final_approach = "settle"`), m:
/// the straight-line distance without a planner, the route's length left with one.
pub const APPROACH_RADIUS_M: f64 = 1.0;
/// A robot that has begun its final approach leaves it only beyond this distance, m (a
/// robot pushed back, or a route that grew).
pub const APPROACH_LEFT_BEYOND_M: f64 = 1.5;
/// The DFL holds a robot within the goal tolerance once its speed is below this, m/s.
pub const HOLD_SPEED_M_S: f64 = 0.02;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// `sim`: the simulated robot below; `ros2`: a ROS 2 robot driven over rmw_zenoh
    /// (the `[ros2]` section; real time only). The keys below are the simulator's, except
    /// the wheels' geometry and limit, which the estimator and the DFL use either way.
    pub kind: PlantKind,
    /// Wheel radius `r` of the transform `T` (paper eq. 5), m.
    pub wheel_radius_m: f64,
    /// Distance between the wheels `d` of the transform `T`, m.
    pub wheel_base_m: f64,
    /// Wheel-speed saturation, rad/s; `0` disables it.
    pub max_wheel_speed_rad_s: f64,
    /// Variance of the Gaussian output noise: one number for x, y and theta, or
    /// `[var_x_m2, var_y_m2, var_theta_rad2]`.
    pub noise_variance: NoiseVariance,
    /// Standard deviation of a white process disturbance added to `[xdot, ydot, thetadot]`
    /// (m/s, m/s, rad/s), drawn once per inner tick; `0` disables it.
    pub disturbance_std: f64,
    /// RK4 substeps per inner tick.
    pub rk4_substeps: usize,
    /// The simulated base's lag, s: `auto` is the one the controller is told
    /// (`robot.actuator_lag_s`); a number simulates a base that differs from its model.
    pub actuator_lag_s: AutoOr,
    /// The simulated base's command delay, s: `auto` is the one the controller is told
    /// (`robot.command_delay_s`); a number simulates a base that differs from its model.
    pub command_delay_s: AutoOr,
    /// The simulated base's command watchdog, s: once the newest command has been applied
    /// this long beyond its own tick, the base brakes straight to rest on its own at the
    /// DFL's brake's deceleration (as a real base stops when its commands stop; a DFL on
    /// a host that is lost cannot brake it).
    pub command_timeout_s: f64,
}

impl PlantConfig {
    /// The wheels' geometry, the transform `T` (paper eq. 5).
    pub fn wheel_geometry(&self) -> crate::WheelGeometry {
        crate::WheelGeometry {
            wheel_radius_m: self.wheel_radius_m,
            wheel_base_m: self.wheel_base_m,
        }
    }

    /// The inputs `[u1, u2]` (m/s, rad/s) as the wheels realize them: each wheel speed
    /// clipped to `max_wheel_speed_rad_s` when that is set. The plant integrates these;
    /// the EKF predicts with them (the robot's own actuator limits are known to it).
    pub fn realized_inputs(&self, body: [f64; 2]) -> [f64; 2] {
        if self.max_wheel_speed_rad_s > 0.0 {
            let limit = self.max_wheel_speed_rad_s;
            let geometry = self.wheel_geometry();
            let wheels = geometry.wheel_speeds(body);
            geometry.body_inputs(wheels.map(|w| w.clamp(-limit, limit)))
        } else {
            body
        }
    }
}

/// Output-noise variance, either shared by the three axes or per axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum NoiseVariance {
    Uniform(f64),
    PerAxis([f64; 3]),
}

impl NoiseVariance {
    /// Per-axis variances `[x_m2, y_m2, theta_rad2]`.
    pub fn per_axis(self) -> [f64; 3] {
        match self {
            NoiseVariance::Uniform(v) => [v; 3],
            NoiseVariance::PerAxis(v) => v,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum EstimatorKind {
    /// Extended Kalman filter on the unicycle (the default).
    Ekf,
    /// The raw noisy measurement, as in the paper's noisy-feedback experiment.
    Passthrough,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorConfig {
    /// `ekf`: an extended Kalman filter on the unicycle; `passthrough`: the raw
    /// measurement, as in the paper's noisy-feedback experiment.
    pub kind: EstimatorKind,
    /// EKF process-noise intensity on `[x, y, theta]`, variance per second.
    pub process_noise: [f64; 3],
    /// EKF initial variance of `[x, y, theta]`.
    pub initial_variance: [f64; 3],
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ConstraintKind {
    /// Discrete control barrier function `H(z_{i+1}) >= (1 - gamma) H(z_i)` (eq. 54).
    Cbf,
    /// The paper's benchmark: `H(z_i) >= 0` at every stage.
    Euclidean,
}

/// Which MPC drives the DFL.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Formulation {
    /// The paper's scheme: linear MPC on the DFL-linearized model (problem of eqs. 51 to 47).
    Linear,
    /// The baseline SCNMPC on the unicycle itself (eqs. pr3-pr7), by sequential conic
    /// programming.
    Nonlinear,
}

/// How the linear scheme's conic program is written (the same program either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum QpForm {
    /// The one measured faster for the horizon: condensed up to
    /// [`QpForm::CONDENSED_UP_TO_HORIZON`], sparse beyond.
    Auto,
    /// States and inputs are variables, the dynamics are equality rows.
    Sparse,
    /// The states are eliminated: the inputs are the only variables.
    Condensed,
}

impl QpForm {
    /// Longest horizon `Auto` condenses. Measured on the paper's run (docs/performance.md,
    /// Performance): condensed takes 27 % fewer instructions at N = 8, sparse 14 % fewer
    /// at N = 12 and 3x fewer at N = 30.
    pub const CONDENSED_UP_TO_HORIZON: usize = 10;

    /// Whether the program for horizon `n` is condensed.
    pub fn condensed(self, n: usize) -> bool {
        match self {
            QpForm::Auto => n <= QpForm::CONDENSED_UP_TO_HORIZON,
            QpForm::Sparse => false,
            QpForm::Condensed => true,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MpcConfig {
    /// `linear` (the paper's scheme) or `nonlinear` (the SCNMPC baseline).
    pub formulation: Formulation,
    /// `auto`, `sparse` or `condensed` conic program for the linear scheme.
    pub qp_form: QpForm,
    /// Prediction horizon `N`.
    pub horizon: usize,
    /// Constraint-checking horizon `Nc` of the terminal constraints (eqs. 45, 47).
    pub constraint_horizon: usize,
    /// CBF decay rate `gamma` in (0, 1].
    pub gamma: f64,
    /// `cbf`: the discrete CBF of eq. 54 per stage; `euclidean`: the paper's benchmark,
    /// `H >= 0` per stage.
    pub constraint: ConstraintKind,
    /// Diagonal of the state weight `Q` on `z = [x, xdot, y, ydot]`.
    pub q_diag: [f64; 4],
    /// Diagonal of the input weight `R` on `v = [xddot, yddot]`.
    pub r_diag: [f64; 2],
    /// `Q` on the final approach (`robot.final_approach = "settle"`): by default, with
    /// `approach_r_diag`, an LQR per axis critically damped at about 1.4 rad/s (the
    /// paper's weights give 0.3 rad/s, damping 0.7: a robot coming in fast passes its goal
    /// and takes tens of seconds to settle).
    pub approach_q_diag: [f64; 4],
    /// `R` on the final approach.
    pub approach_r_diag: [f64; 2],
    /// Input box `|v_i| <= v_max`, m/s^2.
    pub v_max: f64,
    /// Lower corner of the position box on `(z1, z3)`, m.
    pub position_min: [f64; 2],
    /// Upper corner of the position box on `(z1, z3)`, m.
    pub position_max: [f64; 2],
    /// Fixed margin `m` added to every obstacle radius in the constraints, m.
    pub safety_margin_m: f64,
    /// `kappa`: standard deviations of the position estimate added to every radius.
    pub uncertainty_sigmas: f64,
    /// Most convex solves per sample (1 = no refinement of the linearization).
    pub max_solves: usize,
    /// Refinement stops once no predicted position moves more than this, m. A move of
    /// `d` leaves the convexified CBF exactly `d^2` (m^2) tighter than one linearized at
    /// the new plan (`H(p) - L(p) = |p - p_bar|^2`), so the re-solve it would start
    /// changes the plan far less than `d` (measured: docs/performance.md). The
    /// default 2 cm refines only from a poor reference (a cold start, a plan bent by a
    /// new obstacle).
    pub refinement_tol_m: f64,
    /// `brake` (the default): every plan ends in a state the DFL's brake stops from
    /// without its stopping path entering an obstacle, and the CBF's decay may be relaxed
    /// where braking needs it (recursive feasibility); `brake_ball`: the same with the
    /// whole ball of the stopping distance kept clear (a standoff whatever the direction);
    /// `none`: the paper's formulation exactly. The linear scheme only: with the nonlinear
    /// baseline (the paper's SCNMPC) it must be `none`.
    pub terminal_safety: TerminalSafety,
    /// How long after the robot's stop the stop must stay out of a moving obstacle's way,
    /// s: with terminal safety rows, a moving disc swept over the stop is carried on at its
    /// velocity for this long more (without more growth), so that a plan does not stop
    /// where a person walking on meets a robot at rest (docs/safety.md, "The stop and the
    /// person's way"). 0 is passive safety alone.
    pub rest_lookahead_s: f64,
}

/// The MPC's terminal safety rows (`mpc.terminal_safety`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TerminalSafety {
    /// The plan's last state must stop under the DFL's brake with its straight stopping
    /// path outside every obstacle; the CBF decay gets a slack bounded by the linearized
    /// barrier.
    Brake,
    /// As `Brake`, with the ball of the stopping distance around the last state clear.
    BrakeBall,
    /// The paper's formulation (problem of eqs. 51 to 47) as it stands.
    None,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DflConfig {
    /// `zeta_th`: below this `|zeta|` the steering input `U2` is zero, m/s.
    pub zeta_threshold: f64,
    /// Deceleration of the fallback brake (`U2 = 0`, `|U1|` this), m/s^2: `auto` is
    /// `mpc.v_max`, the largest the input box delivers along every heading. The MPC's
    /// terminal rows, the brake and the safety check all use it
    /// ([`Scenario::brake_decel`]); a value above `mpc.v_max` is refused.
    pub brake_decel: AutoOr,
    /// The safety check (docs/safety.md): the DFL flies only a plan whose trajectory,
    /// followed by the brake, it has checked against every obstacle, and brakes at once
    /// when the estimate shows the trajectory it flies is no longer safe.
    pub gatekeeper: bool,
    /// With the safety check: a robot that would brake without a plan, or rest, where an
    /// obstacle coming at it is predicted to run into it steps out of its way along its
    /// heading, when the check finds a way clear (`dfl::evasion`, docs/safety.md).
    pub evasion: bool,
}

/// The route planner (docs/planner.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlannerConfig {
    /// `none` (the paper: the MPC drives at the goal), `route` (a planner process, and
    /// the MPC follows its route) or `auto` ([`Scenario::plans_routes`]).
    pub kind: PlannerKind,
    /// Replan at least this often, s; 0: only at the start, on a stall or a stray.
    pub period_s: f64,
    /// Room the route keeps from every grown obstacle, m (given up where a gap is too
    /// narrow for it).
    pub clearance_m: f64,
    /// Cruising speed of the MPC's reference along the route, m/s: an upper bound on the
    /// speed profile the MPC derives from the input box (`mpc::follow`); `auto`: none.
    pub speed_m_s: AutoOr,
    /// Replan when the robot is farther than this from the route, m.
    pub stray_m: f64,
    /// A replan takes a route that goes round the obstacles another way than the current
    /// one only if it is shorter than what is left of the current one by this share of
    /// it (or the current one is blocked): two ways of about the same length are not
    /// swapped replan after replan.
    pub switch_margin: f64,
}

/// `planner.kind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PlannerKind {
    None,
    Route,
    Auto,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        PlannerConfig {
            kind: PlannerKind::Auto,
            period_s: 1.0,
            clearance_m: 0.2,
            speed_m_s: AutoOr::Auto(Auto::Auto),
            stray_m: 0.5,
            switch_margin: 0.1,
        }
    }
}

/// `"auto"` (a value derived from the rest of the scenario) or a number: `dfl.brake_decel`
/// (m/s^2), `planner.speed_m_s` (m/s), `plant.actuator_lag_s` and `plant.command_delay_s`
/// (s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum AutoOr {
    Auto(Auto),
    Value(f64),
}

/// The word `auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Auto {
    Auto,
}

impl Scenario {
    /// The paper's canonical scenario (`scenarios/paper.toml`): the defaults, with the
    /// paper's arrival (`robot.final_approach = "paper"`).
    pub fn paper() -> Scenario {
        let mut s = Scenario::default();
        s.robot.final_approach = FinalApproach::Paper;
        s
    }
}

impl Default for Scenario {
    /// The paper's canonical scenario (docs/running.md, "Scenario keys").
    fn default() -> Self {
        Scenario {
            name: "paper".into(),
            seed: 1,
            duration_s: 30.0,
            extra_roles: Vec::new(),
            timing: Timing::default(),
            robot: Robot::default(),
            plant: PlantConfig::default(),
            estimator: EstimatorConfig::default(),
            mpc: MpcConfig::default(),
            dfl: DflConfig::default(),
            planner: PlannerConfig::default(),
            perception: PerceptionConfig::default(),
            lidar: None,
            obstacles: vec![Obstacle::fixed(3.0, 3.5, 1.5)],
            fault: FaultConfig::default(),
            supervision: Supervision::default(),
            swap: Vec::new(),
            hosts: HostsConfig::default(),
            ros2: Ros2Config::default(),
            realtime: RealtimeConfig::default(),
            robots: Vec::new(),
            live: None,
            fleet_id: None,
        }
    }
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            ts_s: 0.05,
            inner_steps: 10,
        }
    }
}

impl Default for Robot {
    fn default() -> Self {
        Robot {
            start: [7.0, 7.0, -3.0 * std::f64::consts::FRAC_PI_4],
            zeta0: 0.0,
            goal: Goal::at([0.0, 0.0]),
            goal_tolerance_m: 0.1,
            goal_yaw_tolerance_rad: 0.1,
            radius_m: 0.0,
            final_approach: FinalApproach::Settle,
            hold_at_goal: false,
            actuator_lag_s: 0.0,
            command_delay_s: 0.0,
        }
    }
}

impl Default for PlantConfig {
    fn default() -> Self {
        PlantConfig {
            kind: PlantKind::Sim,
            wheel_radius_m: 0.1,
            wheel_base_m: 0.5,
            max_wheel_speed_rad_s: 0.0,
            noise_variance: NoiseVariance::Uniform(0.0),
            disturbance_std: 0.0,
            rk4_substeps: 1,
            actuator_lag_s: AutoOr::Auto(Auto::Auto),
            command_delay_s: AutoOr::Auto(Auto::Auto),
            command_timeout_s: 0.5,
        }
    }
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        EstimatorConfig {
            kind: EstimatorKind::Ekf,
            process_noise: [1e-4, 1e-4, 1e-4],
            initial_variance: [1e-2, 1e-2, 1e-2],
        }
    }
}

impl Default for MpcConfig {
    fn default() -> Self {
        MpcConfig {
            formulation: Formulation::Linear,
            qp_form: QpForm::Auto,
            horizon: 8,
            constraint_horizon: 10,
            gamma: 0.1,
            constraint: ConstraintKind::Cbf,
            q_diag: [1.0; 4],
            r_diag: [100.0; 2],
            approach_q_diag: [4.0; 4],
            approach_r_diag: [1.0; 2],
            v_max: 3.0,
            position_min: [-10.0, -10.0],
            position_max: [10.0, 10.0],
            safety_margin_m: 0.0,
            uncertainty_sigmas: 3.0,
            max_solves: 5,
            refinement_tol_m: 0.02,
            terminal_safety: TerminalSafety::Brake,
            rest_lookahead_s: 0.5,
        }
    }
}

impl Default for DflConfig {
    fn default() -> Self {
        DflConfig {
            zeta_threshold: 0.01,
            brake_decel: AutoOr::Auto(Auto::Auto),
            gatekeeper: true,
            evasion: true,
        }
    }
}

impl Scenario {
    /// Deceleration of the fallback brake, m/s^2: `dfl.brake_decel`, whose `auto` is
    /// `mpc.v_max`. One braking model for the MPC's terminal rows, the DFL's brake and its
    /// safety check (docs/safety.md).
    pub fn brake_decel(&self) -> f64 {
        match self.dfl.brake_decel {
            AutoOr::Auto(_) => self.mpc.v_max,
            AutoOr::Value(decel) => decel,
        }
    }

    /// The role processes of a run: the four of the paper, the tracker when it runs
    /// ([`Scenario::runs_tracker`]), the lidar with one, the planner when it is on, and
    /// the optional roles `extra_roles` names.
    pub fn roles(&self) -> impl Iterator<Item = crate::Role> + use<> {
        let planner = self.plans_routes();
        let tracker = self.runs_tracker();
        let lidar = self.lidar.is_some();
        let extra = self.extra_roles.clone();
        crate::Role::ALL.into_iter().filter(move |r| match r {
            crate::Role::Planner => planner,
            crate::Role::Tracker => tracker,
            crate::Role::Lidar => lidar,
            r if crate::graph::declaration(*r, PlantKind::Sim).optional => {
                extra.iter().any(|name| name == r.as_str())
            }
            _ => true,
        })
    }

    /// Whether a route planner runs: with `planner.kind = "route"`, and with `auto` (the
    /// default) in a world of more than one obstacle or of any moving one, where the
    /// straight way to the goal is likely to be blocked and a route around the obstacles
    /// at rest leaves the moving ones to the MPC, and with a lidar (what stands in the way
    /// is seen on the way: the routes go round the tracks that stand still). A world of one obstacle at rest (the
    /// paper's) and the nonlinear baseline (which drives at the goal only) run none.
    pub fn plans_routes(&self) -> bool {
        match self.planner.kind {
            PlannerKind::Route => true,
            PlannerKind::None => false,
            PlannerKind::Auto => {
                self.mpc.formulation == Formulation::Linear
                    && (self.obstacles.len() > 1
                        || self.obstacles.iter().any(Obstacle::moves)
                        || self.sees_with_lidar())
            }
        }
    }

    /// Whether the tracker sees the world in the lidar's scans (`perception.kind =
    /// "lidar"`, or `auto` with a `[lidar]`).
    pub fn sees_with_lidar(&self) -> bool {
        match self.perception.kind {
            PerceptionKind::Lidar => true,
            PerceptionKind::Auto => self.lidar.is_some(),
            PerceptionKind::Track => false,
        }
    }

    /// Whether the tracker assumes phantoms where the lidar cannot see (with a lidar, and
    /// `perception.phantoms`).
    pub fn phantoms(&self) -> bool {
        self.sees_with_lidar() && self.perception.phantoms
    }

    /// The most obstacle discs the MPC keeps clear of at once: the known obstacles and
    /// one per track (with a lidar, whose tracks and phantoms are not the scenario's
    /// obstacles, the [`MAX_SEEN_DISCS`] nearest).
    pub fn max_obstacle_discs(&self) -> usize {
        let peers = self.robot_count() - 1;
        let tracks = peers
            + if self.sees_with_lidar() {
                MAX_SEEN_DISCS
            } else {
                self.tracked().count()
            };
        self.known_obstacles().count() + tracks
    }

    /// Whether the MPC and the DFL take tracks: whenever a tracker runs.
    pub fn takes_tracks(&self) -> bool {
        self.runs_tracker()
    }

    /// Whether a tracker runs: it sees with a lidar, it tracks an obstacle, or the robot is
    /// one of a fleet, whose tracker tells it of the others ([`crate::PeerPrediction`]).
    pub fn runs_tracker(&self) -> bool {
        self.sees_with_lidar() || self.tracked().next().is_some() || self.is_fleet()
    }

    /// Whether the tracker measures obstacle `obstacle` from the truth: every one with
    /// `perception.kind = "track"`, the ones not `known` with `auto`, none with a lidar
    /// (which sees them). The MPC takes the known ones from the scenario.
    pub fn is_tracked(&self, obstacle: &Obstacle) -> bool {
        match self.perception.kind {
            _ if self.sees_with_lidar() => false,
            PerceptionKind::Track => true,
            _ => !obstacle.is_known(),
        }
    }

    /// The obstacles the tracker measures from the truth, with their indices in
    /// `obstacles`, in order.
    pub fn tracked(&self) -> impl Iterator<Item = (usize, &Obstacle)> {
        self.obstacles
            .iter()
            .enumerate()
            .filter(|(_, o)| self.is_tracked(o))
    }

    /// The obstacles the pipeline takes from the scenario (the map), in order: the ones
    /// not tracked, and with a lidar the `known` ones.
    pub fn known_obstacles(&self) -> impl Iterator<Item = &Obstacle> {
        let lidar = self.sees_with_lidar();
        (self.obstacles.iter()).filter(move |o| {
            if lidar {
                o.is_known()
            } else {
                !self.is_tracked(o)
            }
        })
    }

    /// Inner ticks between two perception ticks (the lidar's scans with a lidar, else
    /// `perception.period_s`; at least one).
    pub fn perception_ticks(&self) -> u64 {
        let period = match (&self.lidar, self.perception.period_s) {
            (Some(lidar), _) => 1.0 / lidar.rate_hz,
            (None, AutoOr::Auto(_)) => self.timing.ts_s,
            (None, AutoOr::Value(p)) => p,
        };
        ((period / self.timing.dt_s()).round() as u64).max(1)
    }

    /// Number of inner ticks in a run of `duration_s` (rounded to the nearest tick).
    pub fn tick_count(&self) -> u64 {
        (self.duration_s / self.timing.dt_s()).round() as u64
    }
}

mod document;
pub use document::{ScenarioError, ScenarioErrors};

mod faults;
pub use faults::*;

mod world;
pub use world::*;

mod ros2;
pub use ros2::*;

mod realtime;
pub use realtime::*;

mod lidar;
pub use lidar::*;

mod live;
pub use live::*;

mod hosts;
pub use hosts::*;

mod supervision;
pub use supervision::*;

mod fleet;
pub use fleet::*;

pub mod keys;

mod validate;

#[cfg(test)]
mod tests;
