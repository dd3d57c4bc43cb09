//! `lhmpp [run ...] --ros-args ...`: the ROS 2 command-line arguments that `ros2 run` and
//! `ros2 launch` pass to a node, translated into `lhmpp run` options before clap parses them.
//!
//! ros2-client reads no `--ros-args`, so the node does it here. The subset understood:
//!
//! | ROS 2 argument                    | becomes                                           |
//! |-----------------------------------|---------------------------------------------------|
//! | `--params-file FILE` (one)        | `--config FILE`                                   |
//! | `-p`/`--param NAME:=VALUE`        | `--set NAME=VALUE` (dotted names, YAML values)    |
//! | `-r`/`--remap FROM:=TO`           | `--remap FROM:=TO`                                |
//! | `-r __ns:=/NS`                    | `--set namespace=/NS`                             |
//! | `-r __node:=lhmpp`                | accepted (the node's name is fixed: `lhmpp`)      |
//! | `-r NODE:FROM:=TO`                | applied when NODE is `lhmpp`, else ignored        |
//! | `--log-level LEVEL` / `lhmpp:=L`  | `--log error,lhmpp=LEVEL,...`                     |
//!
//! Anything else after `--ros-args` is an error that names it. The ROS arguments end at `--`
//! (what follows is the node's own arguments again); there may be several `--ros-args`
//! sections. The node's own arguments must be empty (meaning `run`) or start with `run`.

use std::ffi::OsString;

/// The node's name in the ROS graph (and the parameter file's top-level key).
const NODE: &str = lhmpp::config::NODE_NAME;

/// A `--ros-args` section that cannot be translated.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RosArgsError {
    /// An argument outside the supported subset.
    #[error("--ros-args: `{0}` is not supported (supported: --params-file FILE, -p/--param NAME:=VALUE, -r/--remap FROM:=TO, --log-level LEVEL)")]
    Unsupported(String),
    /// A flag without its value.
    #[error("--ros-args: `{0}` needs a value")]
    MissingValue(String),
    /// A rule that is not `NAME:=VALUE`.
    #[error("--ros-args: `{flag} {rule}`: expected NAME:=VALUE")]
    Rule {
        /// `-r` or `-p`.
        flag: String,
        /// The malformed rule.
        rule: String,
    },
    /// More than one `--params-file`.
    #[error("--ros-args: more than one --params-file (`{0}`); lhmpp reads one parameter file")]
    SecondParamsFile(String),
    /// `-r __node:=OTHER`.
    #[error("--ros-args: cannot rename the node to `{0}`: its name is `lhmpp`")]
    NodeName(String),
    /// An unknown log level.
    #[error("--ros-args: --log-level `{0}`: expected debug, info, warn, error or fatal")]
    LogLevel(String),
    /// A non-UTF-8 argument in the ROS section.
    #[error("--ros-args: an argument is not valid UTF-8: {0:?}")]
    NotUtf8(OsString),
    /// `--ros-args` after a subcommand other than `run`.
    #[error("--ros-args goes with `lhmpp run` (or no subcommand), not `{0}`")]
    NotRun(String),
}

/// `args` (program name first) with its `--ros-args` sections turned into `run` options;
/// unchanged when there are none.
pub fn translate(args: Vec<OsString>) -> Result<Vec<OsString>, RosArgsError> {
    if !args.iter().any(|a| a == "--ros-args") {
        return Ok(args);
    }
    let mut iter = args.into_iter();
    let program = iter.next().unwrap_or_else(|| NODE.into());
    let mut own: Vec<OsString> = Vec::new();
    let mut ros: Vec<String> = Vec::new();
    let mut in_ros = false;
    for arg in iter {
        if arg == "--ros-args" {
            in_ros = true;
        } else if in_ros && arg == "--" {
            in_ros = false;
        } else if in_ros {
            ros.push(arg.into_string().map_err(RosArgsError::NotUtf8)?);
        } else {
            own.push(arg);
        }
    }
    match own.first() {
        None => own.push("run".into()),
        Some(first) if first == "run" => {}
        Some(other) => return Err(RosArgsError::NotRun(other.to_string_lossy().into_owned())),
    }

    let mut out: Vec<OsString> = vec![program];
    let mut params_file: Option<String> = None;
    let mut ros = ros.into_iter();
    while let Some(flag) = ros.next() {
        let mut value = || {
            ros.next()
                .ok_or_else(|| RosArgsError::MissingValue(flag.clone()))
        };
        match flag.as_str() {
            "--params-file" => {
                let file = value()?;
                if params_file.is_some() {
                    return Err(RosArgsError::SecondParamsFile(file));
                }
                params_file = Some(file);
            }
            "-p" | "--param" => {
                let rule = value()?;
                let (name, val) = split_rule(&flag, &rule)?;
                own.extend(["--set".into(), format!("{name}={val}").into()]);
            }
            "-r" | "--remap" => {
                let rule = value()?;
                let (from, to) = split_rule(&flag, &rule)?;
                // `node:from:=to` applies to that node only (`rosservice:`/`rostopic:` URLs
                // keep their scheme).
                let from = match from.split_once(':') {
                    Some((scheme, _)) if scheme == "rostopic" || scheme == "rosservice" => from,
                    Some((node, _)) if node != NODE => continue,
                    Some((_, rest)) => rest,
                    None => from,
                };
                match from {
                    "__ns" => own.extend(["--set".into(), format!("namespace={to}").into()]),
                    "__node" | "__name" if to == NODE => {}
                    "__node" | "__name" => return Err(RosArgsError::NodeName(to.into())),
                    _ => own.extend(["--remap".into(), format!("{from}:={to}").into()]),
                }
            }
            "--log-level" => {
                let spec = value()?;
                let level = match spec.split_once(":=") {
                    Some((logger, _)) if logger != NODE => continue,
                    Some((_, level)) => level,
                    None => spec.as_str(),
                };
                let level = match level.to_ascii_lowercase().as_str() {
                    l @ ("debug" | "info" | "warn" | "error") => l.to_owned(),
                    "fatal" => "error".into(),
                    _ => return Err(RosArgsError::LogLevel(level.into())),
                };
                let filter =
                    super::DEFAULT_LOG_FILTER.replace("lhmpp=info", &format!("lhmpp={level}"));
                out.extend(["--log".into(), filter.into()]);
            }
            _ => return Err(RosArgsError::Unsupported(flag)),
        }
    }
    if let Some(file) = params_file {
        own.extend(["--config".into(), file.into()]);
    }
    out.extend(own);
    Ok(out)
}

