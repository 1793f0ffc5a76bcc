use super::*;

#[test]
fn a_replacement_is_standby_while_warming_and_takes_over_at_its_switch_tick() {
    let mut s = EpochSchedule::default();
    assert_eq!(s.judge(Role::Mpc, 0, 100), EpochVerdict::Take);
    assert_eq!(s.judge(Role::Mpc, 7, 100), EpochVerdict::Reject);
    s.announce(Role::Mpc, 1);
    assert_eq!(s.judge(Role::Mpc, 0, 100), EpochVerdict::Take);
    assert_eq!(s.judge(Role::Mpc, 1, 100), EpochVerdict::Standby);
    s.schedule_switch(Role::Mpc, 200);
    assert_eq!(s.judge(Role::Mpc, 0, 199), EpochVerdict::Take);
    assert_eq!(s.judge(Role::Mpc, 1, 199), EpochVerdict::Standby);
    assert_eq!(s.judge(Role::Mpc, 1, 200), EpochVerdict::Take);
    assert_eq!(s.judge(Role::Mpc, 0, 200), EpochVerdict::Standby);
    // Other roles are untouched.
    assert_eq!(s.judge(Role::Estimator, 1, 200), EpochVerdict::Reject);
    // The next swap replaces the producer of the newest ticks.
    assert_eq!(s.current(Role::Mpc), 1);
    s.announce(Role::Mpc, 2);
    assert_eq!(s.judge(Role::Mpc, 1, 500), EpochVerdict::Take);
    assert_eq!(s.judge(Role::Mpc, 0, 500), EpochVerdict::Reject);
    s.schedule_switch(Role::Mpc, 600);
    s.unschedule(Role::Mpc);
    assert_eq!(s.judge(Role::Mpc, 1, 700), EpochVerdict::Take);
    assert_eq!(s.judge(Role::Mpc, 2, 700), EpochVerdict::Standby);
    s.activate(Role::Mpc, 3);
    assert_eq!(s.judge(Role::Mpc, 1, 700), EpochVerdict::Reject);
    assert_eq!(s.judge(Role::Mpc, 3, 0), EpochVerdict::Take);
}

#[test]
fn codes_counts_and_lengths_outside_their_type_are_malformed() {
    let verdict = DeadlineVerdict {
        status: PLAN_MISSING,
        ..DeadlineVerdict::default()
    };
    assert!(verdict.well_formed());
    for bad in [
        DeadlineVerdict { met: 2, ..verdict },
        DeadlineVerdict {
            status: 17,
            ..verdict
        },
        DeadlineVerdict {
            fallback: 99,
            ..verdict
        },
    ] {
        assert!(!bad.well_formed(), "{bad:?}");
    }
    let plan = Plan {
        status: PlanStatus::Solved as u32,
        horizon: 8,
        ..Plan::default()
    };
    assert!(plan.well_formed());
    assert!(
        !Plan {
            horizon: MAX_HORIZON as u32 + 1,
            ..plan
        }
        .well_formed()
    );
    assert!(!Plan { status: 9, ..plan }.well_formed());
    let request = SwapRequest::new(1, Role::Mpc, &["scmpc".into(), "mpc".into()]).unwrap();
    assert!(request.well_formed());
    assert!(!SwapRequest { role: 9, ..request }.well_formed());
    // A command that does not end in NUL, or runs past the buffer.
    assert!(
        !SwapRequest {
            command_len: 4,
            ..request
        }
        .well_formed()
    );
    assert!(
        !SwapRequest {
            command_len: MAX_COMMAND_BYTES as u32 + 1,
            ..request
        }
        .well_formed()
    );
    let status = Status {
        event: StatusEvent::Rejected as u32,
        detail: Rejection::Malformed as u32,
        producer: NO_PRODUCER,
        ..Status::default()
    };
    assert!(status.well_formed());
    assert!(
        !Status {
            detail: Rejection::COUNT as u32,
            ..status
        }
        .well_formed()
    );
    assert!(!Status { event: 7, ..status }.well_formed());
    assert!(
        !Control {
            command: 6,
            ..Control::default()
        }
        .well_formed()
    );
}

#[test]
fn a_swap_request_carries_its_command_line_exactly() {
    let command: Vec<String> = ["scmpc", "mpc", "--set", "mpc.horizon=10", ""]
        .map(String::from)
        .to_vec();
    let request = SwapRequest::new(7, Role::Mpc, &command).unwrap();
    assert_eq!(request.command(), command);
    assert!(
        SwapRequest::new(7, Role::Mpc, &[])
            .unwrap()
            .command()
            .is_empty()
    );
    assert!(SwapRequest::new(7, Role::Mpc, &["a\0b".into()]).is_none());
    let long = vec!["x".repeat(MAX_COMMAND_BYTES)];
    assert!(SwapRequest::new(7, Role::Mpc, &long).is_none());
}

#[test]
fn a_swap_reply_message_is_cut_at_a_character_boundary() {
    let text = "é".repeat(MAX_REPLY_BYTES);
    let reply = SwapReply::default().with_message(&text);
    assert_eq!(reply.message(), "é".repeat(MAX_REPLY_BYTES / 2));
}
