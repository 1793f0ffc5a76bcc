//! The map of the house cannot go stale: the crate table of docs/design.md ("Crates and
//! what they may depend on") is the one `cargo metadata` reports, crate by crate, and no
//! role crate reaches a transport.

use std::collections::{BTreeMap, BTreeSet};

/// What a crate depends on: the workspace's crates, and the transports (iceoryx2, zenoh,
/// `(optional)` after one that only a feature brings in).
type Dependencies = BTreeMap<String, (BTreeSet<String>, BTreeSet<String>)>;

const TRANSPORTS: [&str; 2] = ["iceoryx2", "zenoh"];

/// What `cargo ARGS` prints, in the workspace (it must succeed).
fn cargo(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "cargo {args:?}: {stderr}");
    String::from_utf8(out.stdout).unwrap()
}

/// `cargo metadata` of the workspace's crates.
fn metadata() -> serde_json::Value {
    let out = cargo(&[
        "metadata",
        "--format-version",
        "1",
        "--no-deps",
        "--offline",
    ]);
    serde_json::from_str(&out).unwrap()
}

/// The roles added as examples to copy (`examples/roles/*`): role crates, which the crate
/// table of docs/design.md leaves out.
fn example_roles() -> Vec<String> {
    let metadata = metadata();
    let packages = metadata["packages"].as_array().unwrap();
    packages
        .iter()
        .filter(|p| {
            let manifest = p["manifest_path"].as_str().unwrap();
            manifest.contains("/examples/roles/")
        })
        .map(|p| p["name"].as_str().unwrap().to_string())
        .collect()
}

/// The normal dependencies of every workspace crate, as `cargo metadata` declares them.
fn from_cargo() -> Dependencies {
    let metadata = metadata();
    let packages = metadata["packages"].as_array().unwrap();
    let members: BTreeSet<&str> = packages
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    packages
        .iter()
        .map(|p| {
            let (mut crates, mut transports) = (BTreeSet::new(), BTreeSet::new());
            for d in p["dependencies"].as_array().unwrap() {
                let name = d["name"].as_str().unwrap();
                if !d["kind"].is_null() {
                    continue; // dev- and build-dependencies
                }
                if members.contains(name) {
                    crates.insert(name.to_string());
                } else if TRANSPORTS.contains(&name) {
                    let optional = d["optional"].as_bool().unwrap_or(false);
                    transports.insert(if optional {
                        format!("{name} (optional)")
                    } else {
                        name.to_string()
                    });
                }
            }
            (
                p["name"].as_str().unwrap().to_string(),
                (crates, transports),
            )
        })
        .collect()
}

