//! The scenario's one validator: every value checked against its meaning, every problem
//! reported with its dotted key, nothing run before it passes.

use super::*;

impl Scenario {
    /// The scenario as a [`Validated`] one, if [`Scenario::validate`] accepts it.
    pub fn validated(mut self, origin: &str) -> Result<Validated, ScenarioErrors> {
        self.obstacles = self
            .obstacles
            .into_iter()
            .map(Obstacle::with_start_of_path)
            .collect();
        self.validate(origin)?;
        Ok(Validated(self))
    }

    /// Checks every value against its meaning; reports every problem with its dotted key.
    /// One check per key, in the schema's order, section by section.
    pub fn validate(&self, origin: &str) -> Result<(), ScenarioErrors> {
        let mut v = Validator {
            origin,
            errors: Vec::new(),
        };
        self.check_basics(&mut v);
        self.check_mpc_and_dfl(&mut v);
        self.check_planner_and_obstacles(&mut v);
        // A fleet's robots are each checked where they are (`check_fleet`); its `[robot]`
        // is their template, not a robot in the world.
        if !self.is_fleet() {
            self.check_geometry(&mut v);
        }
        self.check_faults(&mut v);
        self.check_hosts(&mut v);
        self.check_swaps(&mut v);
        self.check_fleet(&mut v);
        for (key, message) in self
            .ros2
            .problems()
            .into_iter()
            .chain(self.realtime.problems())
            .chain(self.actuator_problems())
            .chain(self.lidar.iter().flat_map(LidarConfig::problems))
            .chain(self.live.iter().flat_map(LiveConfig::problems))
        {
            v.fail(key, message);
        }
        if v.errors.is_empty() {
            Ok(())
        } else {
            Err(ScenarioErrors(v.errors))
        }
    }

    /// The run's length and clock, the robot, the plant and the estimator.
    fn check_basics(&self, v: &mut Validator) {
        v.positive("duration_s", self.duration_s);
        v.positive(
            "supervision.swap_timeout_s",
            self.supervision.swap_timeout_s,
        );
        for (i, name) in self.extra_roles.iter().enumerate() {
            let optional = crate::Role::from_name(name)
                .is_some_and(|r| crate::graph::declaration(r, crate::PlantKind::Sim).optional);
            if !optional {
                let roles: Vec<&str> = (crate::Role::ALL.iter())
                    .filter(|r| crate::graph::declaration(**r, crate::PlantKind::Sim).optional)
                    .map(|r| r.as_str())
                    .collect();
                v.fail(
                    &format!("extra_roles[{i}]"),
                    format!("`{name}` is no optional role (optional roles: {roles:?})"),
                );
            }
        }
        v.positive("timing.ts_s", self.timing.ts_s);
        v.in_range(
            "timing.inner_steps",
            self.timing.inner_steps,
            1,
            MAX_INNER_STEPS,
        );

        v.finite_all("robot.start", &self.robot.start);
        v.finite("robot.zeta0", self.robot.zeta0);
        v.finite_all("robot.goal", &self.robot.goal.position);
        if let Some(yaw) = self.robot.goal.yaw_rad
            && v.finite("robot.goal.2", yaw)
            && self.robot.final_approach != super::FinalApproach::Settle
        {
            v.fail(
                "robot.goal",
                "a goal heading needs robot.final_approach = \"settle\" (the paper's \
                 arrival has none)"
                    .into(),
            );
        }
        v.positive("robot.goal_tolerance_m", self.robot.goal_tolerance_m);
        let yaw_tolerance = self.robot.goal_yaw_tolerance_rad;
        if !(yaw_tolerance > 0.0 && yaw_tolerance <= std::f64::consts::PI) {
            v.fail(
                "robot.goal_yaw_tolerance_rad",
                format!("must be in (0, pi], got {yaw_tolerance}"),
            );
        }
        v.non_negative("robot.radius_m", self.robot.radius_m);

        self.check_plant(v);

        v.non_negative_all("estimator.process_noise", &self.estimator.process_noise);
        v.non_negative_all(
            "estimator.initial_variance",
            &self.estimator.initial_variance,
        );
    }

