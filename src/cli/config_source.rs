//! `--config FILE` and `--set KEY=VALUE`: the one argument group of every command that reads
//! the node's parameters (`run`, `replay`, `record`, `eval`, `config`).

use anyhow::Result;
use lhmpp::config::NodeConfig;
use std::path::PathBuf;

/// Where a command's node parameters come from.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct ConfigSource {
    /// Parameter file (`launch_configs/*.yaml`); omitted = built-in defaults.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a parameter: `--set model.device=cpu` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

impl ConfigSource {
    /// The parameter file (or the defaults) with the overrides applied, validated.
    pub fn load(&self) -> Result<NodeConfig> {
        Ok(match &self.config {
            Some(path) => NodeConfig::load(path, &self.overrides)?,
            None => {
                let text = NodeConfig::default().to_param_file();
                NodeConfig::from_yaml(&text, "<defaults>".as_ref(), &self.overrides)?
            }
        })
    }
}