/// `NAME:=VALUE` into its two halves.
fn split_rule<'a>(flag: &str, rule: &'a str) -> Result<(&'a str, &'a str), RosArgsError> {
    rule.split_once(":=")
        .filter(|(name, _)| !name.is_empty())
        .ok_or_else(|| RosArgsError::Rule {
            flag: flag.into(),
            rule: rule.into(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tr(args: &[&str]) -> Result<Vec<String>, RosArgsError> {
        let args = args.iter().map(OsString::from).collect();
        translate(args).map(|v| v.into_iter().map(|a| a.into_string().unwrap()).collect())
    }

    #[test]
    fn without_ros_args_nothing_changes() {
        let args = ["lhmpp", "run", "--config", "c.yaml", "--set", "a=1"];
        assert_eq!(tr(&args).unwrap(), args);
    }

    #[test]
    fn ros2_run_arguments_become_run_options() {
        let got = tr(&[
            "/x/lib/lhmpp/lhmpp",
            "--ros-args",
            "--params-file",
            "launch_configs/camera.yaml",
            "-r",
            "/camera/image_raw:=/cam0/image_raw",
            "-p",
            "outputs.render_size:=64",
            "--param",
            "inputs.image_topics:=[a, b]",
            "-r",
            "__ns:=/robot",
            "-r",
            "__node:=lhmpp",
            "-r",
            "other_node:/x:=/y",
            "-r",
            "lhmpp:/status:=/s",
        ])
        .unwrap();
        assert_eq!(
            got,
            [
                "/x/lib/lhmpp/lhmpp",
                "run",
                "--remap",
                "/camera/image_raw:=/cam0/image_raw",
                "--set",
                "outputs.render_size=64",
                "--set",
                "inputs.image_topics=[a, b]",
                "--set",
                "namespace=/robot",
                "--remap",
                "/status:=/s",
                "--config",
                "launch_configs/camera.yaml",
            ]
        );
    }

    #[test]
    fn run_options_and_the_end_marker_are_kept() {
        let got = tr(&[
            "lhmpp",
            "run",
            "--set",
            "a=1",
            "--ros-args",
            "-p",
            "b:=2",
            "--",
            "--set",
            "c=3",
            "--ros-args",
            "--log-level",
            "DEBUG",
        ])
        .unwrap();
        assert_eq!(
            got,
            [
                "lhmpp",
                "--log",
                "error,lhmpp=debug,rustdds::network::udp_listener=off",
                "run",
                "--set",
                "a=1",
                "--set",
                "c=3",
                "--set",
                "b=2",
            ]
        );
        // A log level for another logger leaves ours alone.
        assert_eq!(
            tr(&["lhmpp", "--ros-args", "--log-level", "rcl:=debug"]).unwrap(),
            ["lhmpp", "run"]
        );
    }

    #[test]
    fn what_cannot_be_honoured_is_an_error() {
        let err = |args: &[&str]| tr(args).unwrap_err();
        assert_eq!(
            err(&["lhmpp", "--ros-args", "--enclave", "/e"]),
            RosArgsError::Unsupported("--enclave".into())
        );
        assert_eq!(
            err(&["lhmpp", "--ros-args", "--params-file"]),
            RosArgsError::MissingValue("--params-file".into())
        );
        assert_eq!(
            err(&[
                "lhmpp",
                "--ros-args",
                "--params-file",
                "a",
                "--params-file",
                "b"
            ]),
            RosArgsError::SecondParamsFile("b".into())
        );
        assert!(matches!(
            err(&["lhmpp", "--ros-args", "-p", "size=3"]),
            RosArgsError::Rule { .. }
        ));
        assert_eq!(
            err(&["lhmpp", "--ros-args", "-r", "__node:=camera"]),
            RosArgsError::NodeName("camera".into())
        );
        assert_eq!(
            err(&["lhmpp", "--ros-args", "--log-level", "loud"]),
            RosArgsError::LogLevel("loud".into())
        );
        assert_eq!(
            err(&["lhmpp", "replay", "b.mcap", "--ros-args"]),
            RosArgsError::NotRun("replay".into())
        );
    }

    #[test]
    fn the_translation_parses_as_a_run_command() {
        use clap::Parser;
        let args = tr(&[
            "lhmpp",
            "--ros-args",
            "--params-file",
            "c.yaml",
            "-p",
            "model.seed:=7",
            "-r",
            "/a:=/b",
        ])
        .unwrap();
        let cli = super::super::Cli::try_parse_from(args).unwrap();
        match cli.command {
            super::super::Command::Run(run) => {
                assert_eq!(
                    run.source.config.as_deref(),
                    Some(std::path::Path::new("c.yaml"))
                );
                assert_eq!(run.source.overrides, ["model.seed=7"]);
                assert_eq!(run.remaps, ["/a:=/b"]);
            }
            other => panic!("{other:?}"),
        }
    }
}