    /// The simulated plant's keys.
    fn check_plant(&self, v: &mut Validator) {
        v.positive("plant.wheel_radius_m", self.plant.wheel_radius_m);
        v.positive("plant.wheel_base_m", self.plant.wheel_base_m);
        v.non_negative(
            "plant.max_wheel_speed_rad_s",
            self.plant.max_wheel_speed_rad_s,
        );
        match self.plant.noise_variance {
            NoiseVariance::Uniform(variance) => v.non_negative("plant.noise_variance", variance),
            NoiseVariance::PerAxis(variances) => {
                v.non_negative_all("plant.noise_variance", &variances)
            }
        }
        v.non_negative("plant.disturbance_std", self.plant.disturbance_std);
        let (timeout_s, tick_s) = (self.plant.command_timeout_s, self.timing.dt_s());
        if tick_s.is_finite() && !(timeout_s.is_finite() && timeout_s >= tick_s) {
            v.fail(
                "plant.command_timeout_s",
                format!("must be at least one inner tick (Ts / M = {tick_s} s), got {timeout_s}"),
            );
        }
        v.in_range(
            "plant.rk4_substeps",
            self.plant.rk4_substeps,
            1,
            MAX_RK4_SUBSTEPS,
        );
    }

    /// The MPC's keys, and the DFL's against the MPC's input box.
    fn check_mpc_and_dfl(&self, v: &mut Validator) {
        let m = &self.mpc;
        v.in_range("mpc.horizon", m.horizon, 1, MAX_HORIZON);
        v.in_range(
            "mpc.constraint_horizon",
            m.constraint_horizon,
            0,
            MAX_CONSTRAINT_HORIZON,
        );
        if !(m.gamma.is_finite() && m.gamma > 0.0 && m.gamma <= 1.0) {
            v.fail("mpc.gamma", format!("must be in (0, 1], got {}", m.gamma));
        }
        for (key, q, r) in [
            ("", &m.q_diag, &m.r_diag),
            ("approach_", &m.approach_q_diag, &m.approach_r_diag),
        ] {
            v.non_negative_all(&format!("mpc.{key}q_diag"), q);
            for (i, r) in r.iter().enumerate() {
                v.positive(&format!("mpc.{key}r_diag.{i}"), *r);
            }
        }
        v.positive("mpc.v_max", m.v_max);
        v.finite_all("mpc.position_min", &m.position_min);
        v.finite_all("mpc.position_max", &m.position_max);
        for axis in 0..2 {
            if m.position_min[axis] >= m.position_max[axis] {
                v.fail(
                    "mpc.position_min",
                    format!("must be below mpc.position_max on axis {axis}"),
                );
            }
        }
        if m.formulation == Formulation::Nonlinear && m.terminal_safety != TerminalSafety::None {
            v.fail(
                "mpc.terminal_safety",
                "the nonlinear baseline (mpc.formulation = \"nonlinear\") has no terminal \
                 safety rows; set mpc.terminal_safety = \"none\" with it"
                    .into(),
            );
        }
        v.non_negative("mpc.safety_margin_m", m.safety_margin_m);
        v.non_negative("mpc.uncertainty_sigmas", m.uncertainty_sigmas);
        v.in_range("mpc.max_solves", m.max_solves, 1, 100);
        v.positive("mpc.refinement_tol_m", m.refinement_tol_m);
        v.non_negative("mpc.rest_lookahead_s", m.rest_lookahead_s);

        v.non_negative("dfl.zeta_threshold", self.dfl.zeta_threshold);
        if let AutoOr::Value(decel) = self.dfl.brake_decel {
            v.positive("dfl.brake_decel", decel);
            if decel > m.v_max {
                v.fail(
                    "dfl.brake_decel",
                    format!(
                        "{decel} m/s^2 is more than the input box delivers along every \
                         heading (mpc.v_max = {}); use at most that, or \"auto\"",
                        m.v_max
                    ),
                );
            }
        }
    }