/// The rows of the crate table of docs/design.md: crate, holds, depends on, transports.
fn from_design() -> Dependencies {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/design.md");
    let text = std::fs::read_to_string(path).unwrap();
    let section = text
        .split("## Crates and what they may depend on")
        .nth(1)
        .expect("docs/design.md has a section `Crates and what they may depend on`");
    // A cell lists names by commas; a parenthesis after a name qualifies it.
    let names = |cell: &str| -> BTreeSet<String> {
        let mut depth = 0;
        let cell: String = cell
            .chars()
            .map(|c| {
                depth += i32::from(c == '(') - i32::from(c == ')');
                if c == ',' && depth > 0 { ';' } else { c }
            })
            .collect();
        cell.split(',')
            .map(|n| n.trim())
            .filter(|n| !n.is_empty())
            .map(|n| match n.split_once(" (optional") {
                Some((name, _)) => format!("{name} (optional)"),
                None => n.to_string(),
            })
            .collect()
    };
    section
        .lines()
        .skip_while(|l| !l.starts_with("| crate |"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|row| {
            let cells: Vec<&str> = row.split('|').map(str::trim).collect();
            let name = cells[1].trim_matches('`').to_string();
            (name, (names(cells[3]), names(cells[4])))
        })
        .collect()
}

#[test]
fn the_crate_table_of_the_design_is_the_one_cargo_metadata_reports() {
    let _machine = crate::common::machine_shared();
    let (mut cargo, design) = (from_cargo(), from_design());
    let examples = example_roles();
    cargo.retain(|name, _| !examples.contains(name));
    for (crates, _) in cargo.values_mut() {
        crates.retain(|c| !examples.contains(c));
    }
    assert_eq!(
        cargo.keys().collect::<Vec<_>>(),
        design.keys().collect::<Vec<_>>(),
        "the crates of the workspace against the rows of docs/design.md"
    );
    for (name, declared) in &cargo {
        assert_eq!(
            &design[name], declared,
            "crate `{name}`: docs/design.md says (depends on, transports) {:?}, Cargo.toml {:?}",
            design[name], declared
        );
    }
}

/// The transports `cargo tree -p name` resolves for a crate, with the features its
/// dependencies turn on (protocol's iceoryx2 is the runtime's to ask for).
fn linked_transports(name: &str) -> Vec<String> {
    let tree = cargo(&[
        "tree",
        "-p",
        name,
        "-e",
        "normal",
        "--prefix",
        "none",
        "--offline",
    ]);
    tree.lines()
        .filter(|l| TRANSPORTS.iter().any(|t| l.starts_with(&format!("{t} v"))))
        .map(str::to_string)
        .collect()
}

#[test]
fn no_role_crate_depends_on_another_role_the_runtime_or_a_transport() {
    let _machine = crate::common::machine_shared();
    let declared = from_cargo();
    let examples = example_roles();
    for role in ROLE_CRATES
        .iter()
        .copied()
        .chain(examples.iter().map(String::as_str))
    {
        let (crates, transports) = &declared[role];
        assert_eq!(
            crates.iter().collect::<Vec<_>>(),
            ["protocol"],
            "{role} depends on {crates:?}"
        );
        assert!(transports.is_empty(), "{role} declares {transports:?}");
        let linked = linked_transports(role);
        assert!(linked.is_empty(), "cargo tree -p {role} lists {linked:?}");
    }
}

/// The role crates (with the example roles, [`example_roles`]): they depend on
/// `protocol` alone, link no transport and read no clock (the `Task` contract). The robot, the plant role played by a ROS 2 robot, links Zenoh
/// for its ROS 2 link: its task code reads no clock ([`is_task_code`]), its link does.
const ROLE_CRATES: [&str; 7] = [
    "plant",
    "estimator",
    "mpc",
    "dfl",
    "planner",
    "tracker",
    "lidar",
];

/// The task code of every role: the role crates' sources, the example roles', and the
/// robot's but for its links (`robot/src/link.rs` and its modules), the resources its
/// tasks are handed, which may read a clock.
fn is_task_code(name: &str) -> bool {
    ROLE_CRATES
        .iter()
        .any(|r| name.starts_with(&format!("{r}/src/")))
        || name.starts_with("examples/roles/")
        || (name.starts_with("robot/src/")
            && name != "robot/src/link.rs"
            && !name.starts_with("robot/src/link/"))
}

/// The code lines of `text` that read a clock: `Instant::now`, `SystemTime`, or a clock
/// function of the runtime's (`clock::monotonic_ns`) rather than the context's.
fn clock_readings(text: &str) -> Vec<(usize, &str)> {
    code_lines(text)
        .into_iter()
        .filter(|(_, l)| {
            ["Instant::now", "SystemTime", "clock::monotonic_ns"]
                .iter()
                .any(|c| l.contains(c))
        })
        .collect()
}

#[test]
fn no_role_crate_reads_a_clock_its_context_does_not_hand_it() {
    let _machine = crate::common::machine_shared();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut readings = Vec::new();
    for path in library_sources() {
        let name = path.strip_prefix(root).unwrap().display().to_string();
        if !is_task_code(&name) {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        for (line, code) in clock_readings(&text) {
            readings.push(format!("{name}:{line}: {}", code.trim()));
        }
    }
    assert!(readings.is_empty(), "clocks read:\n{}", readings.join("\n"));
    // The search sees what it is meant to, and not in a test module.
    let sample = "fn f() {\n    let t = std::time::Instant::now();\n    runtime::clock::monotonic_ns();\n    context.monotonic_ns();\n}\n#[cfg(test)]\nmod tests {\n    fn t() { SystemTime::now(); }\n}\n";
    assert_eq!(
        clock_readings(sample),
        [
            (2, "    let t = std::time::Instant::now();"),
            (3, "    runtime::clock::monotonic_ns();")
        ]
    );
    assert!(is_task_code("robot/src/task.rs") && is_task_code("tracker/src/lib.rs"));
    assert!(!is_task_code("robot/src/link.rs") && !is_task_code("runtime/src/clock.rs"));
}

#[test]
fn the_robot_depends_on_neither_the_simulated_plant_nor_the_hosts() {
    let _machine = crate::common::machine_shared();
    // What it shares with them is `protocol`'s (the plant role's output) and `net`'s (the
    // Zenoh session).
    let (crates, _) = &from_cargo()["robot"];
    for other in ["plant", "hosts"] {
        assert!(!crates.contains(other), "robot depends on {crates:?}");
    }
}

#[test]
fn the_record_links_no_transport() {
    let _machine = crate::common::machine_shared();
    let linked = linked_transports("record");
    assert!(linked.is_empty(), "cargo tree -p record lists {linked:?}");
}

/// Lines of code of a Rust source: neither blank nor comment lines, nor the inline test
/// modules (`#[cfg(test)] mod ... { ... }`), each with its line number.
fn code_lines(text: &str) -> Vec<(usize, &str)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut code = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let next = lines.get(i + 1).map(|l| l.trim_start());
        let test_module = lines[i].trim() == "#[cfg(test)]"
            && next.is_some_and(|l| l.starts_with("mod ") || l.starts_with("pub mod "));
        if test_module && next.is_some_and(|l| l.ends_with('{')) {
            let mut depth = 0i64;
            let mut j = i + 1;
            while j < lines.len() {
                depth +=
                    lines[j].matches('{').count() as i64 - lines[j].matches('}').count() as i64;
                if depth <= 0 {
                    break;
                }
                j += 1;
            }
            i = j + 1;
            continue;
        }
        let trimmed = lines[i].trim();
        if !trimmed.is_empty() && !trimmed.starts_with("//") {
            code.push((i + 1, lines[i]));
        }
        i += 1;
    }
    code
}

