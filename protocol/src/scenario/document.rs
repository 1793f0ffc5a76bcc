//! A scenario as a TOML document: parsed with errors that name the dotted key (and the
//! line), written back with every key spelled out, and changed by `--set KEY=VALUE`.

use super::*;

/// One thing wrong with a scenario: where it came from, the dotted key, and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScenarioError {
    /// The file, `--set`, or `built-in`.
    pub origin: String,
    /// Dotted key, e.g. `mpc.gamma`; empty when the document as a whole is unreadable.
    pub key: String,
    pub message: String,
}

impl fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.key.is_empty() {
            write!(f, "{}: {}", self.origin, self.message)
        } else {
            write!(f, "{}: `{}`: {}", self.origin, self.key, self.message)
        }
    }
}

/// All the problems found in one scenario, reported together.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct ScenarioErrors(pub Vec<ScenarioError>);

impl fmt::Display for ScenarioErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "invalid scenario:")?;
        for e in &self.0 {
            writeln!(f, "  {e}")?;
        }
        Ok(())
    }
}

impl Scenario {
    /// Parses a TOML document; `origin` names it in errors (a path, or `built-in`).
    pub fn from_toml(text: &str, origin: &str) -> Result<Scenario, ScenarioErrors> {
        toml::from_str::<Scenario>(text).map_err(|e| {
            let at = e.span().map(|span| span.start);
            let (key, line) = at.map_or((String::new(), 0), |offset| key_at(text, offset));
            let message = in_words(&key, None, e.message().trim());
            let message = if line > 0 {
                format!("{message} (line {line})")
            } else {
                message
            };
            ScenarioErrors(vec![ScenarioError {
                origin: origin.to_string(),
                key,
                message,
            }])
        })
    }

    /// The scenario as a TOML document, every key spelled out.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_else(|e| format!("# cannot render scenario: {e}\n"))
    }

    /// [`Scenario::with_overrides_from`] `--set`.
    pub fn with_overrides(&self, overrides: &[String]) -> Result<Scenario, ScenarioErrors> {
        self.with_overrides_from(overrides, "--set")
    }

    /// Applies `KEY=VALUE` overrides in order (the scenario's faults first, below). `KEY`
    /// is a dotted path that must already exist (array elements by index:
    /// `obstacles.0.radius`); `VALUE` is a TOML value, or a bare word taken as a string
    /// (`mpc.constraint=euclidean`). Nothing is applied unless every override is valid;
    /// each one that is not is one error, labelled with `origin` (the option it came
    /// from: `--set`, `--grid ...`).
    ///
    /// The scenario's own faults (`fault.*`) are set first: a fleet's robot's first key
    /// of `robots.<i>.fault` starts its faults from them ([`make_room`]), so its faults
    /// are the same whichever order the two are given in.
    pub fn with_overrides_from(
        &self,
        overrides: &[String],
        origin: &str,
    ) -> Result<Scenario, ScenarioErrors> {
        let error = |key: &str, message: String| ScenarioError {
            origin: origin.to_string(),
            key: key.to_string(),
            message,
        };
        let mut doc = toml::Value::try_from(self)
            .map_err(|e| ScenarioErrors(vec![error("", e.to_string())]))?;
        // Keys a document leaves out when they are empty can be set too, and `[live]`,
        // which a document never holds.
        if let toml::Value::Table(table) = &mut doc {
            table
                .entry("extra_roles")
                .or_insert_with(|| toml::Value::Array(Vec::new()));
            if let Some(live) = (self.live.as_ref()).and_then(|l| toml::Value::try_from(l).ok()) {
                table.insert("live".into(), live);
            }
        }
        let mut scenario = self.clone();
        let mut errors = Vec::new();
        let (faults, others): (Vec<&String>, Vec<&String>) = overrides
            .iter()
            .partition(|item| sets_scenario_faults(item));
        for item in faults.into_iter().chain(others) {
            let Some((key, raw)) = item.split_once('=') else {
                errors.push(error(item, "expected KEY=VALUE".into()));
                continue;
            };
            let (key, raw) = (key.trim(), raw.trim());
            make_room(&mut doc, key);
            let Some(slot) = lookup_mut(&mut doc, key) else {
                errors.push(error(key, missing_key(&doc, key)));
                continue;
            };
            let before = std::mem::replace(slot, parse_value(raw));
            match doc.clone().try_into::<Scenario>() {
                Ok(changed) => scenario = changed,
                Err(e) => {
                    errors.push(error(key, in_words(key, Some(raw), e.message().trim())));
                    if let Some(slot) = lookup_mut(&mut doc, key) {
                        *slot = before;
                    }
                }
            }
        }
        if errors.is_empty() {
            Ok(scenario)
        } else {
            Err(ScenarioErrors(errors))
        }
    }
}