    /// The planner's keys and the obstacles' values.
    fn check_planner_and_obstacles(&self, v: &mut Validator) {
        let (p, m) = (&self.planner, &self.mpc);
        v.non_negative("planner.period_s", p.period_s);
        v.non_negative("planner.clearance_m", p.clearance_m);
        if let AutoOr::Value(speed) = p.speed_m_s {
            v.positive("planner.speed_m_s", speed);
        }
        v.positive("planner.stray_m", p.stray_m);
        if v.finite("planner.switch_margin", p.switch_margin)
            && !(0.0..1.0).contains(&p.switch_margin)
        {
            v.fail(
                "planner.switch_margin",
                format!("must be a share in [0, 1), got {}", p.switch_margin),
            );
        }
        if p.kind == PlannerKind::Route && m.formulation == Formulation::Nonlinear {
            v.fail(
                "planner.kind",
                "the nonlinear baseline (mpc.formulation = \"nonlinear\") drives at the goal \
                 only; use planner.kind = \"none\" with it"
                    .into(),
            );
        }

        for (i, o) in self.obstacles.iter().enumerate() {
            check_obstacle(v, i, o);
        }
        let tracked = self.tracked().count();
        if tracked > 0 && m.formulation == Formulation::Nonlinear {
            v.fail(
                "mpc.formulation",
                "the nonlinear baseline knows obstacles at rest only; a moving or tracked \
                 obstacle needs mpc.formulation = \"linear\""
                    .into(),
            );
        }
        // A fleet's tracks hold a slot for each other robot beside them.
        let others = self.robot_count() - 1;
        if tracked + others > crate::MAX_TRACKS {
            let most = crate::MAX_TRACKS;
            let room = match others {
                0 => format!("the tracker tracks at most {most}"),
                1 => format!("a robot's tracks hold {} beside the other robot", most - 1),
                n => format!(
                    "a robot's tracks hold {} beside the {n} other robots",
                    most - n
                ),
            };
            v.fail("obstacles", format!("{tracked} obstacles to track; {room}"));
        }
        let c = &self.perception;
        if let AutoOr::Value(period) = c.period_s {
            v.positive("perception.period_s", period);
        }
        v.non_negative("perception.noise_std", c.noise_std);
        v.non_negative("perception.accel_max", c.accel_max);
        self.check_lidar_perception(v);
    }

    /// The keys of perception with a lidar, and what a lidar needs.
    fn check_lidar_perception(&self, v: &mut Validator) {
        let c = &self.perception;
        if c.kind == PerceptionKind::Lidar && self.lidar.is_none() {
            v.fail(
                "perception.kind",
                "\"lidar\" sees with the robot's lidar: add a [lidar] table".into(),
            );
        }
        if self.lidar.is_some() && c.period_s != AutoOr::Auto(Auto::Auto) {
            v.fail(
                "perception.period_s",
                "with a [lidar] the perception ticks are its scans (lidar.rate_hz): leave \
                 perception.period_s out"
                    .into(),
            );
        }
        if self.sees_with_lidar() && self.mpc.formulation == Formulation::Nonlinear {
            v.fail(
                "mpc.formulation",
                "the nonlinear baseline knows obstacles at rest only; seeing with a lidar \
                 needs mpc.formulation = \"linear\""
                    .into(),
            );
        }
        v.non_negative("perception.min_radius", c.min_radius);
        if !(1..=CONFIRM_WINDOW).contains(&c.confirm) {
            v.fail(
                "perception.confirm",
                format!("must be 1 to {CONFIRM_WINDOW} scans, got {}", c.confirm),
            );
        }
        v.positive("perception.lost_s", c.lost_s);
        if !(c.gate > 0.0 && c.gate <= MAX_GATE) {
            v.fail(
                "perception.gate",
                format!(
                    "must be in (0, {MAX_GATE}] standard deviations, got {}",
                    c.gate
                ),
            );
        }
        v.non_negative("perception.cluster_gap_m", c.cluster_gap_m);
        v.positive("perception.phantom_radius", c.phantom_radius);
        v.non_negative("perception.phantom_speed", c.phantom_speed);
        if self.phantoms() && self.mpc.uncertainty_sigmas <= 0.0 {
            v.fail(
                "perception.phantoms",
                "a phantom's disc grows at perception.phantom_speed through the predictions' \
                 sigmas: it needs mpc.uncertainty_sigmas > 0 (or perception.phantoms = false)"
                    .into(),
            );
        }
    }

