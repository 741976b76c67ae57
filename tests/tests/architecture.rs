//! ARCHITECTURE.md's crate table against the workspace as cargo sees it:
//! every member has a row, and each row's "depends on" column lists exactly
//! the workspace crates the member depends on.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

use serde_json::Value;

/// Each workspace member's normal dependencies on other members, from
/// `cargo metadata`.
fn workspace_dependencies() -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let output = Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(&root)
        .output()
        .expect("cargo metadata runs");
    assert!(
        output.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let metadata: Value = serde_json::from_slice(&output.stdout).unwrap();
    let packages = metadata["packages"].as_array().unwrap();
    let members: BTreeSet<String> = packages
        .iter()
        .map(|p| p["name"].as_str().unwrap().to_string())
        .collect();
    packages
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["kind"].is_null())
                .map(|d| d["name"].as_str().unwrap().to_string())
                .filter(|name| members.contains(name))
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

/// The crate table's rows: crate and the crates its second column names.
fn documented_dependencies(text: &str) -> BTreeMap<String, BTreeSet<String>> {
    let table = text
        .split("| crate | depends on |")
        .nth(1)
        .expect("ARCHITECTURE.md has the crate table");
    table
        .lines()
        .skip(2)
        .take_while(|line| line.starts_with('|'))
        .map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let name = cells[1].trim_matches('`').to_string();
            let deps = cells[2]
                .split(',')
                .map(|d| d.trim().trim_matches('`'))
                .filter(|d| !d.is_empty() && *d != "—")
                .map(String::from)
                .collect();
            (name, deps)
        })
        .collect()
}

#[test]
fn the_crate_table_lists_every_member_with_its_dependencies() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../ARCHITECTURE.md");
    let documented = documented_dependencies(&std::fs::read_to_string(path).unwrap());
    let actual = workspace_dependencies();
    let names = |m: &BTreeMap<String, BTreeSet<String>>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(
        names(&documented),
        names(&actual),
        "the crate table's rows are not the workspace's members"
    );
    for (name, deps) in &actual {
        assert_eq!(
            &documented[name], deps,
            "ARCHITECTURE.md: `{name}` depends on {deps:?}"
        );
    }
}

#[test]
fn the_table_parser_reads_rows_and_empty_cells() {
    let text = "| crate | depends on | owns |\n|---|---|---|\n| `a` | — | x |\n| `b` | `a`, `c` | y |\n\nafter";
    let rows = documented_dependencies(text);
    assert_eq!(rows["a"], BTreeSet::new());
    assert_eq!(
        rows["b"],
        BTreeSet::from(["a".to_string(), "c".to_string()])
    );
    assert_eq!(rows.len(), 2);
}
