//! The border check on real iceoryx2 topics (each test on a prefix of its own).
use super::*;
use protocol::{Control, ControlCommand, Header, Measurement, Role};

/// A clock by which tick `newest` is the newest any producer can have made.
struct FixedClock(u64);

impl TickLimit for FixedClock {
    fn newest_tick(&self, _refresh: bool) -> Option<u64> {
        Some(self.0)
    }
    fn dt_s(&self) -> f64 {
        0.005
    }
}

fn measurement(tick: u64) -> Measurement {
    Measurement {
        header: Header {
            tick,
            time_s: tick as f64 * 0.005,
            ..Header::default()
        },
        ..Measurement::default()
    }
}

/// Runs `test` with a node on a fresh prefix, then removes the prefix's files.
fn on_fresh_prefix(test: impl FnOnce(&Node<ipc::Service>)) {
    let prefix = new_prefix();
    let node = create_node(&prefix, "test", false).unwrap();
    test(&node);
    drop(node);
    remove_run_resources(&prefix).unwrap();
}

fn refused(counts: [u64; Rejection::COUNT], reason: Rejection) -> u64 {
    counts[reason as usize]
}

#[test]
fn a_sample_ahead_of_the_clock_or_off_its_tick_time_is_refused_and_moves_nothing() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap();
        let plant = topic.sender(0).unwrap();
        let measurements = topic.receiver_from(Role::Plant).unwrap();
        measurements.follow(EpochSchedule::default());
        measurements.bound_by(Rc::new(FixedClock(100)));
        plant.send(measurement(1_000_000)).unwrap();
        let mut off_time = measurement(50);
        off_time.header.time_s += 1e-3;
        plant.send(off_time).unwrap();
        plant.send(measurement(99)).unwrap();
        let (m, _) = measurements.receive().unwrap().unwrap();
        // The forged tick did not become "now": tick 99 is not behind anything.
        assert_eq!(m.header.tick, 99);
        let counts = measurements.take_rejections();
        assert_eq!(refused(counts, Rejection::TickAhead), 1);
        assert_eq!(refused(counts, Rejection::TimeMismatch), 1);
        assert_eq!(counts.iter().sum::<u64>(), 2);
    });
}

#[test]
fn a_receiver_of_any_producer_bound_to_a_clock_refuses_a_sample_ahead_of_it() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap();
        let other_robot = topic.sender(3).unwrap();
        let peer = topic.receiver().unwrap();
        peer.bound_by(Rc::new(FixedClock(100)));
        other_robot.send(measurement(1_000_000)).unwrap();
        other_robot.send(measurement(99)).unwrap();
        let (m, _) = peer.receive().unwrap().unwrap();
        assert_eq!(
            m.header.tick, 99,
            "the forged tick did not hide the next sample"
        );
        assert_eq!(refused(peer.take_rejections(), Rejection::TickAhead), 1);
    });
}

#[test]
fn a_sample_from_another_publisher_than_the_pinned_one_is_refused_whatever_its_header() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap();
        let plant = topic.sender(0).unwrap();
        let intruder = topic.sender(0).unwrap();
        let measurements = topic.receiver_from(Role::Plant).unwrap();
        let mut schedule = EpochSchedule::default();
        let slot = output_slot(Role::Plant, MEASUREMENT).unwrap();
        let mut pins = [0; 2];
        pins[slot] = plant.publisher_id();
        assert!(schedule.pin(Role::Plant, 0, pins));
        // A second announcement for the same epoch changes nothing.
        assert!(!schedule.pin(Role::Plant, 0, [intruder.publisher_id(); 2]));
        measurements.follow(schedule);
        intruder.send(measurement(1)).unwrap();
        plant.send(measurement(2)).unwrap();
        let (m, _) = measurements.receive().unwrap().unwrap();
        assert_eq!(m.header.tick, 2);
        assert!(measurements.receive().unwrap().is_none());
        let counts = measurements.take_rejections();
        assert_eq!(refused(counts, Rejection::UnknownPublisher), 1);
        assert_eq!(counts.iter().sum::<u64>(), 1);
        assert!(!Rejection::UnknownPublisher.blames_producer());
    });
}

