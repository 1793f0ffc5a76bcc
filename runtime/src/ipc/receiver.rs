//! The receiving side of a topic: a [`Receiver`] and the border check every sample passes
//! (docs/design.md, "Supervision"), against the clock a consumer knows ([`TickLimit`]).

use super::*;

impl<T: Wire> Topic<T> {
    /// A receiver of samples from any producer epoch (for topics without a single
    /// producer role, such as status).
    pub fn receiver(&self) -> Result<Receiver<T>, IpcError> {
        self.receiver_inner(None)
    }

    /// A receiver that takes only samples of this run, from the active epoch of
    /// `producer`, finite, and in tick order; it counts every sample it refuses.
    pub fn receiver_from(&self, producer: protocol::Role) -> Result<Receiver<T>, IpcError> {
        self.receiver_inner(Some(producer))
    }

    /// [`Topic::receiver_from`] whose process only the samples at sample starts wake (of a
    /// topic of [`protocol::graph::SAMPLE_START_TOPICS`]; of another, every sample).
    pub fn receiver_at_sample_starts(
        &self,
        producer: protocol::Role,
    ) -> Result<Receiver<T>, IpcError> {
        let event = self.sample_starts.as_ref().unwrap_or(&self.event);
        self.receiver_on(Some(producer), event)
    }

    fn receiver_inner(&self, producer: Option<protocol::Role>) -> Result<Receiver<T>, IpcError> {
        self.receiver_on(producer, &self.event)
    }

    fn receiver_on(
        &self,
        producer: Option<protocol::Role>,
        event: &event::PortFactory<ipc::Service>,
    ) -> Result<Receiver<T>, IpcError> {
        let (subscriber, listener) = self.subscribing_ports_on(event)?;
        Ok(Receiver {
            subscriber,
            listener: Some(listener),
            run_id: self.run_id,
            robot: self.robot,
            producer,
            slot: producer.and_then(|role| output_slot(role, self.name)),
            pinned: Cell::new(None),
            schedule: Cell::new(None),
            last_tick: Cell::new(None),
            rejected: Cell::new([0; Rejection::COUNT]),
            taken: Cell::new(0),
            newest_publish_ns: Cell::new(None),
            limit: OnceCell::new(),
            clock_known: Cell::new(false),
            standby_newest: Cell::new(None),
            _payload: PhantomData,
        })
    }
}

/// Receives `T`; its listener is what a WaitSet blocks on.
pub struct Receiver<T: Wire> {
    subscriber: Subscriber<ipc::Service, T, ()>,
    /// `None`: a quiet receiver ([`Receiver::quiet`]).
    listener: Option<Listener<ipc::Service>>,
    run_id: u32,
    robot: u32,
    /// Role whose producer epoch is checked (`None`: any epoch, no tick order).
    producer: Option<protocol::Role>,
    /// Which of the producer's outputs this topic is ([`output_slot`]).
    slot: Option<usize>,
    /// The only publisher taken from, when set ([`Receiver::pin_to`]).
    pinned: Cell<Option<u128>>,
    /// Which epoch of `producer` to take; `None` until the orchestrator has said (a
    /// process that joins a running run takes nothing before that).
    schedule: Cell<Option<EpochSchedule>>,
    last_tick: Cell<Option<u64>>,
    /// Refused samples by [`Rejection`] code, since last taken.
    rejected: Cell<[u64; Rejection::COUNT]>,
    /// Samples taken so far.
    taken: Cell<u64>,
    /// When the newest sample taken was published, monotonic ns.
    newest_publish_ns: Cell<Option<u64>>,
    /// The clock a sample's tick is judged against ([`Receiver::bound_by`]).
    limit: OnceCell<Rc<dyn TickLimit>>,
    /// Whether that clock has known "now" ([`Receiver::clock_known`]).
    clock_known: Cell<bool>,
    /// Newest tick heard from a producer being swapped in or out (not taken).
    standby_newest: Cell<Option<u64>>,
    _payload: PhantomData<T>,
}

