//! Every scenario key, read from the schema the parser and the validator use (the types
//! of this module, through `schemars`): its type in words, its unit, its default and the
//! first sentence of its doc comment. `scmpc keys` prints them; the errors of a file or a
//! `--set` use them to say what a value must be and which key was meant.

use super::{LidarConfig, LiveConfig, Scenario};
use serde_json::Value;

/// One scenario key.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyDoc {
    /// Dotted key as `--set` takes it; `<i>` stands for an element's index in a list of
    /// tables (`obstacles.<i>.radius`), `<name>` for a name of a table of names.
    pub key: String,
    /// What a value must be, in words (`a number`, `one of "ekf", "passthrough"`).
    pub kind: String,
    /// The unit its name ends in (`_s`: `s`), empty where the name carries none.
    pub unit: &'static str,
    /// The default (the paper's value), as TOML; `none` where a key has none.
    pub default: String,
    /// The first sentence of its doc comment.
    pub meaning: String,
}

/// Every key of a scenario, in the schema's order.
pub fn catalogue() -> Vec<KeyDoc> {
    let schema = serde_json::to_value(schemars::schema_for!(Scenario)).unwrap_or(Value::Null);
    let defaults = default_document();
    let mut keys = Vec::new();
    let walk = Walk {
        defs: schema.get("$defs").unwrap_or(&Value::Null),
        defaults: &defaults,
    };
    walk.node(&schema, "", None, &mut keys);
    keys
}

/// The entry of `key` as written (indices as numbers, `obstacles.3.radius`).
pub fn find(catalogue: &[KeyDoc], key: &str) -> Option<usize> {
    catalogue
        .iter()
        .position(|doc| matches_pattern(&doc.key, key))
}

/// Up to three keys nearest to the unknown `key`, nearest first: keys and sections
/// (`mpc`) spelled alike (list indices aside), and keys of the same name in another
/// section. A key with an index keeps it (`obstacles.2.radius`).
pub fn nearest(catalogue: &[KeyDoc], key: &str) -> Vec<String> {
    let parts: Vec<&str> = key.split('.').collect();
    let typed = without_indices(key);
    let last = typed.rsplit('.').next().unwrap_or("");
    let mut sections: Vec<&str> = (catalogue.iter())
        .filter_map(|doc| doc.key.split_once('.').map(|(section, _)| section))
        .collect();
    sections.dedup();
    let candidates = (catalogue.iter().map(|doc| doc.key.as_str())).chain(sections);
    let mut scored: Vec<(f64, String)> = candidates
        .filter_map(|pattern| {
            let plain = without_indices(pattern);
            let same_name = plain.contains('.') && plain.rsplit('.').next() == Some(last);
            let score = strsim::normalized_levenshtein(&plain, &typed);
            let shown = if pattern.split('.').count() == parts.len() {
                instantiate(pattern, &parts)
            } else {
                pattern.to_string()
            };
            (same_name || score >= 0.7).then_some((if same_name { 1.0 } else { score }, shown))
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.dedup_by(|a, b| a.1 == b.1);
    scored.into_iter().take(3).map(|(_, key)| key).collect()
}

/// A key without its list indices and name placeholders (`obstacles.radius`).
fn without_indices(key: &str) -> String {
    (key.split('.'))
        .filter(|p| p.parse::<usize>().is_err() && !p.starts_with('<'))
        .collect::<Vec<_>>()
        .join(".")
}

/// The unit a key's name ends in.
pub fn unit_of(key: &str) -> &'static str {
    const SUFFIXES: [(&str, &str); 9] = [
        ("_rad_s", "rad/s"),
        ("_m_s", "m/s"),
        ("_ms", "ms"),
        ("_s", "s"),
        ("_m", "m"),
        ("_rad", "rad"),
        ("_deg", "deg"),
        ("_hz", "Hz"),
        ("_m2", "m²"),
    ];
    SUFFIXES
        .iter()
        .find(|(suffix, _)| key.ends_with(suffix))
        .map_or("", |(_, unit)| unit)
}

/// Whether `pattern` (with `<i>` and `<name>`) matches the key `key`.
fn matches_pattern(pattern: &str, key: &str) -> bool {
    let (pattern, key): (Vec<&str>, Vec<&str>) =
        (pattern.split('.').collect(), key.split('.').collect());
    pattern.len() == key.len()
        && pattern.iter().zip(&key).all(|(p, k)| match *p {
            "<i>" => k.parse::<usize>().is_ok(),
            "<name>" => !k.is_empty(),
            _ => p == k,
        })
}

/// `pattern` with its `<i>` and `<name>` taken from the same places of `parts`.
fn instantiate(pattern: &str, parts: &[&str]) -> String {
    pattern
        .split('.')
        .enumerate()
        .map(|(i, p)| match p {
            "<i>" | "<name>" => parts.get(i).copied().unwrap_or(p),
            _ => p,
        })
        .collect::<Vec<_>>()
        .join(".")
}

/// The default scenario as a TOML document, with the sections a document leaves out
/// when they are absent (`[lidar]`, `[live]`) at their defaults.
fn default_document() -> toml::Value {
    let mut doc = toml::Value::try_from(Scenario::default()).unwrap_or(toml::Value::Boolean(false));
    if let toml::Value::Table(table) = &mut doc {
        let sections = [
            ("lidar", toml::Value::try_from(LidarConfig::default())),
            ("live", toml::Value::try_from(LiveConfig::default())),
        ];
        for (name, section) in sections {
            if let Ok(section) = section {
                table.insert(name.into(), section);
            }
        }
        table.insert("extra_roles".into(), toml::Value::Array(Vec::new()));
    }
    doc
}

/// The schema's definitions and the default document, while walking the schema.
struct Walk<'a> {
    defs: &'a Value,
    defaults: &'a toml::Value,
}

