//! Shared by the tests that run `lhmpp` as a process: a child process killed when dropped, the
//! `lhmpp` binary without inherited ROS settings, numbers read off the node's summary lines,
//! and its log without terminal colours.

#![allow(dead_code)]

use std::process::{Child, Command};

/// A child process (the node under load) killed and reaped when dropped.
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The `lhmpp` binary, without `RUST_LOG` and `ROS_DOMAIN_ID` from the environment.
pub fn lhmpp() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    c.env_remove("RUST_LOG").env_remove("ROS_DOMAIN_ID");
    c
}

/// The number after `key ` in `line` (`received 1747,` → 1747).
pub fn number_after(line: &str, key: &str) -> f64 {
    let at = line
        .find(key)
        .unwrap_or_else(|| panic!("`{key}` not in `{line}`"));
    line[at + key.len()..]
        .trim_start()
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no number after `{key}` in `{line}`"))
}

/// Sends SIGINT to `pid` (the node's clean stop).
pub fn interrupt(pid: u32) {
    let ok = Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "kill -INT {pid}");
}

/// `text` without ANSI terminal sequences (the node's log is coloured even into a pipe).
pub fn without_ansi(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}