#[test]
fn control_is_taken_from_the_orchestrators_publisher_alone_and_only_when_well_formed() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Control>(node, protocol::FIRST_ROBOT, CONTROL).unwrap();
        let orchestrator = topic.sender(0).unwrap();
        let rogue = topic.sender(0).unwrap();
        let control = topic.receiver().unwrap();
        control.pin_to(orchestrator.publisher_id());
        let command = |c: ControlCommand| Control {
            command: c as u32,
            ..Control::default()
        };
        rogue.send(command(ControlCommand::Stop)).unwrap();
        orchestrator
            .send(Control {
                command: 99,
                ..Control::default()
            })
            .unwrap();
        orchestrator.send(command(ControlCommand::Grant)).unwrap();
        let (c, _) = control.receive().unwrap().unwrap();
        assert_eq!(c.command(), Some(ControlCommand::Grant));
        assert!(control.receive().unwrap().is_none());
        let counts = control.take_rejections();
        assert_eq!(refused(counts, Rejection::UnknownPublisher), 1);
        assert_eq!(refused(counts, Rejection::Malformed), 1);
    });
}

#[test]
fn a_sample_of_another_run_is_refused_and_another_type_cannot_open_the_topic() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap();
        let measurements = topic.receiver_from(Role::Plant).unwrap();
        measurements.follow(EpochSchedule::default());
        let stranger = Topic {
            run_id: topic.run_id ^ 1,
            ..open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap()
        };
        let stranger = stranger.sender(0).unwrap();
        stranger.send(measurement(1)).unwrap();
        assert!(measurements.receive().unwrap().is_none());
        assert_eq!(
            refused(measurements.take_rejections(), Rejection::WrongRun),
            1
        );
        // A payload of another type (and size) is not even let onto the topic.
        let other = open_topic::<protocol::Estimate>(node, protocol::FIRST_ROBOT, MEASUREMENT);
        assert!(
            other.is_err(),
            "an estimate type opened the measurement topic"
        );
    });
}

#[test]
fn a_sample_of_another_robot_is_refused_at_the_border_and_not_blamed_on_the_producer() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap();
        let measurements = topic.receiver_from(Role::Plant).unwrap();
        measurements.follow(EpochSchedule::default());
        // A forged sample: this run's id and the active epoch, another robot's.
        let other_robot = Topic {
            robot: protocol::FIRST_ROBOT + 1,
            ..open_topic::<Measurement>(node, protocol::FIRST_ROBOT, MEASUREMENT).unwrap()
        };
        let (forger, plant) = (other_robot.sender(0).unwrap(), topic.sender(0).unwrap());
        forger.send(measurement(1)).unwrap();
        plant.send(measurement(2)).unwrap();
        let (taken, _) = measurements.receive().unwrap().unwrap();
        assert_eq!(
            (taken.header.tick, taken.header.robot),
            (2, protocol::FIRST_ROBOT)
        );
        assert!(measurements.receive().unwrap().is_none());
        let refusals = measurements.take_rejections();
        assert_eq!(refused(refusals, Rejection::WrongRobot), 1);
        assert!(!Rejection::WrongRobot.blames_producer());
    });
}

#[test]
fn two_robots_pipelines_on_one_prefix_have_services_of_their_own() {
    on_fresh_prefix(|node| {
        let robots = [protocol::FIRST_ROBOT, protocol::FIRST_ROBOT + 1];
        let [first, second] = robots.map(|robot| {
            let topic = open_topic::<Measurement>(node, robot, MEASUREMENT).unwrap();
            let measurements = topic.receiver_from(Role::Plant).unwrap();
            measurements.follow(EpochSchedule::default());
            (topic.sender(0).unwrap(), measurements)
        });
        first.0.send(measurement(1)).unwrap();
        second.0.send(measurement(2)).unwrap();
        let taken = |(_, measurements): &(Sender<Measurement>, Receiver<Measurement>)| {
            let (m, _) = measurements.receive().unwrap().unwrap();
            assert!(measurements.receive().unwrap().is_none());
            assert_eq!(measurements.take_rejections(), [0; Rejection::COUNT]);
            (m.header.tick, m.header.robot)
        };
        assert_eq!(taken(&first), (1, robots[0]));
        assert_eq!(taken(&second), (2, robots[1]));
    });
}