impl<T: Wire> Receiver<T> {
    /// The receiver without its listener: no publisher wakes it, so a sample costs its
    /// publisher no system call for it; its samples are taken when the process wakes for
    /// something else (in lockstep: a role's control topic, `process::Member`; the
    /// orchestrator's inputs that come before a tick's command, `run::multiproc`).
    pub fn quiet(mut self) -> Receiver<T> {
        self.listener = None;
        self
    }

    /// The listener its publishers wake (`None`: a quiet receiver).
    pub fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }

    /// The next acceptable sample, if any, with its publish-to-receipt latency in ns.
    /// Refused samples are counted and skipped.
    pub fn receive(&self) -> Result<Option<(T, u64)>, IpcError> {
        Ok(self
            .receive_with_origin()?
            .map(|(m, latency, _)| (m, latency)))
    }

    /// [`Receiver::receive`], with the iceoryx2 id of the sample's publisher.
    pub fn receive_with_origin(&self) -> Result<Option<(T, u64, u128)>, IpcError> {
        // Nothing is judged before the orchestrator has named the producers and, for a
        // bound receiver, before its clock knows "now" (a process that joins a real-time
        // run may hear the schedule before the clock's start).
        if self.producer.is_some() && (self.schedule.get().is_none() || !self.clock_known()) {
            return Ok(None);
        }
        loop {
            let Some(sample) = self.subscriber.receive().map_err(ctx("receiving"))? else {
                return Ok(None);
            };
            let message = *sample.payload();
            let origin = sample.origin().value();
            let latency = monotonic_ns().saturating_sub(message.header().publish_ns);
            match self.check(&message, origin) {
                Ok(EpochVerdict::Take) => {
                    self.taken.set(self.taken.get() + 1);
                    self.newest_publish_ns
                        .set(Some(message.header().publish_ns));
                    return Ok(Some((message, latency, origin)));
                }
                Ok(_) => {
                    let tick = message.header().tick;
                    self.standby_newest
                        .set(self.standby_newest.get().max(Some(tick)));
                }
                Err(reason) => {
                    let mut counts = self.rejected.get();
                    counts[reason as usize] += 1;
                    self.rejected.set(counts);
                }
            }
        }
    }

    /// The border check (docs/design.md, "Supervision"), in one place. A sample of a producer
    /// being swapped in or out is [`EpochVerdict::Standby`]: skipped, not an error.
    /// Whether the bound clock (if any) knows "now". A clock once known stays known, so
    /// it is asked only until then (in real time asking reads the wall clock).
    fn clock_known(&self) -> bool {
        if self.clock_known.get() {
            return true;
        }
        let known = self.limit.get().is_none_or(|l| {
            l.newest_tick(false)
                .or_else(|| l.newest_tick(true))
                .is_some()
        });
        self.clock_known.set(known);
        known
    }

    /// The order matters: who sent it (run, epoch, publisher) before what it says, so a
    /// stranger's sample is never blamed on the producer ([`Rejection::blames_producer`]).
    fn check(&self, message: &T, origin: u128) -> Result<EpochVerdict, Rejection> {
        let h = message.header();
        if h.run_id != self.run_id {
            return Err(Rejection::WrongRun);
        }
        if h.robot != self.robot {
            return Err(Rejection::WrongRobot);
        }
        if self.pinned.get().is_some_and(|id| id != origin) {
            return Err(Rejection::UnknownPublisher);
        }
        let content = || message.content_rejection().map_or(Ok(()), Err);
        let (Some(role), Some(schedule)) = (self.producer, self.schedule.get()) else {
            // Any producer (a fleet's other robot, `Member::peer_input`): what it says,
            // and its tick against the clock when bound to one.
            content()?;
            return self.against_clock(h).map(|()| EpochVerdict::Take);
        };
        let verdict = schedule.judge(role, h.epoch, h.tick);
        if verdict == EpochVerdict::Reject {
            return Err(Rejection::WrongEpoch);
        }
        // Until the producer's announcement is known here (a moment after it joins),
        // its epoch alone vouches for it.
        let pin = self
            .slot
            .and_then(|slot| schedule.publisher(role, h.epoch, slot));
        if pin.is_some_and(|id| id != origin) {
            return Err(Rejection::UnknownPublisher);
        }
        if verdict == EpochVerdict::Standby {
            return Ok(EpochVerdict::Standby);
        }
        content()?;
        self.against_clock(h)?;
        if self.last_tick.get().is_some_and(|last| h.tick < last) {
            return Err(Rejection::TickBackwards);
        }
        self.last_tick.set(Some(h.tick));
        Ok(EpochVerdict::Take)
    }

    /// A sample's tick and time judged against the clock it is bound to, if any
    /// ([`Receiver::bound_by`]), refreshed once before a sample is refused: a sample may
    /// overtake the control message that let its producer make it.
    fn against_clock(&self, h: &protocol::Header) -> Result<(), Rejection> {
        let Some(limit) = self.limit.get() else {
            return Ok(());
        };
        let ahead = |refresh| limit.newest_tick(refresh).is_none_or(|n| h.tick > n);
        if ahead(false) && ahead(true) {
            return Err(Rejection::TickAhead);
        }
        let tick_time_s = h.tick as f64 * limit.dt_s();
        if (h.time_s - tick_time_s).abs() > TIME_TOLERANCE_S {
            return Err(Rejection::TimeMismatch);
        }
        Ok(())
    }

    /// Takes samples only from the iceoryx2 publisher `id` from now on (the control topic:
    /// the orchestrator's); others are refused as [`Rejection::UnknownPublisher`].
    pub fn pin_to(&self, id: u128) {
        self.pinned.set(Some(id));
    }

    /// Judges every sample's tick and time against `limit` from now on (once; later calls
    /// change nothing): a sample ahead of what its producer can have made by now is
    /// refused as [`Rejection::TickAhead`] and changes nothing.
    pub fn bound_by(&self, limit: Rc<dyn TickLimit>) {
        let _ = self.limit.set(limit);
    }

    /// Takes samples by `schedule` from now on. When the producers of the role change,
    /// ticks are checked afresh.
    pub fn follow(&self, schedule: EpochSchedule) {
        let Some(role) = self.producer else {
            return;
        };
        let r = role as usize;
        let changed = self.schedule.replace(Some(schedule)).is_none_or(|old| {
            (old.active[r], old.next[r], old.switch_tick[r])
                != (
                    schedule.active[r],
                    schedule.next[r],
                    schedule.switch_tick[r],
                )
        });
        if changed {
            self.last_tick.set(None);
        }
    }

    /// Whether a sample is waiting (without taking it).
    pub fn has_samples(&self) -> bool {
        self.subscriber.has_samples().unwrap_or(false)
    }

    /// Consumes the pending wake-ups, so a WaitSet does not fire again for them.
    pub fn clear_wakeups(&self) {
        if let Some(listener) = &self.listener {
            let _ = listener.try_wait(|_| {});
        }
    }
}