/// Whether the override `item` (`KEY=VALUE`) sets the scenario's `[fault]`.
fn sets_scenario_faults(item: &str) -> bool {
    let key = item.split_once('=').map_or(item, |(key, _)| key).trim();
    key == "fault" || key.starts_with("fault.")
}

/// Why `key` is not in `doc`: an index past the end of its list (how many there are), or
/// a key no scenario has (with the keys nearest to it).
fn missing_key(doc: &toml::Value, key: &str) -> String {
    let parts: Vec<&str> = key.split('.').collect();
    for end in 1..parts.len() {
        let prefix = parts[..end].join(".");
        if let (Some(toml::Value::Array(list)), Ok(index)) =
            (lookup(doc, &prefix), parts[end].parse::<usize>())
            && index >= list.len()
        {
            let of_tables =
                (keys::catalogue().iter()).any(|k| k.key.starts_with(&format!("{prefix}.<i>.")));
            return match list.len() {
                0 if of_tables => format!(
                    "`{prefix}` is empty in this scenario (a file adds one as `[[{prefix}]]`)"
                ),
                0 => {
                    format!("`{prefix}` is empty in this scenario (set it whole: `{prefix}=[...]`)")
                }
                1 => format!("`{prefix}` has 1 entry, `{prefix}.0`"),
                n => format!(
                    "`{prefix}` has {n} entries, `{prefix}.0` to `{prefix}.{}`",
                    n - 1
                ),
            };
        }
    }
    unknown_key(key)
}

/// `unknown key`, with the keys nearest to it.
fn unknown_key(key: &str) -> String {
    let near = keys::nearest(&keys::catalogue(), key);
    match &near[..] {
        [] => "unknown key (`scmpc keys` lists every key)".into(),
        [only] => format!("unknown key; did you mean `{only}`?"),
        [first @ .., last] => {
            let first: Vec<String> = first.iter().map(|k| format!("`{k}`")).collect();
            format!(
                "unknown key; did you mean {} or `{last}`?",
                first.join(", ")
            )
        }
    }
}

/// A parser's message about `key` (set to `value`, where known) in words: an unknown key
/// with the keys nearest to it; a value of the wrong type or an unknown word with what
/// the key takes ([`keys::KeyDoc::kind`]). A message of the scenario's own types (a goal's
/// length, a priority's words) is already in words and kept.
fn in_words(key: &str, value: Option<&str>, message: &str) -> String {
    // `unknown field `radus`, expected one of ...`: the field may be inside `key` (an
    // inline table, a list of them).
    if let Some(field) = (message.strip_prefix("unknown field `")).and_then(|r| r.split('`').next())
    {
        return match key {
            key if key == field || key.ends_with(&format!(".{field}")) => unknown_key(key),
            "" => format!("`{field}`: {}", unknown_key(field)),
            key => format!(
                "`{field}` in it: {}",
                unknown_key(&format!("{key}.{field}"))
            ),
        };
    }
    const SERDE_WORDING: [&str; 5] = [
        "invalid type",
        "invalid value",
        "invalid length",
        "unknown variant",
        "data did not match",
    ];
    let catalogue = keys::catalogue();
    let doc = keys::find(&catalogue, key).map(|i| &catalogue[i]);
    match doc {
        Some(doc) if SERDE_WORDING.iter().any(|w| message.starts_with(w)) => {
            let unit = match doc.unit {
                "" => String::new(),
                unit => format!(" ({unit})"),
            };
            match value {
                Some(value) => format!("bad value `{value}`: expected {}{unit}", doc.kind),
                None => format!("expected {}{unit}", doc.kind),
            }
        }
        _ => match value {
            Some(value) => format!("bad value `{value}`: {message}"),
            None => message.to_string(),
        },
    }
}

