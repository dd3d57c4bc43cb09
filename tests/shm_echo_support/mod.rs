//! Shared by the shared-memory tests that talk to the `shm-echo` child process: unique service
//! names per test and the parsing of its `key=value` report lines.

use std::io::{BufReader, Lines};
use std::process::ChildStdout;
use std::sync::atomic::{AtomicUsize, Ordering};

static COUNTER: AtomicUsize = AtomicUsize::new(0);

/// A person id no other test (or test process) uses: `tag`, the process id and a counter.
pub fn unique_person(tag: &str) -> String {
    format!(
        "{tag}{}x{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// The next line `shm-echo` printed.
pub fn next_line(lines: &mut Lines<BufReader<ChildStdout>>) -> String {
    lines
        .next()
        .expect("shm-echo ended early (see its stderr)")
        .expect("readable stdout")
}

/// The value of `key=` in a report line.
pub fn field<'a>(line: &'a str, key: &str) -> &'a str {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(key).and_then(|r| r.strip_prefix('=')))
        .unwrap_or_else(|| panic!("no `{key}=` in {line:?}"))
}