#[test]
fn a_process_is_alive_until_it_exits_and_a_zombie_counts_as_dead() {
    assert!(process_alive(std::process::id()));
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    // Exited, not reaped yet: a zombie.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    while process_alive(pid) && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    assert!(!process_alive(pid), "the zombie {pid} counts as alive");
    child.wait().unwrap();
    assert!(!process_alive(pid));
}

#[test]
fn a_receiver_at_sample_starts_is_woken_by_those_samples_alone_and_takes_every_one() {
    use protocol::Estimate;
    let estimate = |tick: u64| Estimate {
        header: Header {
            tick,
            time_s: tick as f64 * 0.005,
            ..Header::default()
        },
        ..Estimate::default()
    };
    on_fresh_prefix(|node| {
        let topic = open_topic::<Estimate>(node, protocol::FIRST_ROBOT, ESTIMATE).unwrap();
        let estimator = topic.sender(0).unwrap().with_ticks_per_sample(10);
        let mpc = topic.receiver_at_sample_starts(Role::Estimator).unwrap();
        let dfl = topic.receiver_from(Role::Estimator).unwrap();
        mpc.follow(EpochSchedule::default());
        dfl.follow(EpochSchedule::default());
        let woken = |receiver: &Receiver<Estimate>| {
            let mut wake_ups = 0;
            (receiver.listener().unwrap())
                .try_wait(|_| wake_ups += 1)
                .unwrap();
            wake_ups > 0
        };
        for tick in 1..10 {
            estimator.send(estimate(tick)).unwrap();
        }
        assert!(!woken(&mpc), "a sample inside a sample woke the MPC");
        assert!(woken(&dfl), "the DFL, woken every tick, was not");
        estimator.send(estimate(10)).unwrap();
        assert!(
            woken(&mpc),
            "the sample starting sample 1 did not wake the MPC"
        );
        let mut ticks = Vec::new();
        mpc.take(|e, _| ticks.push(e.header.tick)).unwrap();
        assert_eq!(ticks, (1..=10).collect::<Vec<_>>());

        // A relay from another host does not know `M`: it announces every sample.
        let relay = wire::relay(node, protocol::FIRST_ROBOT, ESTIMATE).unwrap();
        let inside = estimate(11);
        // SAFETY: an `Estimate` is `#[repr(C)]` of integers and floats (wire.rs).
        let bytes = unsafe {
            std::slice::from_raw_parts(
                &inside as *const Estimate as *const u8,
                size_of::<Estimate>(),
            )
        };
        assert!(relay.relay(bytes, &mut |_| {}).unwrap());
        assert!(woken(&mpc), "a relayed sample did not wake the MPC");
    });
}

#[test]
fn another_robots_sample_may_be_ahead_by_the_lead_a_fleet_allows_in_lockstep_and_no_more() {
    on_fresh_prefix(|node| {
        let topic = open_topic::<Measurement>(node, 1, MEASUREMENT).unwrap();
        let other_robot = topic.sender(0).unwrap();
        let peer = topic.receiver().unwrap();
        peer.bound_by(Rc::new(Ahead {
            clock: Rc::new(FixedClock(100)),
            ticks: MAX_TICKS_APART,
        }));
        other_robot
            .send(measurement(100 + MAX_TICKS_APART))
            .unwrap();
        other_robot
            .send(measurement(101 + MAX_TICKS_APART))
            .unwrap();
        let (m, _) = peer.receive().unwrap().unwrap();
        assert_eq!(m.header.tick, 100 + MAX_TICKS_APART);
        assert!(peer.receive().unwrap().is_none());
        assert_eq!(refused(peer.take_rejections(), Rejection::TickAhead), 1);
    });
}
