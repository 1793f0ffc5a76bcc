//! Receiving and recording: every sample filed by its tick as it arrives, and a tick
//! recorded once it is whole, with the plans and the deadline verdicts in sample order.

use super::*;

impl Driver<'_> {
    /// Waits for input (at most [`POLL`]) and files everything received by tick.
    pub(super) fn pump(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<()> {
        ipc::wait(waitset, POLL)?;
        // Ticks already recorded come again only as replays: skipped.
        let cursor = self.cursor;
        let slots = &mut self.slots;
        let newest = &mut self.newest_truth;
        self.session.truth.drain(|m, _| {
            *newest = (*newest).max(Some(m.header.tick));
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.truth = Some(m);
            }
        })?;
        self.session.measurement.drain(|m, _| {
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.measurement = Some(m);
            }
        })?;
        self.session.estimate.drain(|m, _| {
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.estimate = Some(m);
            }
        })?;
        self.session.actuation.drain(|m, l| {
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.actuation = Some((m, l));
            }
        })?;
        let plans = &mut self.plans;
        self.session.plan.drain(|p, _| {
            plans.insert(p.sample, p);
        })?;
        let routes = &mut self.routes;
        self.session.route.drain(|r, _| routes.push(r))?;
        self.take_status()?;
        let verdicts = &mut self.verdicts;
        self.session.deadline.drain(|v, _| {
            verdicts.insert(v.sample, v);
        })?;
        Ok(())
    }

    /// Takes the processes' status reports: refused samples (the orchestrator's own
    /// included) are counted and recorded by reason, and a process that joined the running
    /// loop is told the clock and the schedule.
    fn take_status(&mut self) -> anyhow::Result<()> {
        let mut restarted_ready = Vec::new();
        let mut rejected = Vec::new();
        self.session.status.drain(|s, _| {
            if let Some(joined) = ready_role(&s) {
                restarted_ready.push(joined);
            } else if s.event == StatusEvent::Rejected as u32 {
                rejected.push((
                    Role::from_code(s.role).map_or("unknown", Role::as_str),
                    Role::from_code(s.producer),
                    s.detail,
                    s.count,
                ));
            }
        })?;
        for (producer, code, count) in self.session.take_rejections() {
            rejected.push(("orchestrator", producer, code, count));
        }
        for (consumer, producer, code, count) in rejected {
            let reason = Rejection::ALL.get(code as usize);
            if let (Some(role), true) = (producer, reason.is_some_and(|r| r.blames_producer())) {
                self.blame(role);
            }
            let reason = reason.map_or("unknown", |r| r.as_str());
            *self.rejected.entry(reason.to_string()).or_default() += count;
            self.recorder.event(
                "rejected",
                serde_json::json!({ "consumer": consumer, "reason": reason, "count": count }),
            )?;
        }
        for (role, s) in restarted_ready {
            self.session.pin(role, &s)?;
            // A process joined the running loop: tell it the clock and the schedule, and
            // have every producer repeat its newest sample for it; watch its node.
            self.recorder
                .event("ready", serde_json::json!({ "role": role.as_str() }))?;
            self.last_node_listing = None;
            match self.mode {
                RunMode::Realtime => {
                    self.session
                        .command(ControlCommand::Start, 0, self.start_ns)?
                }
                RunMode::Lockstep => self.session.command(ControlCommand::Epochs, 0, 0)?,
            }
            self.session.command(ControlCommand::Replay, 0, 0)?;
        }
        Ok(())
    }

    /// Records a whole tick; returns an outcome that ends the run.
    pub(super) fn record(&mut self, tick: u64, slot: TickSlot) -> anyhow::Result<Option<Outcome>> {
        let (Some(truth), Some(measurement), Some((act, own_latency))) =
            (slot.truth, slot.measurement, slot.actuation)
        else {
            return Ok(None);
        };
        let inner_steps = self.scenario.timing.inner_steps as u64;
        let l = &mut self.latencies;
        l.hop(
            "control_to_plant",
            u64::from(measurement.header.input_latency_ns),
        );
        // A tick the DFL commanded without an estimate (estimator silent, DFL braking) is
        // recorded with an estimate of NaN.
        self.ticks_without_estimate += u64::from(slot.estimate.is_none());
        let estimate = slot.estimate.unwrap_or(Estimate {
            state: [f64::NAN; 4],
            ..Estimate::default()
        });
        if slot.estimate.is_some() {
            l.hop(
                "measurement_to_estimator",
                u64::from(estimate.header.input_latency_ns),
            );
            l.hop("estimate_to_dfl", u64::from(act.header.input_latency_ns));
        }
        if self.mode == RunMode::Lockstep {
            // In real time the orchestrator drains its buffers periodically: not a hop.
            l.hop("actuation_to_orchestrator", own_latency);
        }
        if !tick.is_multiple_of(inner_steps) && slot.estimate.is_some() {
            let ns = act
                .header
                .publish_ns
                .saturating_sub(measurement.header.publish_ns);
            l.sensor_to_actuator(ns);
            self.last_sensor_to_actuator_ns = Some(ns);
        }
        Ok(self.recorder.tick(&truth, &estimate, &act)?)
    }

    /// Records every route and plan received, then every deadline verdict (the DFL judges
    /// sample k at the start of sample k + 1, after plan(k) was published). Returns
    /// [`Outcome::NoRoute`] when the planner found none.
    pub(super) fn record_plans(&mut self) -> anyhow::Result<Option<Outcome>> {
        let mut no_route = None;
        for route in std::mem::take(&mut self.routes) {
            no_route = no_route.or(self.recorder.route(&route)?);
        }
        while let Some((sample, plan)) = self.plans.pop_first() {
            // A replay repeats a plan already recorded.
            if self.last_plan.is_some_and(|last| sample <= last) {
                continue;
            }
            self.last_plan = Some(sample);
            self.latencies
                .hop("estimate_to_mpc", u64::from(plan.header.input_latency_ns));
            self.recorder.plan(&plan)?;
        }
        while let Some((_, v)) = self.verdicts.pop_first() {
            self.recorder.verdict(&v)?;
        }
        Ok(no_route)
    }
}
