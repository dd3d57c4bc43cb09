//! `lhmpp config`: load a launch config with overrides, validate it, print the result.

use super::config_source::ConfigSource;
use anyhow::Result;

/// Arguments of `lhmpp config`.
#[derive(clap::Args, Debug)]
pub struct ConfigArgs {
    #[command(flatten)]
    pub source: ConfigSource,
}

/// Prints the resolved parameters as a ROS 2 parameter file.
pub fn run(args: ConfigArgs) -> Result<()> {
    let config = args.source.load()?;
    print!("{}", config.to_param_file());
    Ok(())
}
