//! Property-based fuzzing of the rig TOML and samples CSV readers: valid
//! files from the simulator, damaged by random edits (bytes deleted,
//! inserted or replaced, lines dropped or repeated, truncation), must either
//! parse into something that writes back and reads again identically, or
//! fail with one line naming the file and the line or key at fault. Never a
//! panic.
//!
//! Bounded for CI (proptest's default, 256 cases per reader); run longer with
//! `PROPTEST_CASES=100000 cargo test --release -p formats --test fuzz`.

use std::path::Path;

use formats::{FormatError, rig, samples};
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use proptest::prelude::*;

/// Text fragments likely to upset a parser: structure, numbers at their
/// limits, non-finite values, quotes, non-ASCII.
const FRAGMENTS: &[&str] = &[
    "=",
    "[",
    "]",
    "[[camera]]",
    "[arm]",
    "\"",
    ",",
    "\n",
    "#",
    "nan",
    "inf",
    "-inf",
    "NaN",
    "1e309",
    "-0",
    "0",
    "-1",
    "1e-320",
    "18446744073709551616",
    "9007199254740993",
    ".",
    "e",
    " ",
    "\t",
    "\r\n",
    "é",
    "\u{0}",
    "true",
    "{}",
    "q0",
    "q9",
    "left_u",
    "pose",
    "view",
    "mirror",
    "direct",
];

#[derive(Debug, Clone)]
enum Edit {
    Delete { at: usize, len: usize },
    Insert { at: usize, fragment: usize },
    Replace { at: usize, byte: u8 },
    DropLine { line: usize },
    RepeatLine { line: usize },
    Truncate { at: usize },
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), 1usize..16).prop_map(|(at, len)| Edit::Delete { at, len }),
        (any::<usize>(), 0..FRAGMENTS.len())
            .prop_map(|(at, fragment)| Edit::Insert { at, fragment }),
        (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| Edit::Replace { at, byte }),
        any::<usize>().prop_map(|line| Edit::DropLine { line }),
        any::<usize>().prop_map(|line| Edit::RepeatLine { line }),
        any::<usize>().prop_map(|at| Edit::Truncate { at }),
    ]
}

/// Applies `edits` to `text` as bytes (so edits may break UTF-8, as a
/// damaged file would).
fn damage(text: &str, edits: &[Edit]) -> Vec<u8> {
    let mut bytes = text.as_bytes().to_vec();
    for e in edits {
        let n = bytes.len().max(1);
        match *e {
            Edit::Delete { at, len } => {
                let at = at % n;
                let end = (at + len).min(bytes.len());
                if at < end {
                    bytes.drain(at..end);
                }
            }
            Edit::Insert { at, fragment } => {
                let at = at % (bytes.len() + 1);
                bytes.splice(at..at, FRAGMENTS[fragment].bytes());
            }
            Edit::Replace { at, byte } => {
                if !bytes.is_empty() {
                    bytes[at % n] = byte;
                }
            }
            Edit::DropLine { line } | Edit::RepeatLine { line } => {
                let mut lines: Vec<Vec<u8>> =
                    bytes.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
                let k = line % lines.len();
                if matches!(e, Edit::DropLine { .. }) {
                    lines.remove(k);
                } else {
                    let copy = lines[k].clone();
                    lines.insert(k, copy);
                }
                bytes = lines.join(&b'\n');
            }
            Edit::Truncate { at } => bytes.truncate(at % n),
        }
    }
    bytes
}

/// The error is one line that names the file, and the line or key when the
/// content (not the file system) is at fault.
fn check_error(e: &FormatError, path: &str) -> Result<(), TestCaseError> {
    let text = e.to_string();
    prop_assert!(!text.contains('\n'), "not one line: {text:?}");
    prop_assert!(text.starts_with(path), "does not name the file: {text}");
    prop_assert!(!e.message.is_empty(), "no message: {text}");
    prop_assert!(
        e.location
            .as_deref()
            .is_some_and(|l| l.starts_with("line ") || l.starts_with("key ")),
        "no line or key: {text}"
    );
    Ok(())
}

fn rig_text() -> &'static str {
    use std::sync::OnceLock;
    static TEXT: OnceLock<String> = OnceLock::new();
    TEXT.get_or_init(|| rig::to_toml(&nico_scene().rig))
}

fn samples_text() -> &'static str {
    use std::sync::OnceLock;
    static TEXT: OnceLock<String> = OnceLock::new();
    TEXT.get_or_init(|| {
        let counts = Counts {
            train: 6,
            test: 2,
            direct: 2,
        };
        let data = generate(&nico_scene(), 0, &nico_noise(), counts, 5).unwrap();
        let mut all = data.train.clone();
        all.extend(data.direct.iter().cloned());
        samples::to_csv(&all)
    })
}

proptest! {
    #[test]
    fn damaged_rig_files_fail_on_one_line_or_round_trip(
        edits in prop::collection::vec(edit(), 1..6)
    ) {
        let bytes = damage(rig_text(), &edits);
        // A file that is not UTF-8 is refused by the reader before parsing.
        let Ok(text) = String::from_utf8(bytes) else { return Ok(()) };
        match rig::parse(Path::new("fuzz.toml"), &text) {
            Err(e) => check_error(&e, "fuzz.toml")?,
            Ok(parsed) => {
                let again = rig::parse(Path::new("again.toml"), &rig::to_toml(&parsed));
                prop_assert_eq!(again, Ok(parsed));
            }
        }
    }

    #[test]
    fn damaged_samples_files_fail_on_one_line_or_round_trip(
        edits in prop::collection::vec(edit(), 1..6),
        dof in prop_oneof![Just(None), Just(Some(4usize))],
    ) {
        let bytes = damage(samples_text(), &edits);
        match samples::parse(Path::new("fuzz.csv"), bytes.as_slice(), dof) {
            Err(e) => check_error(&e, "fuzz.csv")?,
            Ok(parsed) => {
                for s in &parsed {
                    prop_assert!(s.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())));
                    if let Some(q) = &s.joints {
                        prop_assert!(q.iter().all(|v| v.is_finite()));
                    }
                }
                if !parsed.is_empty() {
                    let again = samples::parse(
                        Path::new("again.csv"),
                        samples::to_csv(&parsed).as_bytes(),
                        dof,
                    );
                    prop_assert_eq!(again, Ok(parsed));
                }
            }
        }
    }
}

/// Files that are not UTF-8 and unreadable paths: still one line naming the file.
#[test]
fn unreadable_files_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let binary = dir.path().join("rig.toml");
    std::fs::write(&binary, [0xff, 0xfe, b'[', 0x80]).unwrap();
    let e = rig::read(&binary).unwrap_err().to_string();
    assert!(
        e.starts_with(&binary.display().to_string()) && !e.contains('\n'),
        "{e}"
    );
    let missing = dir.path().join("missing.csv");
    let e = samples::read(&missing, None).unwrap_err().to_string();
    assert!(
        e.starts_with(&missing.display().to_string()) && !e.contains('\n'),
        "{e}"
    );
}