impl Walk<'_> {
    /// Adds the keys under `node`, at `prefix`; `meaning` is the description of the field
    /// that holds it, if it has one.
    fn node(&self, node: &Value, prefix: &str, meaning: Option<&str>, keys: &mut Vec<KeyDoc>) {
        let resolved = self.resolve(node);
        let meaning = meaning
            .or_else(|| description(node))
            .or_else(|| description(resolved));
        if let Some(properties) = resolved.get("properties").and_then(Value::as_object) {
            for (name, property) in properties {
                let key = join(prefix, name);
                self.node(property, &key, description(property), keys);
            }
        } else if let Some(items) = self.table_items(resolved) {
            self.node(items, &join(prefix, "<i>"), None, keys);
        } else if let Some(values) = resolved
            .get("additionalProperties")
            .filter(|v| v.is_object())
        {
            self.leaf(values, &join(prefix, "<name>"), meaning, keys);
        } else {
            self.leaf(resolved, prefix, meaning, keys);
        }
    }

    fn leaf(&self, node: &Value, key: &str, meaning: Option<&str>, keys: &mut Vec<KeyDoc>) {
        keys.push(KeyDoc {
            key: key.to_string(),
            kind: self.kind(node),
            unit: unit_of(key),
            default: self.default_of(key),
            meaning: first_sentence(meaning.unwrap_or("")),
        });
    }

    /// `node` with a `$ref`, or an optional (`anyOf` a type and `null`), followed.
    fn resolve<'v>(&'v self, node: &'v Value) -> &'v Value {
        if let Some(name) = node.get("$ref").and_then(Value::as_str) {
            let name = name.rsplit('/').next().unwrap_or("");
            return self.resolve(self.defs.get(name).unwrap_or(&Value::Null));
        }
        if let Some(options) = node.get("anyOf").and_then(Value::as_array) {
            let not_null: Vec<&Value> = options.iter().filter(|o| !is_null(o)).collect();
            if let [only] = not_null[..] {
                return self.resolve(only);
            }
        }
        node
    }

    /// The element schema of a list of tables (`[[obstacles]]`).
    fn table_items<'v>(&'v self, node: &'v Value) -> Option<&'v Value> {
        let items = node.get("items")?;
        self.resolve(items).get("properties").map(|_| items)
    }

    /// What a value must be, in words.
    fn kind(&self, node: &Value) -> String {
        let node = self.resolve(node);
        if let Some(words) = choices(node) {
            return words;
        }
        if let Some(options) = node.get("anyOf").or_else(|| node.get("oneOf")) {
            let kinds: Vec<String> = (options.as_array().into_iter().flatten())
                .filter(|o| !is_null(o))
                .map(|o| self.kind(o))
                .collect();
            return kinds.join(" or ");
        }
        let types: Vec<&str> = match node.get("type") {
            Some(Value::String(t)) => vec![t.as_str()],
            Some(Value::Array(ts)) => ts.iter().filter_map(Value::as_str).collect(),
            _ => Vec::new(),
        };
        match types.iter().find(|t| **t != "null").copied() {
            Some("number") => "a number".into(),
            Some("integer") => match node.get("minimum").and_then(Value::as_f64) {
                Some(min) => format!("a whole number ≥ {min}"),
                None => "a whole number".into(),
            },
            Some("string") => "text".into(),
            Some("boolean") => "true or false".into(),
            Some("array") => self.list_kind(node),
            _ => "a value".into(),
        }
    }

    fn list_kind(&self, node: &Value) -> String {
        let item = node.get("items").map_or("a value".into(), |i| self.kind(i));
        let items = plural(&item);
        match (node.get("minItems"), node.get("maxItems")) {
            (Some(min), Some(max)) if min == max => format!("a list of {min} {items}"),
            _ => format!("a list of {items}"),
        }
    }

    /// The default of `key` as TOML, `none` where the default document has no value.
    fn default_of(&self, key: &str) -> String {
        let value = key
            .split('.')
            .try_fold(self.defaults, |node, part| match node {
                toml::Value::Table(t) => t.get(part),
                toml::Value::Array(a) => a.first().filter(|_| part == "<i>"),
                _ => None,
            });
        value.map_or("none".into(), |v| v.to_string())
    }
}

