//! `lhmpp` command-line entry point: see `lhmpp --help`.

mod cli;

fn main() -> anyhow::Result<()> {
    cli::main()
}