    /// The injected faults (those of the links only with a role on another host).
    pub(super) fn check_faults(&self, v: &mut Validator) {
        let f = &self.fault;
        v.non_negative("fault.mpc_delay_ms", f.mpc_delay_ms);
        v.non_negative("fault.estimator_delay_ms", f.estimator_delay_ms);
        if f.estimator_nan_from_s.is_nan() || f.estimator_nan_from_s < 0.0 {
            v.fail(
                "fault.estimator_nan_from_s",
                format!(
                    "must be a time, s, or inf (off), got {}",
                    f.estimator_nan_from_s
                ),
            );
        }
        v.non_negative("fault.tracker_delay_ms", f.tracker_delay_ms);
        for (key, set) in [
            ("fault.mpc_delay_samples", &f.mpc_delay_samples),
            ("fault.mpc_fail_samples", &f.mpc_fail_samples),
            ("fault.tracker_drop_samples", &f.tracker_drop_samples),
        ] {
            if !set.is_well_formed() {
                v.fail(
                    key,
                    "must be a list of samples or a range like \"100..=104\"".into(),
                );
            }
        }

        v.non_negative("fault.link_delay_ms", f.link_delay_ms);
        if !(0.0..1.0).contains(&f.link_loss) {
            v.fail(
                "fault.link_loss",
                format!("must be a probability in [0, 1), got {}", f.link_loss),
            );
        }
        let [from, to] = f.link_down_s;
        if !(from.is_finite() && to.is_finite() && from >= 0.0 && to >= from) {
            v.fail(
                "fault.link_down_s",
                format!("must be [from, to] with 0 <= from <= to, s, got [{from}, {to}]"),
            );
        }
        let link_keys = [
            ("fault.link_delay_ms", f.link_delay_ms > 0.0),
            ("fault.link_loss", f.link_loss > 0.0),
            ("fault.link_down_s", f.link_is_ever_down()),
        ];
        // A fleet's robot's links are those of its own host (`robots.<i>.host`).
        let hosts = match self.fleet_id {
            Some(_) => self.hosts.names(),
            None => self.host_names(),
        };
        for (key, _) in link_keys.iter().filter(|(_, set)| *set) {
            if hosts.is_empty() {
                v.fail(
                    key,
                    "acts on the links between hosts, and no role is placed on another host \
                     ([hosts], docs/hosts.md)"
                        .into(),
                );
            }
        }
    }

    /// Each `[[swap]]`: its time within the run, a swappable role, a program.
    fn check_swaps(&self, v: &mut Validator) {
        for (i, swap) in self.swap.iter().enumerate() {
            if !(swap.time_s.is_finite() && swap.time_s >= 0.0 && swap.time_s < self.duration_s) {
                v.fail(
                    &format!("swap.{i}.time_s"),
                    format!(
                        "must be in [0, duration_s = {}), got {}",
                        self.duration_s, swap.time_s
                    ),
                );
            }
            match swap.swappable_role() {
                None => v.fail(
                    &format!("swap.{i}.role"),
                    format!(
                        "must be estimator, mpc, dfl, planner or tracker (the plant cannot \
                         be swapped), got `{}`",
                        swap.role
                    ),
                ),
                Some(role) => {
                    if let Some(why) = self.absent(role) {
                        v.fail(&format!("swap.{i}.role"), format!("{why}: nothing to swap"));
                    }
                }
            }
            if swap.command.first().is_some_and(|p| p.trim().is_empty()) {
                v.fail(&format!("swap.{i}.command"), "the program is empty".into());
            }
        }
    }

