//! `lhmpp config`: load a launch config with overrides, validate it, print the result.

use anyhow::Result;
use lhmpp::config::NodeConfig;
use std::path::PathBuf;

/// Arguments of `lhmpp config`.
#[derive(clap::Args, Debug)]
pub struct ConfigArgs {
    /// Parameter file (`launch_configs/*.yaml`); omitted = built-in defaults.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override a parameter: `--set model.device=cpu` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
}

/// Prints the resolved parameters as a ROS 2 parameter file.
pub fn run(args: ConfigArgs) -> Result<()> {
    let config = match &args.config {
        Some(path) => NodeConfig::load(path, &args.overrides)?,
        None => {
            let text = NodeConfig::default().to_param_file();
            NodeConfig::from_yaml(&text, "<defaults>".as_ref(), &args.overrides)?
        }
    };
    print!("{}", config.to_param_file());
    Ok(())
}
