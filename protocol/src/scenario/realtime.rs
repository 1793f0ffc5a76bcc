//! How the processes of a real-time run are scheduled (docs/running.md, "Real-time
//! scheduling"): `SCHED_FIFO` at priorities that follow the data path, memory locked, and
//! optionally pinned to CPUs, where the machine allows it.

use serde::{Deserialize, Serialize};

/// `realtime.priority`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(try_from = "PriorityText", into = "PriorityText")]
pub enum Priority {
    /// `"auto"`: [`AUTO_TOP_PRIORITY`] (or the highest the machine grants, if lower), where
    /// the machine grants real-time scheduling at all.
    Auto,
    /// `"off"`: every process at the normal policy, as the machine starts it.
    Off,
    /// A number: the priority of the top tier (the DFL and the plant); checked by
    /// [`RealtimeConfig::problems`].
    Top(i64),
}

/// The top tier's priority with `realtime.priority = "auto"`: ros2_control's real-time
/// default, above the kernel's threaded interrupt handlers (50 too), below its watchdogs
/// (99).
pub const AUTO_TOP_PRIORITY: u8 = 50;
/// Tiers below the top one ([`RealtimeConfig::problems`]): the lowest has priority top − 3,
/// which must be at least 1.
pub const TIERS_BELOW_TOP: u8 = 3;
/// The highest `SCHED_FIFO` priority of Linux.
pub const MAX_FIFO_PRIORITY: u8 = 99;

/// `realtime.priority` as written: a word or a number.
#[derive(Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
enum PriorityText {
    Word(String),
    Number(i64),
}

impl TryFrom<PriorityText> for Priority {
    type Error = String;

    fn try_from(text: PriorityText) -> Result<Priority, String> {
        match text {
            PriorityText::Word(word) if word == "auto" => Ok(Priority::Auto),
            PriorityText::Word(word) if word == "off" => Ok(Priority::Off),
            PriorityText::Word(word) => Err(format!(
                "`{word}` is none of \"auto\", \"off\" or a priority {}..={MAX_FIFO_PRIORITY}",
                TIERS_BELOW_TOP + 1
            )),
            PriorityText::Number(n) => Ok(Priority::Top(n)),
        }
    }
}

impl From<Priority> for PriorityText {
    fn from(priority: Priority) -> PriorityText {
        match priority {
            Priority::Auto => PriorityText::Word("auto".into()),
            Priority::Off => PriorityText::Word("off".into()),
            Priority::Top(n) => PriorityText::Number(n),
        }
    }
}

/// `[realtime]`: the scheduling of a real-time run's processes on their host. Lockstep
/// and in-process runs ignore it (lockstep polls its peers with yields, which a
/// `SCHED_FIFO` poller would starve, and needs no deadline to be met).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RealtimeConfig {
    /// `SCHED_FIFO` priority of the top tier (the DFL and the plant; the tiers below get
    /// one less each): `auto`, `off` or a number.
    pub priority: Priority,
    /// The CPUs every process of the run is pinned to (empty: wherever the machine lets
    /// it run).
    pub cpus: Vec<usize>,
}

impl Default for RealtimeConfig {
    fn default() -> Self {
        RealtimeConfig {
            priority: Priority::Auto,
            cpus: Vec::new(),
        }
    }
}

/// Linux's largest CPU number plus one (`CPU_SETSIZE`).
pub const CPU_SET_SIZE: usize = 1024;

impl RealtimeConfig {
    /// Every problem of the section, with its key (`realtime.*`). Whether the CPUs exist
    /// on the machine is checked where the run starts.
    pub fn problems(&self) -> Vec<(&'static str, String)> {
        let mut problems = Vec::new();
        let lowest = i64::from(TIERS_BELOW_TOP) + 1;
        if let Priority::Top(n) = self.priority
            && !(lowest..=i64::from(MAX_FIFO_PRIORITY)).contains(&n)
        {
            problems.push((
                "realtime.priority",
                format!(
                    "{n} is not in {lowest}..={MAX_FIFO_PRIORITY} (the top tier's \
                     priority; the tiers below it take the {TIERS_BELOW_TOP} below)"
                ),
            ));
        }
        if let Some(&cpu) = self.cpus.iter().find(|&&cpu| cpu >= CPU_SET_SIZE) {
            problems.push((
                "realtime.cpus",
                format!("CPU {cpu} is not below {CPU_SET_SIZE}"),
            ));
        }
        let mut sorted = self.cpus.clone();
        sorted.sort_unstable();
        if sorted.windows(2).any(|w| w[0] == w[1]) {
            problems.push(("realtime.cpus", "a CPU is named twice".into()));
        }
        problems
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_priority_is_a_word_or_a_number_in_range() {
        let parse = |text: &str| toml::from_str::<RealtimeConfig>(text).map(|c| c.priority);
        assert_eq!(parse("priority = \"auto\"").unwrap(), Priority::Auto);
        assert_eq!(parse("priority = \"off\"").unwrap(), Priority::Off);
        assert_eq!(parse("priority = 70").unwrap(), Priority::Top(70));
        let word = parse("priority = \"fifo\"").unwrap_err().to_string();
        assert!(word.contains("`fifo` is none of"), "{word}");
        for n in [3, 100, -1] {
            let config = RealtimeConfig {
                priority: Priority::Top(n),
                cpus: Vec::new(),
            };
            assert_eq!(config.problems()[0].0, "realtime.priority", "{n}");
        }
        for n in [4, 99] {
            let config = RealtimeConfig {
                priority: Priority::Top(n),
                cpus: Vec::new(),
            };
            assert!(config.problems().is_empty(), "{n}");
        }
    }

    #[test]
    fn the_cpus_are_distinct_and_below_the_set_size() {
        let problems = |cpus: Vec<usize>| {
            RealtimeConfig {
                priority: Priority::Auto,
                cpus,
            }
            .problems()
        };
        assert!(problems(vec![0, 1]).is_empty());
        assert_eq!(problems(vec![1, 1])[0].1, "a CPU is named twice");
        assert!(problems(vec![CPU_SET_SIZE])[0].1.contains("not below"));
    }

    #[test]
    fn it_goes_back_to_toml_as_it_came() {
        for config in [
            RealtimeConfig::default(),
            RealtimeConfig {
                priority: Priority::Top(60),
                cpus: vec![1],
            },
            RealtimeConfig {
                priority: Priority::Off,
                cpus: Vec::new(),
            },
        ] {
            let text = toml::to_string(&config).unwrap();
            assert_eq!(toml::from_str::<RealtimeConfig>(&text).unwrap(), config);
        }
    }
}
