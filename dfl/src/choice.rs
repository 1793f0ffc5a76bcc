//! The DFL's choice when every choice touches (docs/safety.md, "When every choice
//! touches"): which trajectory to fly when a new plan is refused or the committed one is
//! found unsafe, by the rule of [`least_unsafe`].

use crate::covering_element;
use crate::gatekeeper::{Gatekeeper, Moment, Verdict};
use protocol::{Intervention, Plan};

/// A trajectory the DFL can fly when a new plan is refused or the committed trajectory is
/// found unsafe, each flown from the current estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Candidate {
    /// Braking at once (`U2 = 0`, zeta to zero), then staying at rest.
    Brake,
    /// The committed trajectory flown on: its plan's elements before `stages`, then the
    /// brake.
    Committed { stages: u32 },
    /// The new plan that the commit check refused (the MPC's escape plan among them:
    /// `protocol::Prediction::ConstantVelocity`): its elements before `stages`, then
    /// the brake.
    Refused { stages: u32 },
}

/// The least unsafe of `candidates`, each with what the check found of it (docs/safety.md,
/// "When every choice touches"): one that enters no grown disc; else one that comes to
/// rest before its first predicted contact (passive safety: if the obstacle comes, it
/// meets a robot at rest), the one that keeps the most clearance among those; only where
/// every candidate would still move at a contact, the one that keeps the most clearance.
/// Ties go to the candidate given first. None for no candidates.
pub fn least_unsafe(candidates: &[(Candidate, Verdict)]) -> Option<(Candidate, Verdict)> {
    // Larger is better: clear, then at rest at every contact, then the clearance.
    let rank = |v: &Verdict| match v.deepest() {
        None => (2, 0.0),
        Some(clearance) => (u8::from(v.rests_before_contact()), clearance),
    };
    candidates.iter().copied().reduce(|best, next| {
        let (b, n) = (rank(&best.1), rank(&next.1));
        if n.0 > b.0 || (n.0 == b.0 && n.1 > b.1) {
            next
        } else {
            best
        }
    })
}

/// What the DFL flies when the new plan (if any) is not committed.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Choice {
    /// The committed trajectory, safe, goes on; or the robot brakes already.
    Unchanged,
    /// The brake: for the committed plan's sample, if one is given up; what the check
    /// found of the brake; the committed trajectory's clearance.
    Brake(Option<u64>, Verdict, f64),
    /// The committed trajectory flown on though it touches, or cut short (its sample, what
    /// the check found, the elements flown before the brake, the whole trajectory's
    /// clearance): every other choice is worse ([`least_unsafe`]).
    Fly(u64, Verdict, u32, f64),
    /// Every other choice touches; the refused plan is the least unsafe (what the check
    /// found at the re-check's growth, nothing if it clears that; the elements flown
    /// before the brake).
    Refused(Verdict, u32),
}

/// The most candidates [`choose`] weighs: the brake, and each plan whole and cut short
/// after each of its elements.
const MOST_CANDIDATES: usize = 1 + 2 * protocol::MAX_HORIZON;

/// The candidates of one choice, without allocating.
struct Candidates {
    list: [(Candidate, Verdict); MOST_CANDIDATES],
    count: usize,
}

impl Candidates {
    fn add(&mut self, candidate: (Candidate, Verdict)) {
        self.list[self.count] = candidate;
        self.count += 1;
    }

    fn all(&self) -> &[(Candidate, Verdict)] {
        &self.list[..self.count]
    }
}

/// The choice of the least unsafe trajectory when the committed one (`flying`) is unsafe
/// or there is none, and a new plan was `refused`, checked `at` (the moment, the state,
/// the re-check's growth): the committed trajectory if it is safe; else the
/// [`least_unsafe`] of the brake, the committed trajectory and the refused plan, in that
/// order on ties; and, if none of those is clear, of each plan cut short after each of
/// its elements from now on (then braking: a switch to the backup trajectory earlier, as
/// the gatekeeper of Agrawal and Panagou searches for), after the whole plans on ties. A
/// plan cut short may come to rest before the obstacle comes where the whole one would
/// still move.
pub(crate) fn choose(
    gatekeeper: &Gatekeeper,
    at: (Moment, [f64; 4], f64),
    flying: Option<&Plan>,
    refused: Option<&Plan>,
) -> Choice {
    let (now, z, grow) = at;
    let fly = flying.map(|plan| (plan.sample, gatekeeper.verdict(plan, now, z, grow)));
    if fly.is_some_and(|(_, v)| v.clear()) || (fly.is_none() && refused.is_none()) {
        return Choice::Unchanged;
    }
    let brake = gatekeeper.brake_verdict(z, now, grow);
    let mut candidates = Candidates {
        list: [(Candidate::Brake, brake); MOST_CANDIDATES],
        count: 1,
    };
    if let (Some(plan), Some((_, verdict))) = (flying, fly) {
        let stages = plan.horizon;
        candidates.add((Candidate::Committed { stages }, verdict));
    }
    if let Some(plan) = refused {
        let stages = plan.horizon;
        let verdict = gatekeeper.verdict(plan, now, z, grow);
        candidates.add((Candidate::Refused { stages }, verdict));
    }
    if !least_unsafe(candidates.all()).is_some_and(|(_, v)| v.clear()) {
        for (plan, committed) in [(flying, true), (refused, false)] {
            let Some(plan) = plan else { continue };
            let Some(first) = covering_element(plan, now.sample) else {
                continue;
            };
            let mut cut = *plan;
            for stages in (first as u32 + 1..plan.horizon).rev() {
                cut.horizon = stages;
                let verdict = gatekeeper.verdict(&cut, now, z, grow);
                let candidate = if committed {
                    Candidate::Committed { stages }
                } else {
                    Candidate::Refused { stages }
                };
                candidates.add((candidate, verdict));
            }
        }
    }
    let whole_clearance = fly.and_then(|(_, v)| v.deepest()).unwrap_or(0.0);
    match least_unsafe(candidates.all()) {
        Some((Candidate::Committed { stages }, verdict)) => match fly {
            Some((plan_sample, _)) => Choice::Fly(plan_sample, verdict, stages, whole_clearance),
            None => Choice::Unchanged,
        },
        Some((Candidate::Refused { stages }, verdict)) => Choice::Refused(verdict, stages),
        _ => Choice::Brake(
            fly.map(|(plan_sample, _)| plan_sample),
            brake,
            whole_clearance,
        ),
    }
}

/// How the DFL reports flying a trajectory that touches: [`Intervention::LeastUnsafe`],
/// or [`Intervention::MovingContact`] where it is predicted to touch while the robot
/// still moves.
pub(crate) fn touching(verdict: Verdict) -> Intervention {
    if verdict.rests_before_contact() {
        Intervention::LeastUnsafe
    } else {
        Intervention::MovingContact
    }
}