/// `one of "a", "b"` for an enumeration of words (with or without a doc per word).
fn choices(node: &Value) -> Option<String> {
    let words: Vec<String> = if let Some(values) = node.get("enum").and_then(Value::as_array) {
        values.iter().map(Value::to_string).collect()
    } else {
        let options = node.get("oneOf")?.as_array()?;
        let mut words = Vec::new();
        for option in options {
            match (
                option.get("const"),
                option.get("enum").and_then(Value::as_array),
            ) {
                (Some(word), _) => words.push(word.to_string()),
                (None, Some(values)) => words.extend(values.iter().map(Value::to_string)),
                _ => return None,
            }
        }
        words
    };
    Some(match &words[..] {
        [only] => only.clone(),
        _ => format!("one of {}", words.join(", ")),
    })
}

/// `a number` as `numbers`, `text` as `texts`, `a list of 3 numbers` as `lists of 3 numbers`.
fn plural(kind: &str) -> String {
    let kind = kind.strip_prefix("a ").unwrap_or(kind);
    match kind.split_once(' ') {
        _ if kind == "text" => "texts".into(),
        Some((noun @ ("number" | "list" | "value"), rest)) => format!("{noun}s {rest}"),
        Some(("whole", rest)) => format!("whole {}", plural(rest)),
        _ if kind == "number" || kind == "value" => format!("{kind}s"),
        _ => kind.to_string(),
    }
}

fn is_null(node: &Value) -> bool {
    node.get("type").and_then(Value::as_str) == Some("null")
}

fn description(node: &Value) -> Option<&str> {
    node.get("description").and_then(Value::as_str)
}

fn join(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

/// The first sentence of a doc comment, on one line.
fn first_sentence(text: &str) -> String {
    let paragraph = text.split("\n\n").next().unwrap_or("").replace('\n', " ");
    let end = (paragraph.match_indices(". ").map(|(i, _)| i + 1))
        .find(|&i| {
            !["e.g.", "eq.", "eqs.", "i.e."]
                .iter()
                .any(|a| paragraph[..i].ends_with(a))
        })
        .unwrap_or(paragraph.len());
    paragraph[..end].trim().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_says_what_it_takes_and_what_it_means() {
        let keys = catalogue();
        assert!(keys.len() > 100, "{} keys", keys.len());
        for doc in &keys {
            assert!(!doc.meaning.is_empty(), "`{}` has no doc comment", doc.key);
            assert!(!doc.kind.contains("value"), "`{}`: {}", doc.key, doc.kind);
        }
        let horizon = &keys[find(&keys, "mpc.horizon").expect("mpc.horizon")];
        assert_eq!(
            (horizon.kind.as_str(), horizon.default.as_str()),
            ("a whole number ≥ 0", "8")
        );
        let radius = &keys[find(&keys, "obstacles.3.radius").expect("an obstacle's radius")];
        assert_eq!(radius.key, "obstacles.<i>.radius");
        let kind = &keys[find(&keys, "estimator.kind").expect("estimator.kind")].kind;
        assert_eq!(kind, r#"one of "ekf", "passthrough""#);
        let noise = &keys[find(&keys, "plant.noise_variance").expect("noise")].kind;
        assert_eq!(noise, "a number or a list of 3 numbers");
        assert_eq!(unit_of("planner.speed_m_s"), "m/s");
    }

    #[test]
    fn an_unknown_key_is_near_the_keys_it_was_meant_as() {
        let keys = catalogue();
        assert_eq!(nearest(&keys, "mpc.horizn")[0], "mpc.horizon");
        assert_eq!(nearest(&keys, "obstacles.2.radus")[0], "obstacles.2.radius");
        assert!(nearest(&keys, "mpc.zeta_threshold").contains(&"dfl.zeta_threshold".into()));
        assert!(nearest(&keys, "completely.different").is_empty());
        assert_eq!(nearest(&keys, "mpcc")[0], "mpc");
        assert_eq!(nearest(&keys, "obstacles.radus")[0], "obstacles.<i>.radius");
    }

    #[test]
    fn a_first_sentence_ends_at_its_full_stop_not_at_an_abbreviation() {
        assert_eq!(
            first_sentence("Horizon (eqs. 45, 47). More."),
            "Horizon (eqs. 45, 47)."
        );
        assert_eq!(
            first_sentence("One line\nwrapped. Two."),
            "One line wrapped."
        );
    }
}
