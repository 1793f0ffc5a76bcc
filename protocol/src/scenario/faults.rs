//! Faults injected into a run, for tests and demonstrations (docs/design.md, "Deadlines
//! and fallback"), and the sets of samples they act on.

use serde::{Deserialize, Serialize};

/// Samples chosen by a list (`[100, 101]`) or an inclusive range (`"100..=104"`, also
/// `"100..105"`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum SampleSet {
    List(Vec<u64>),
    Range(String),
}

impl Default for SampleSet {
    fn default() -> Self {
        SampleSet::List(Vec::new())
    }
}

impl SampleSet {
    /// The inclusive bounds of a range, or `None` for a list or a malformed range.
    fn range(&self) -> Option<(u64, u64)> {
        let SampleSet::Range(text) = self else {
            return None;
        };
        let (a, b, inclusive) = match text.split_once("..=") {
            Some((a, b)) => (a, b, true),
            None => {
                let (a, b) = text.split_once("..")?;
                (a, b, false)
            }
        };
        let (a, b): (u64, u64) = (a.trim().parse().ok()?, b.trim().parse().ok()?);
        if inclusive {
            Some((a, b))
        } else {
            b.checked_sub(1).map(|b| (a, b))
        }
    }

    pub fn contains(&self, sample: u64) -> bool {
        match self {
            SampleSet::List(list) => list.contains(&sample),
            SampleSet::Range(_) => self.range().is_some_and(|(a, b)| (a..=b).contains(&sample)),
        }
    }

    pub fn is_empty(&self) -> bool {
        match self {
            SampleSet::List(list) => list.is_empty(),
            SampleSet::Range(_) => self.range().is_none_or(|(a, b)| a > b),
        }
    }

    pub(super) fn is_well_formed(&self) -> bool {
        matches!(self, SampleSet::List(_)) || self.range().is_some()
    }
}

/// Faults injected into a run (what they exercise: docs/design.md, "Deadlines and fallback").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct FaultConfig {
    /// Delay added before the MPC publishes a plan, ms. In real time the MPC sleeps it; in
    /// lockstep it is added to the plan's production time, so the plan arrives late by the
    /// same rule as a slow solve.
    pub mpc_delay_ms: f64,
    /// Samples whose plan is delayed.
    pub mpc_delay_samples: SampleSet,
    /// Also delay every n-th sample (`k % n == 0`); 0 = off.
    pub mpc_delay_every: u64,
    /// Samples whose solve is forced to fail (reported as `numerical_error`).
    pub mpc_fail_samples: SampleSet,
    /// The estimator sleeps this long before publishing each estimate, ms (real time: a
    /// slow estimator; lockstep: only slower in wall time).
    pub estimator_delay_ms: f64,
    /// The MPC plans as if there were no obstacles: a stand-in for a faulty MPC, to show
    /// that the DFL's safety check (`dfl.gatekeeper`) keeps the robot out of them anyway.
    pub mpc_ignore_obstacles: bool,
    /// From this run time on, s, the estimator process started first (epoch 0) publishes
    /// estimates with a NaN: a stand-in for a broken producer, to show it is refused, then
    /// treated as failed and restarted (its restart is healthy). `inf` (the default): off.
    pub estimator_nan_from_s: f64,
    /// The tracker holds every publication of tracks this long, ms (real time: a slow
    /// tracker; lockstep: only slower in wall time).
    pub tracker_delay_ms: f64,
    /// Samples whose measurement of the obstacles the tracker drops (it predicts them on
    /// and publishes its tracks older, so the MPC's predicted discs grow).
    pub tracker_drop_samples: SampleSet,
    /// Every sample crossing a link between hosts is held this long by the bridge that
    /// sends it, ms (docs/hosts.md; real time).
    pub link_delay_ms: f64,
    /// Probability that a sample crossing a link is dropped (real time).
    pub link_loss: f64,
    /// Run times `[from, to)`, s, in which every link between hosts is down: the samples
    /// of those times are dropped (real time; `[0, 0]`: never).
    pub link_down_s: [f64; 2],
}

