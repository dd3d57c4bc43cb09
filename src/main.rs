//! `lhmpp` command-line entry point: see `lhmpp --help`.

mod cli;

fn main() -> std::process::ExitCode {
    match cli::main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line: the error and its causes, without the backtrace that returning the
            // error from `main` prints under RUST_BACKTRACE=1.
            eprintln!("Error: {}", cli::error_line(&e));
            std::process::ExitCode::from(cli::exit_code(&e))
        }
    }
}