    /// Why `role` runs no process in this scenario, if it does not.
    pub(super) fn absent(&self, role: crate::Role) -> Option<String> {
        if self.roles().any(|r| r == role) {
            return None;
        }
        Some(match role {
            crate::Role::Planner => "no planner runs (planner.kind = \"none\", or \"auto\" \
                                     in a world of one obstacle at rest)"
                .into(),
            crate::Role::Tracker => {
                "no tracker runs (no obstacle moves and perception.kind = \"auto\")".into()
            }
            _ => format!("no {} runs", role.as_str()),
        })
    }

    /// The start must be clear of every obstacle by the robot's radius, and so must the
    /// robot's path when it brakes from its initial speed; the start must be inside the
    /// position box, and the goal outside every obstacle and inside the position box.
    pub(super) fn check_geometry(&self, v: &mut Validator) {
        let [sx, sy, heading] = self.robot.start;
        let footprint = crate::ObstacleGrowth::footprint(self);
        let radius = footprint.fixed_m;
        if !(sx.is_finite() && sy.is_finite() && heading.is_finite() && radius.is_finite()) {
            return;
        }
        // Braking from zeta0 moves the robot straight along its heading (backwards when
        // zeta0 < 0), U2 being zero.
        let decel = self.brake_decel();
        let stop = if decel > 0.0 && self.robot.zeta0.is_finite() {
            crate::stopping_distance(self.robot.zeta0, decel, self.timing.dt_s())
        } else {
            0.0
        };
        let direction = self.robot.zeta0.signum();
        let stop_point = [
            sx + direction * stop * heading.cos(),
            sy + direction * stop * heading.sin(),
        ];
        let [gx, gy] = self.robot.goal.position;
        for (i, o) in self.obstacles.iter().enumerate() {
            let clearance = footprint.clearance_m(o, [sx, sy]);
            if clearance <= 0.0 {
                v.fail(
                    "robot.start",
                    format!(
                        "({sx}, {sy}) is inside obstacle {i}, inflated by robot.radius_m = \
                         {radius} (clearance {clearance:.3} m)"
                    ),
                );
            } else if crate::segment_distance([sx, sy], stop_point, [o.x, o.y])
                <= crate::Disc::around(o, radius).radius
            {
                v.fail(
                    "robot.zeta0",
                    format!(
                        "braking from {} m/s at {decel} m/s^2 runs into obstacle {i}",
                        self.robot.zeta0
                    ),
                );
            }
            // Where the obstacle comes to rest (an obstacle with a velocity never does).
            if o.rest()
                .is_some_and(|rest| crate::distance(rest, [gx, gy]) <= o.radius + radius)
            {
                v.fail(
                    "robot.goal",
                    format!(
                        "({gx}, {gy}) is inside obstacle {i} where it rests, inflated by \
                         robot.radius_m"
                    ),
                );
            }
        }
        let the_box = self.position_box();
        if self.outside_position_box([sx, sy]) {
            v.fail("robot.start", format!("({sx}, {sy}) is outside {the_box}"));
        }
        if self.outside_position_box([gx, gy]) {
            v.fail(
                "robot.goal",
                format!("({gx}, {gy}) is outside {the_box}: no plan can reach it"),
            );
        }
    }
}

impl Scenario {
    /// Whether `p` is outside the MPC's position box.
    pub(crate) fn outside_position_box(&self, p: [f64; 2]) -> bool {
        let m = &self.mpc;
        (0..2).any(|a| p[a] < m.position_min[a] || p[a] > m.position_max[a])
    }

