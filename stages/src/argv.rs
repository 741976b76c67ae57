//! A stage's command line, derived from its typed arguments.
//!
//! clap's own description of the arguments (`clap::Args::augment_args`)
//! says how each one is written (long name, flag or value, positional);
//! serde says what each field holds. So no stage writes its command line
//! by hand, and the round-trip test (`parse(of(args)) == args`) covers
//! every stage.

use clap::ArgAction;
use serde::Serialize;
use serde_json::Value;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Stage, StageArgs};
    use clap::{Args as _, FromArgMatches, Parser};

    /// Parses `argv` as the binary of stage `S` does (its subcommand, then
    /// its arguments).
    fn parse<S: Stage>(args_hint: &S::Args, argv: &[String]) -> Result<S::Args, clap::Error>
    where
        S::Args: FromArgMatches,
    {
        let command = S::Args::augment_args(clap::Command::new(S::BINARY)).no_binary_name(true);
        let leading = S::leading_words(args_hint);
        assert_eq!(
            argv[..leading.len()],
            leading[..],
            "the command line starts with its leading words"
        );
        let matches = command.try_get_matches_from(&argv[leading.len()..])?;
        S::Args::from_arg_matches(&matches)
    }

    /// `S`'s command line for `args`, parsed back.
    fn parsed_back<S: Stage>(args: &S::Args) -> S::Args
    where
        S::Args: FromArgMatches,
    {
        let argv = S::argv(args);
        parse::<S>(args, &argv).unwrap_or_else(|e| panic!("{} {argv:?}: {e}", S::BINARY))
    }

    fn round_trip<S: Stage>(args: S::Args)
    where
        S::Args: FromArgMatches,
    {
        assert_eq!(parsed_back::<S>(&args), args, "{}", S::BINARY);
    }

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
        for stage in crate::examples() {
            match stage {
                StageArgs::Recorder(a) => round_trip::<crate::recorder::Recorder>(a),
                StageArgs::Mirror(a) => round_trip::<crate::mirror::Mirror>(a),
                StageArgs::Tracker(a) => round_trip::<crate::tracker::Tracker>(a),
                StageArgs::Camera(a) => round_trip::<crate::camera::Camera>(a),
                StageArgs::Replay(a) => round_trip::<crate::replay::Replay>(a),
                StageArgs::SimArm(a) => round_trip::<crate::sim_arm::SimArm>(a),
                StageArgs::ArmDriver(a) => {
                    // The user's command is the program and its own words,
                    // not an argument: everything else comes back.
                    let back = parsed_back::<crate::arm_driver::ArmDriver>(&a);
                    assert!(back.command.is_empty());
                    assert_eq!(
                        crate::arm_driver::Args {
                            command: a.command.clone(),
                            ..back
                        },
                        a
                    );
                }
                StageArgs::Kinematics(a) => round_trip::<crate::kinematics::Kinematics>(a),
                StageArgs::Bridge(a) => round_trip::<crate::bridge::Bridge>(a),
            }
        }
    }
}
