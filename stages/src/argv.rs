//! A stage's command line, derived from its typed arguments.
//!
//! clap's own description of the arguments (`clap::Args::augment_args`)
//! says how each one is written (long name, flag or value, positional);
//! serde says what each field holds. So no stage writes its command line
//! by hand, and the round-trip test (`parse(of(args)) == args`) covers
//! every stage.

use clap::{ArgAction, Args as _, FromArgMatches};
use serde::Serialize;
use serde_json::Value;

use crate::Stage;

/// The command line that makes a binary parsing `A` parse `args` again:
/// positional arguments first, then `--name value` for each field that has
/// a value (repeated for lists, the bare `--name` for a set flag).
///
/// Each field must serialize as its command-line word (enums by their clap
/// value name, lists as sequences); the stages' round-trip tests check it.
pub fn of<A: clap::Args + Serialize>(args: &A) -> Vec<String> {
    let fields = match serde_json::to_value(args) {
        Ok(Value::Object(fields)) => fields,
        // A struct of plain fields always serializes to an object; the
        // round-trip tests cover every stage's.
        other => panic!("stage arguments must serialize to an object, not {other:?}"),
    };
    let command = A::augment_args(clap::Command::new("stage"));
    let mut positional = Vec::new();
    let mut named = Vec::new();
    for arg in command.get_arguments() {
        let Some(value) = fields.get(arg.get_id().as_str()) else {
            continue;
        };
        if arg.is_positional() {
            positional.extend(words(value));
            continue;
        }
        let Some(long) = arg.get_long() else { continue };
        let flag = format!("--{long}");
        match arg.get_action() {
            ArgAction::SetTrue => {
                if value == &Value::Bool(true) {
                    named.push(flag);
                }
            }
            _ => {
                for word in words(value) {
                    named.extend([flag.clone(), word]);
                }
            }
        }
    }
    positional.extend(named);
    positional
}

/// The words of one field's value: none for an absent value, one per item
/// of a list.
fn words(value: &Value) -> Vec<String> {
    match value {
        Value::Null => Vec::new(),
        Value::Array(items) => items.iter().flat_map(words).collect(),
        Value::String(s) => vec![s.clone()],
        Value::Number(n) => vec![n.to_string()],
        Value::Bool(b) => vec![b.to_string()],
        Value::Object(_) => panic!("a stage argument cannot be a map: {value}"),
    }
}

/// A stage's command line that its binary's parser does not take back to
/// the same arguments.
#[derive(Debug, thiserror::Error)]
pub enum RoundTripError {
    /// The parser refused it.
    #[error("{binary} {argv:?}: {error}")]
    Refused {
        /// The stage's binary.
        binary: &'static str,
        /// The command line.
        argv: Vec<String>,
        /// clap's error.
        error: clap::Error,
    },
    /// It parsed to other arguments.
    #[error("{binary} {argv:?} parses to {parsed}, not {given}")]
    Differs {
        /// The stage's binary.
        binary: &'static str,
        /// The command line.
        argv: Vec<String>,
        /// The arguments given, `{:?}`.
        given: String,
        /// The arguments parsed, `{:?}`.
        parsed: String,
    },
}

/// Builds stage `S`'s command line for `args` and parses it back as its
/// binary does (the leading words, then `S::Args`).
pub fn round_trip<S: Stage>(args: &S::Args) -> Result<(), RoundTripError> {
    let argv = S::argv(args);
    let leading = S::leading_words(args).len();
    let command = S::Args::augment_args(clap::Command::new(S::BINARY)).no_binary_name(true);
    let parsed = command
        .try_get_matches_from(&argv[leading..])
        .and_then(|matches| S::Args::from_arg_matches(&matches));
    match parsed {
        Err(error) => Err(RoundTripError::Refused {
            binary: S::BINARY,
            argv,
            error,
        }),
        Ok(parsed) if !S::parsed_again(args, &parsed) => Err(RoundTripError::Differs {
            binary: S::BINARY,
            argv,
            given: format!("{args:?}"),
            parsed: format!("{parsed:?}"),
        }),
        Ok(_) => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StageArgs;
    use clap::Parser;

    #[derive(Debug, Clone, PartialEq, Serialize, Parser)]
    struct Example {
        file: std::path::PathBuf,
        #[arg(long)]
        name: String,
        #[arg(long)]
        quiet: bool,
        #[arg(long)]
        limit: Option<u32>,
        #[arg(long, value_delimiter = ',')]
        items: Vec<String>,
        #[arg(long, default_value_t = 2.5)]
        rate: f64,
    }

    #[test]
    fn positional_first_then_flags_lists_repeated_and_absent_values_left_out() {
        let args = Example {
            file: "a b.mcap".into(),
            name: "x".into(),
            quiet: true,
            limit: None,
            items: vec!["p".into(), "q".into()],
            rate: 30.0,
        };
        let argv = of(&args);
        assert_eq!(
            argv,
            [
                "a b.mcap", "--name", "x", "--quiet", "--items", "p", "--items", "q", "--rate",
                "30.0"
            ]
        );
        let back = Example::try_parse_from(std::iter::once("example".to_string()).chain(argv));
        assert_eq!(back.unwrap(), args);
    }

    /// Every stage of the table: its launcher-built command line parses
    /// back, in its binary's parser, to the same typed arguments.
    #[test]
    fn every_stage_round_trips() {
        for stage in StageArgs::examples() {
            stage.check_argv_round_trip().unwrap();
        }
    }

    /// Arguments whose field serializes under another name than clap's.
    #[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
    struct Misnamed {
        #[arg(long)]
        prefix: String,
        #[arg(long, default_value_t = 1)]
        #[serde(rename = "renamed")]
        count: u32,
    }

    struct MisnamedStage;

    impl Stage for MisnamedStage {
        type Args = Misnamed;
        const BINARY: &'static str = "misnamed";
        const HOME: crate::Home = crate::Home::On(crate::Side::Robot);
        const SAMPLE_PATH_DEPTH: Option<u8> = None;
        const RESTART: crate::RestartPolicy = crate::RestartPolicy::Service;
        fn ports(_: &Misnamed) -> runtime::Ports<'_> {
            runtime::Ports {
                subscribes: &[],
                publishes: &[],
            }
        }
        fn prefix(args: &Misnamed) -> &str {
            &args.prefix
        }
        fn example() -> Misnamed {
            Misnamed {
                prefix: "p".into(),
                count: 5,
            }
        }
    }

    /// A field that does not serialize as its command-line word is left
    /// out of the command line, and the round trip says what came back.
    #[test]
    fn a_field_lost_on_the_way_is_reported() {
        let err = round_trip::<MisnamedStage>(&MisnamedStage::example()).unwrap_err();
        assert!(
            matches!(&err, RoundTripError::Differs { argv, .. } if argv == &["--prefix", "p"]),
            "{err}"
        );
        assert!(err.to_string().contains("count: 1"), "{err}");
    }
}