    /// The position box, as an error message names it.
    pub(crate) fn position_box(&self) -> String {
        let [lo, hi] = [self.mpc.position_min, self.mpc.position_max];
        format!(
            "the position box [{}, {}] x [{}, {}] (mpc.position_min, mpc.position_max)",
            lo[0], hi[0], lo[1], hi[1]
        )
    }
}

/// Collects errors for [`Scenario::validate`].
/// Obstacle `i`: where it is and how it moves.
fn check_obstacle(v: &mut Validator, i: usize, o: &Obstacle) {
    let key = |name: &str| format!("obstacles.{i}.{name}");
    v.non_negative(&key("radius"), o.radius);
    v.finite_all(&key("velocity"), &o.velocity);
    if o.known == Some(true) && o.moves() {
        v.fail(
            &key("known"),
            "an obstacle that moves cannot be known: the map holds obstacles at rest".into(),
        );
    }
    if o.path.is_empty() {
        for (name, value) in [("x", o.x), ("y", o.y)] {
            if value.is_nan() {
                v.fail(
                    &key(name),
                    "missing: an obstacle without a path needs x and y".into(),
                );
            } else {
                v.finite(&key(name), value);
            }
        }
        return;
    }
    if o.velocity != [0.0; 2] {
        v.fail(
            &key("path"),
            "give an obstacle a velocity or a path, not both".into(),
        );
    }
    if o.path.len() < 2 {
        v.fail(
            &key("path"),
            format!("needs at least two [t, x, y] points, got {}", o.path.len()),
        );
    }
    for (j, point) in o.path.iter().enumerate() {
        v.finite_all(&format!("obstacles.{i}.path.{j}"), point);
    }
    if let Some(j) = o.path.windows(2).position(|w| w[1][0] <= w[0][0]) {
        v.fail(
            &key("path"),
            format!(
                "times must increase strictly: point {} at t = {} s follows t = {} s",
                j + 1,
                o.path[j + 1][0],
                o.path[j][0]
            ),
        );
    }
    let start = o.center_at(0.0);
    if (o.x - start[0]).abs() > 1e-9 || (o.y - start[1]).abs() > 1e-9 {
        v.fail(
            &key("x"),
            format!(
                "({}, {}) is not the path's position at t = 0, ({}, {}): leave x and y out \
                 with a path",
                o.x, o.y, start[0], start[1]
            ),
        );
    }
}

pub(super) struct Validator<'a> {
    pub(super) origin: &'a str,
    pub(super) errors: Vec<ScenarioError>,
}

impl Validator<'_> {
    pub(super) fn fail(&mut self, key: &str, message: String) {
        self.errors.push(ScenarioError {
            origin: self.origin.to_string(),
            key: key.to_string(),
            message,
        });
    }
    pub(super) fn finite(&mut self, key: &str, x: f64) -> bool {
        if !x.is_finite() {
            self.fail(key, format!("must be a finite number, got {x}"));
        }
        x.is_finite()
    }
    pub(super) fn finite_all(&mut self, key: &str, xs: &[f64]) {
        for (i, x) in xs.iter().enumerate() {
            self.finite(&format!("{key}.{i}"), *x);
        }
    }
    pub(super) fn positive(&mut self, key: &str, x: f64) {
        if self.finite(key, x) && x <= 0.0 {
            self.fail(key, format!("must be positive, got {x}"));
        }
    }
    pub(super) fn non_negative(&mut self, key: &str, x: f64) {
        if self.finite(key, x) && x < 0.0 {
            self.fail(key, format!("must not be negative, got {x}"));
        }
    }
    fn non_negative_all(&mut self, key: &str, xs: &[f64]) {
        for (i, x) in xs.iter().enumerate() {
            self.non_negative(&format!("{key}.{i}"), *x);
        }
    }
    fn in_range(&mut self, key: &str, n: usize, lo: usize, hi: usize) {
        if n < lo || n > hi {
            self.fail(key, format!("must be in {lo}..={hi}, got {n}"));
        }
    }
}
