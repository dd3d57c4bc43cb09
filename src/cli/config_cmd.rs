//! `lhmpp config`: load a launch config with overrides, validate it, print the result; or,
//! with `--markdown`, print the parameter reference table of docs/configuration.md.

use super::config_source::ConfigSource;
use anyhow::Result;

/// Arguments of `lhmpp config`.
#[derive(clap::Args, Debug)]
pub struct ConfigArgs {
    #[command(flatten)]
    pub source: ConfigSource,
    /// Print the parameter reference (docs/configuration.md's table: types, ranges, defaults, meanings)
    /// as Markdown instead of a config.
    #[arg(long, conflicts_with_all = ["config", "overrides"])]
    pub markdown: bool,
}

/// Prints the resolved parameters as a ROS 2 parameter file, or the parameter table.
pub fn run(args: ConfigArgs) -> Result<()> {
    if args.markdown {
        print!("{}", lhmpp::config::markdown_table());
        return Ok(());
    }
    let config = args.source.load()?;
    print!("{}", config.to_param_file());
    Ok(())
}