impl Default for FaultConfig {
    fn default() -> Self {
        FaultConfig {
            mpc_delay_ms: 0.0,
            mpc_delay_samples: SampleSet::default(),
            mpc_delay_every: 0,
            mpc_fail_samples: SampleSet::default(),
            estimator_delay_ms: 0.0,
            mpc_ignore_obstacles: false,
            estimator_nan_from_s: f64::INFINITY,
            tracker_delay_ms: 0.0,
            tracker_drop_samples: SampleSet::default(),
            link_delay_ms: 0.0,
            link_loss: 0.0,
            link_down_s: [0.0, 0.0],
        }
    }
}

impl FaultConfig {
    /// The injected delay of plan(`sample`), ns.
    pub fn mpc_delay_ns(&self, sample: u64) -> u64 {
        let chosen = self.mpc_delay_samples.contains(sample)
            || (self.mpc_delay_every > 0 && sample.is_multiple_of(self.mpc_delay_every));
        if chosen && self.mpc_delay_ms > 0.0 {
            (self.mpc_delay_ms * 1e6) as u64
        } else {
            0
        }
    }

    pub fn mpc_fails(&self, sample: u64) -> bool {
        self.mpc_fail_samples.contains(sample)
    }

    /// One line per injected fault, for the summary; empty for a clean run.
    pub fn describe(&self) -> Vec<String> {
        let mut faults = Vec::new();
        let set = |s: &SampleSet| match s {
            SampleSet::List(l) => format!("{l:?}"),
            SampleSet::Range(r) => r.clone(),
        };
        if self.mpc_delay_ms > 0.0 && !self.mpc_delay_samples.is_empty() {
            faults.push(format!(
                "mpc delay {} ms at samples {}",
                self.mpc_delay_ms,
                set(&self.mpc_delay_samples)
            ));
        }
        if self.mpc_delay_ms > 0.0 && self.mpc_delay_every > 0 {
            faults.push(format!(
                "mpc delay {} ms every {} samples",
                self.mpc_delay_ms, self.mpc_delay_every
            ));
        }
        if !self.mpc_fail_samples.is_empty() {
            faults.push(format!(
                "forced solver failure at samples {}",
                set(&self.mpc_fail_samples)
            ));
        }
        if self.estimator_delay_ms > 0.0 {
            faults.push(format!(
                "estimator delay {} ms per estimate",
                self.estimator_delay_ms
            ));
        }
        if self.mpc_ignore_obstacles {
            faults.push("the MPC ignores the obstacles".into());
        }
        if self.estimator_nan_from_s.is_finite() {
            faults.push(format!(
                "the first estimator publishes NaN from {} s",
                self.estimator_nan_from_s
            ));
        }
        if self.tracker_delay_ms > 0.0 {
            faults.push(format!(
                "tracker delay {} ms per publication",
                self.tracker_delay_ms
            ));
        }
        if !self.tracker_drop_samples.is_empty() {
            faults.push(format!(
                "the tracker drops its measurements at samples {}",
                set(&self.tracker_drop_samples)
            ));
        }
        if self.link_delay_ms > 0.0 {
            faults.push(format!("links delayed {} ms", self.link_delay_ms));
        }
        if self.link_loss > 0.0 {
            faults.push(format!("links lose {} of their samples", self.link_loss));
        }
        if self.link_is_ever_down() {
            let [from, to] = self.link_down_s;
            faults.push(format!("links down from {from} s to {to} s"));
        }
        faults
    }

    /// Whether any fault acts on the links between hosts (`fault.link_*`).
    pub fn acts_on_links(&self) -> bool {
        self.link_delay_ms > 0.0 || self.link_loss > 0.0 || self.link_is_ever_down()
    }

    /// These faults without those on the links between hosts.
    pub fn without_link_faults(&self) -> FaultConfig {
        let none = FaultConfig::default();
        FaultConfig {
            link_delay_ms: none.link_delay_ms,
            link_loss: none.link_loss,
            link_down_s: none.link_down_s,
            ..self.clone()
        }
    }

    /// Whether `fault.link_down_s` cuts the links at some time.
    pub fn link_is_ever_down(&self) -> bool {
        self.link_down_s[1] > self.link_down_s[0]
    }

    /// Whether the links are down at run time `t_s`.
    pub fn link_down_at(&self, t_s: f64) -> bool {
        (self.link_down_s[0]..self.link_down_s[1]).contains(&t_s)
    }
}
