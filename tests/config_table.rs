//! docs/configuration.md's parameter table is the one `lhmpp config --markdown` prints (generated from
//! the config's defaults, ranges and parameter rows): a change to either fails here.

use std::path::Path;

#[test]
fn documented_parameter_table_is_the_generated_one() {
    let readme = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/configuration.md"),
    )
    .expect("docs/configuration.md");
    let header = "| parameter | type (default) | meaning |\n";
    let start = readme
        .find(header)
        .expect("docs/configuration.md has the parameter table");
    let table: String = readme[start..]
        .lines()
        .take_while(|l| l.starts_with('|'))
        .map(|l| format!("{l}\n"))
        .collect();
    let generated = lhmpp::config::markdown_table();
    assert!(
        table == generated,
        "docs/configuration.md's parameter table differs from `lhmpp config --markdown`; regenerate it.\n\
         documented:\n{table}\ngenerated:\n{generated}"
    );
}

#[test]
fn config_markdown_prints_the_table() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["config", "--markdown"])
        .output()
        .expect("lhmpp runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        String::from_utf8(out.stdout).unwrap(),
        lhmpp::config::markdown_table()
    );
}