impl<T: Wire> Receiver<T> {
    /// Attaches this receiver's listener to `waitset`; keep the guard while waiting.
    pub fn attach<'w>(
        &'w self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> Result<WaitSetGuard<'w, 'w, ipc::Service>, IpcError> {
        attach_input(waitset, self)
    }

    /// Every pending sample, after clearing the wake-ups (so none is missed).
    pub fn drain(&self, each: impl FnMut(T, u64)) -> Result<(), IpcError> {
        self.clear_wakeups();
        self.take(each)
    }

    /// Every pending sample, straight from shared memory (no system call). The caller
    /// must [`clear_wakeups`](Self::clear_wakeups) and take once more before it blocks.
    pub fn take(&self, mut each: impl FnMut(T, u64)) -> Result<(), IpcError> {
        while let Some((message, latency)) = self.receive()? {
            each(message, latency);
        }
        Ok(())
    }
}

/// Real time: how many ticks a sample may be ahead of the consumer's clock (the producer's
/// clock is the same `CLOCK_MONOTONIC`; the slack covers rounding at a tick's edge).
pub const TICK_SLACK: u64 = 2;
/// Largest difference between a sample's time and its tick's, s (both are `tick * dt`).
pub const TIME_TOLERANCE_S: f64 = 1e-6;