/// Makes a place for `key` where the document leaves out what a scenario may lack: a key
/// of `[lidar]` gives a scenario without one the default lidar (of `[live]`, the default
/// live view), a key of a fleet's robot's `fault` gives that robot the scenario's
/// `[fault]` to change, and an obstacle's `known` may be set where it was left to its
/// default.
fn make_room(doc: &mut toml::Value, key: &str) {
    let toml::Value::Table(table) = doc else {
        return;
    };
    if key.starts_with("lidar.")
        && !table.contains_key("lidar")
        && let Ok(lidar) = toml::Value::try_from(super::LidarConfig::default())
    {
        table.insert("lidar".into(), lidar);
    }
    if key.starts_with("live.")
        && !table.contains_key("live")
        && let Ok(live) = toml::Value::try_from(super::LiveConfig::default())
    {
        table.insert("live".into(), live);
    }
    let robot = (key.strip_prefix("robots."))
        .and_then(|rest| rest.split_once(".fault."))
        .and_then(|(i, _)| i.parse::<usize>().ok());
    let fault = table.get("fault").cloned();
    if let Some(toml::Value::Array(robots)) = table.get_mut("robots")
        && let Some(toml::Value::Table(entry)) = robot.and_then(|i| robots.get_mut(i))
        && let Some(mut fault) = fault
    {
        // A robot without a host of its own has no link for the link faults to act on
        // (its own are refused: `check_robot`), so it takes the others alone.
        let local = (entry.get("host").and_then(toml::Value::as_str)).is_none_or(str::is_empty);
        if let (true, toml::Value::Table(keys)) = (local, &mut fault) {
            keys.retain(|key, _| !key.starts_with("link_"));
        }
        entry.entry("fault").or_insert(fault);
    }
    // A robot's keys a document leaves out until they are set, as the robot has them.
    let own = (key.strip_prefix("robots."))
        .and_then(|rest| rest.split_once('.'))
        .and_then(|(i, field)| Some((i.parse::<usize>().ok()?, field)));
    let value_of = |table: &toml::map::Map<String, toml::Value>, section: &str, key: &str| {
        table.get(section).and_then(|s| s.get(key)).cloned()
    };
    let unset = own.and_then(|(i, field)| {
        let value = match field {
            "host" => Some(toml::Value::String(String::new())),
            "host_roles" => toml::Value::try_from(super::HostRoles::default()).ok(),
            "radius_m" => value_of(table, "robot", "radius_m"),
            "v_max" => value_of(table, "mpc", "v_max"),
            _ => None,
        };
        Some((i, field, value?))
    });
    if let (Some(toml::Value::Array(robots)), Some((i, field, value))) =
        (table.get_mut("robots"), unset)
        && let Some(toml::Value::Table(entry)) = robots.get_mut(i)
    {
        entry.entry(field).or_insert(value);
    }
    let index = (key.strip_prefix("obstacles."))
        .and_then(|rest| rest.strip_suffix(".known"))
        .and_then(|i| i.parse::<usize>().ok());
    if let Some(toml::Value::Array(obstacles)) = table.get_mut("obstacles")
        && let Some(toml::Value::Table(obstacle)) = index.and_then(|i| obstacles.get_mut(i))
    {
        obstacle
            .entry("known")
            .or_insert(toml::Value::Boolean(true));
    }
}

/// The dotted key of the `key = value` line holding byte `offset` of a TOML document,
/// with the 1-based line number (array-of-tables elements get their index).
fn key_at(text: &str, offset: usize) -> (String, usize) {
    let line_no = text[..offset.min(text.len())].matches('\n').count();
    let mut table = String::new();
    let mut array_counts: Vec<(String, usize)> = Vec::new();
    // The line itself too: a table header names its own table.
    for line in text.lines().take(line_no + 1) {
        let l = line.trim();
        if let Some(name) = l.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = name.trim().to_string();
            let index = match array_counts.iter_mut().find(|(n, _)| *n == name) {
                Some((_, count)) => {
                    *count += 1;
                    *count - 1
                }
                None => {
                    array_counts.push((name.clone(), 1));
                    0
                }
            };
            table = format!("{name}.{index}");
        } else if let Some(name) = l.strip_prefix('[').and_then(|r| r.split(']').next()) {
            table = name.trim().to_string();
        }
    }
    let line = text.lines().nth(line_no).unwrap_or("");
    let key = line.split('=').next().unwrap_or("").trim();
    let dotted = match (table.is_empty(), key.is_empty() || key.starts_with('[')) {
        (_, true) => table,
        (true, false) => key.to_string(),
        (false, false) => format!("{table}.{key}"),
    };
    (dotted, line_no + 1)
}

/// The value at a dotted path (`a.b.0.c`), if it exists.
fn lookup<'v>(doc: &'v toml::Value, key: &str) -> Option<&'v toml::Value> {
    key.split('.').try_fold(doc, |node, part| match node {
        toml::Value::Table(t) => t.get(part),
        toml::Value::Array(a) => part.parse::<usize>().ok().and_then(|i| a.get(i)),
        _ => None,
    })
}

/// The value at a dotted path (`a.b.0.c`), if it exists, to change it.
fn lookup_mut<'v>(doc: &'v mut toml::Value, key: &str) -> Option<&'v mut toml::Value> {
    key.split('.').try_fold(doc, |node, part| match node {
        toml::Value::Table(t) => t.get_mut(part),
        toml::Value::Array(a) => part.parse::<usize>().ok().and_then(|i| a.get_mut(i)),
        _ => None,
    })
}

/// A `--set` value: a TOML value if it parses as one, else the bare text as a string.
fn parse_value(raw: &str) -> toml::Value {
    format!("v = {raw}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()))
}
