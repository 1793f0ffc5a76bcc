//! Built-in scenarios and loading a scenario from a file plus `--set` overrides.

use protocol::{Scenario, ScenarioError, ScenarioErrors, Validated};
use std::path::Path;

/// Built-in scenarios by name: the files of `scenarios/`, compiled in.
pub const BUILT_IN: &[(&str, &str)] = &[
    ("paper", include_str!("../../scenarios/paper.toml")),
    (
        "paper-noisy",
        include_str!("../../scenarios/paper-noisy.toml"),
    ),
    ("field", include_str!("../../scenarios/field.toml")),
    ("crossing", include_str!("../../scenarios/crossing.toml")),
    ("unmapped", include_str!("../../scenarios/unmapped.toml")),
    ("occluded", include_str!("../../scenarios/occluded.toml")),
    ("swap4", include_str!("../../scenarios/swap4.toml")),
    ("swap8", include_str!("../../scenarios/swap8.toml")),
    ("warehouse", include_str!("../../scenarios/warehouse.toml")),
];

/// The text of a built-in scenario.
pub fn built_in(name: &str) -> Option<&'static str> {
    BUILT_IN
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
}

/// Loads `source` (the name of a built-in scenario, or a file; "paper" when `None`),
/// applies the overrides and validates the result: the one way from the command line to a
/// [`Validated`] scenario, which every executor then takes. Nothing is returned unless all
/// of it is valid; every error names its origin and key.
///
/// A name without a path separator that does not end in `.toml` is a built-in scenario
/// (so a file or directory named `paper` in the working directory does not shadow it);
/// anything else is a file. When neither exists, the error names both possibilities.
pub fn load(source: Option<&str>, overrides: &[String]) -> Result<Validated, ScenarioErrors> {
    let source = source.unwrap_or("paper");
    let fail = |message: String| {
        ScenarioErrors(vec![ScenarioError {
            origin: source.to_string(),
            key: String::new(),
            message,
        }])
    };
    let built_ins = || {
        BUILT_IN
            .iter()
            .map(|(n, _)| *n)
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (origin, text) = if names_built_in(source) {
        let Some(text) = built_in(source) else {
            let file_hint = if Path::new(source).is_file() {
                format!("; to run the file `{source}` here, write `./{source}`")
            } else {
                format!(
                    "; a scenario file is named with a path separator or `.toml` (`./{source}`, `{source}.toml`)"
                )
            };
            return Err(fail(format!(
                "not a built-in scenario ({}){file_hint}",
                built_ins()
            )));
        };
        (format!("built-in scenario `{source}`"), text.to_string())
    } else {
        let text = std::fs::read_to_string(source).map_err(|e| {
            fail(format!(
                "cannot read the scenario file: {e} (a built-in scenario is named without a path separator or `.toml`: {})",
                built_ins()
            ))
        })?;
        (source.to_string(), text)
    };
    let mut scenario = Scenario::from_toml(&text, &origin)?;
    // A file without a `name` is called after itself (not `paper`, the default's name).
    let named = (text.parse::<toml::Table>()).map_or(true, |t| t.contains_key("name"));
    if !named && let Some(stem) = Path::new(source).file_stem() {
        scenario.name = stem.to_string_lossy().into_owned();
    }
    let scenario = scenario.with_overrides(overrides)?;
    let origin = if overrides.is_empty() {
        origin
    } else {
        format!("{origin} with --set")
    };
    scenario.validated(&origin)
}

/// Whether `source` names a built-in scenario rather than a file ([`load`]).
fn names_built_in(source: &str) -> bool {
    !source.contains(std::path::MAIN_SEPARATOR)
        && !source.contains('/')
        && !source.ends_with(".toml")
}

/// Checks that the program of every `[[swap]]` command can be started: `scmpc` (this
/// executable), a path that exists, or a name found in `PATH`.
pub fn check_swap_programs(scenario: &Scenario) -> Result<(), ScenarioErrors> {
    let errors: Vec<ScenarioError> = scenario
        .swap
        .iter()
        .enumerate()
        .filter_map(|(i, swap)| {
            let message = check_swap_command(&swap.command).err()?;
            Some(ScenarioError {
                origin: "scenario".into(),
                key: format!("swap.{i}.command"),
                message,
            })
        })
        .collect();
    if errors.is_empty() {
        Ok(())
    } else {
        Err(ScenarioErrors(errors))
    }
}

/// Whether a swap's command can be started (empty: the built-in process): the same check
/// for the scenario's `[[swap]]` entries and for `scmpc swap` requests.
pub fn check_swap_command(command: &[String]) -> Result<(), String> {
    match command.first() {
        Some(program) if program.trim().is_empty() => Err("the program is empty".into()),
        Some(program) if !program_exists(program) => Err(format!("program `{program}` not found")),
        _ => Ok(()),
    }
}

fn program_exists(program: &str) -> bool {
    if program == "scmpc" {
        return true;
    }
    if program.contains('/') {
        return Path::new(program).is_file();
    }
    std::env::var_os("PATH")
        .is_some_and(|path| std::env::split_paths(&path).any(|dir| dir.join(program).is_file()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_paper_is_the_default_scenario_but_for_its_final_approach() {
        assert_eq!(*load(None, &[]).unwrap(), Scenario::paper());
        assert_eq!(
            Scenario::paper().robot.final_approach,
            protocol::FinalApproach::Paper
        );
        assert_eq!(
            Scenario::default().robot.final_approach,
            protocol::FinalApproach::Settle
        );
    }

    #[test]
    fn paper_noisy_differs_only_in_name_and_noise() {
        let noisy = load(Some("paper-noisy"), &[]).unwrap();
        let mut expected = Scenario {
            name: "paper-noisy".into(),
            ..Scenario::paper()
        };
        expected.plant.noise_variance = protocol::NoiseVariance::Uniform(0.05);
        assert_eq!(*noisy, expected);
    }
}