/// What a consumer knows of "now", so that no sample can move it: the newest tick any
/// producer can have published (docs/design.md, "Supervision").
pub trait TickLimit {
    /// The newest tick a producer can have published by now (`None`: none yet). With
    /// `refresh`, after taking what the clock's source has pending.
    fn newest_tick(&self, refresh: bool) -> Option<u64>;
    /// The inner tick, s.
    fn dt_s(&self) -> f64;
}

/// What the role runtime needs of an input, whatever it carries (every [`Receiver`]).
pub trait Input {
    /// The listener a WaitSet blocks on (`None`: a quiet receiver, which nothing wakes).
    fn listener(&self) -> Option<&Listener<ipc::Service>>;
    /// Whether a sample is waiting (without taking it).
    fn has_samples(&self) -> bool;
    fn clear_wakeups(&self);
    fn follow(&self, schedule: EpochSchedule);
    /// See [`Receiver::bound_by`].
    fn bound_by(&self, limit: Rc<dyn TickLimit>);
    /// Refused samples by [`Rejection`] code since the last call.
    fn take_rejections(&self) -> [u64; Rejection::COUNT];
    /// The role whose samples this input takes (`None`: any sender).
    fn producer(&self) -> Option<protocol::Role>;
    /// How many samples it has taken so far.
    fn taken(&self) -> u64;
    /// When the newest sample taken was published, monotonic ns (`None`: none taken).
    fn newest_publish_ns(&self) -> Option<u64>;
    /// Newest tick published by the replacement (or the retiring producer) of the role and
    /// not taken, since the last call: how the orchestrator sees a replacement warm up.
    fn take_standby_newest(&self) -> Option<u64>;
}

impl<T: Wire> Input for Receiver<T> {
    fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }
    fn has_samples(&self) -> bool {
        Receiver::has_samples(self)
    }
    fn clear_wakeups(&self) {
        Receiver::clear_wakeups(self);
    }
    fn follow(&self, schedule: EpochSchedule) {
        Receiver::follow(self, schedule);
    }
    fn bound_by(&self, limit: Rc<dyn TickLimit>) {
        Receiver::bound_by(self, limit);
    }
    fn take_rejections(&self) -> [u64; Rejection::COUNT] {
        self.rejected.replace([0; Rejection::COUNT])
    }
    fn producer(&self) -> Option<protocol::Role> {
        self.producer
    }
    fn taken(&self) -> u64 {
        self.taken.get()
    }
    fn newest_publish_ns(&self) -> Option<u64> {
        self.newest_publish_ns.get()
    }
    fn take_standby_newest(&self) -> Option<u64> {
        self.standby_newest.take()
    }
}

/// A clock `ticks` ahead of another: what another robot of a fleet can have published by
/// now ([`MAX_TICKS_APART`]).
pub struct Ahead<L: TickLimit> {
    pub clock: Rc<L>,
    pub ticks: u64,
}

impl<L: TickLimit> TickLimit for Ahead<L> {
    fn newest_tick(&self, refresh: bool) -> Option<u64> {
        (self.clock.newest_tick(refresh)).map(|tick| tick + self.ticks)
    }

    fn dt_s(&self) -> f64 {
        self.clock.dt_s()
    }
}