/// Every function of `code` longer than `limit` code lines: `(line, length)`.
fn long_functions(code: &[(usize, &str)], limit: usize) -> Vec<(usize, usize)> {
    let is_fn = |l: &str| {
        let l = l.trim_start();
        let l = l
            .strip_prefix("pub(crate) ")
            .or(l.strip_prefix("pub(super) "))
            .unwrap_or(l);
        let l = l.strip_prefix("pub ").unwrap_or(l);
        let l = l.strip_prefix("const ").unwrap_or(l);
        l.strip_prefix("unsafe ").unwrap_or(l).starts_with("fn ")
    };
    let mut long = Vec::new();
    for (k, &(line, text)) in code.iter().enumerate() {
        if !is_fn(text) {
            continue;
        }
        let (mut depth, mut opened, mut length) = (0i64, false, 0);
        for &(_, l) in &code[k..] {
            length += 1;
            depth += l.matches('{').count() as i64 - l.matches('}').count() as i64;
            opened |= l.contains('{');
            if (opened && depth <= 0) || (!opened && l.trim_end().ends_with(';')) {
                break;
            }
        }
        if length > limit {
            long.push((line, length));
        }
    }
    long
}

/// The Rust sources of the workspace outside tests, benchmarks and examples.
fn library_sources() -> Vec<std::path::PathBuf> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    let mut dirs = vec![root.to_path_buf()];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            if path.is_dir() {
                // `examples/roles` is code of the house; `examples/python` is Python's.
                let skipped = ["target", "tests", "benches", "python", ".git"];
                if !skipped.contains(&name.as_str()) {
                    dirs.push(path);
                }
            } else if name.ends_with(".rs") && name != "tests.rs" {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

#[test]
fn no_source_file_passes_600_code_lines_and_no_function_80() {
    let _machine = crate::common::machine_shared();
    let mut over = Vec::new();
    for path in library_sources() {
        let text = std::fs::read_to_string(&path).unwrap();
        let code = code_lines(&text);
        let name = path
            .strip_prefix(env!("CARGO_MANIFEST_DIR"))
            .unwrap()
            .display()
            .to_string();
        if code.len() > 600 {
            over.push(format!("{name}: {} code lines", code.len()));
        }
        for (line, length) in long_functions(&code, 80) {
            over.push(format!("{name}:{line}: a function of {length} code lines"));
        }
    }
    assert!(
        over.is_empty(),
        "past the house's sizes:\n{}",
        over.join("\n")
    );
    // The counts see what they are meant to: a long function and a test module.
    let sample = format!(
        "fn long() {{\n{}}}\n#[cfg(test)]\nmod tests {{\n    fn t() {{}}\n}}\n",
        "    let x = 1;\n".repeat(90)
    );
    let code = code_lines(&sample);
    assert_eq!(code.len(), 92);
    assert_eq!(long_functions(&code, 80), [(1, 92)]);
}
