//! Goals from outside the run (a live view's client): where a sink hands them to the
//! record, and what it can see of them after.

use protocol::Goal;
use std::sync::mpsc::{SendError, Sender};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// Where a sink hands a run its goals ([`crate::RunStart::goals`],
/// [`crate::Recorder::goal_inbox`]): the record takes them from `sender` and sets them at a
/// sample boundary; `board` shows which goals the robot may come to rest at.
#[derive(Debug, Clone)]
pub struct GoalInbox {
    sender: Sender<Goal>,
    /// Kept by the record ([`crate::Recorder::goal_set`]).
    pub(crate) board: GoalBoard,
}

impl GoalInbox {
    pub(crate) fn new(sender: Sender<Goal>, board: GoalBoard) -> GoalInbox {
        GoalInbox { sender, board }
    }

    /// Hands `goal` to the record, on the board as waiting until it is set; an error once
    /// the record takes no more ([`crate::Recorder::stop_taking_goals`]).
    pub fn send(&self, goal: Goal) -> Result<(), SendError<Goal>> {
        self.board.lock().waiting = Some(goal.position);
        let sent = self.sender.send(goal);
        if sent.is_err() {
            self.board.lock().waiting = None;
        }
        sent
    }

    /// The goal in force and the newest one handed on and not set yet, if any (m): where
    /// the robot may come to rest.
    pub fn goals(&self) -> ([f64; 2], Option<[f64; 2]>) {
        let board = self.board.lock();
        (board.in_force, board.waiting)
    }
}

/// What [`GoalInbox::goals`] reads, kept by the record.
#[derive(Debug, Clone)]
pub(crate) struct GoalBoard(Arc<Mutex<Board>>);

#[derive(Debug)]
struct Board {
    in_force: [f64; 2],
    waiting: Option<[f64; 2]>,
}

impl GoalBoard {
    /// A robot driving to `in_force` (m), with nothing waiting.
    pub(crate) fn new(in_force: [f64; 2]) -> GoalBoard {
        GoalBoard(Arc::new(Mutex::new(Board {
            in_force,
            waiting: None,
        })))
    }

    /// `goal` is set: in force, and no longer waiting (a newer one may wait still).
    pub(crate) fn set(&self, goal: [f64; 2]) {
        let mut board = self.lock();
        board.in_force = goal;
        if board.waiting == Some(goal) {
            board.waiting = None;
        }
    }

    /// The record takes no goals any more: what waited is never set.
    pub(crate) fn closed(&self) {
        self.lock().waiting = None;
    }

    fn lock(&self) -> MutexGuard<'_, Board> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_goal_waits_until_it_is_set_and_none_waits_once_the_record_takes_no_more() {
        let (sender, received) = std::sync::mpsc::channel();
        let board = GoalBoard::new([1.0, 2.0]);
        let inbox = GoalInbox::new(sender, board.clone());
        assert_eq!(inbox.goals(), ([1.0, 2.0], None));
        inbox.send(Goal::at([3.0, 4.0])).unwrap();
        assert_eq!(received.recv().unwrap().position, [3.0, 4.0]);
        assert_eq!(inbox.goals(), ([1.0, 2.0], Some([3.0, 4.0])));
        // A newer goal came while the first was being set: it still waits.
        inbox.send(Goal::at([5.0, 6.0])).unwrap();
        board.set([3.0, 4.0]);
        assert_eq!(inbox.goals(), ([3.0, 4.0], Some([5.0, 6.0])));
        board.set([5.0, 6.0]);
        assert_eq!(inbox.goals(), ([5.0, 6.0], None));
        // The record's outcome: a goal that waited is never set, and none is taken after.
        inbox.send(Goal::at([7.0, 8.0])).unwrap();
        board.closed();
        drop(received);
        assert_eq!(inbox.goals(), ([5.0, 6.0], None));
        assert!(inbox.send(Goal::at([9.0, 9.0])).is_err());
        assert_eq!(inbox.goals(), ([5.0, 6.0], None));
    }
}
