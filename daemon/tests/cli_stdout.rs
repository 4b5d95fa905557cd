//! The one-shot commands through the real binary, their stdout read by a
//! reader that has already gone away (`telextilesd sim list | head`): each
//! ends quietly with status 0 instead of panicking in `println!`, and an
//! error of its own is still reported.

use std::path::Path;
use std::process::{Command, Output, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");

/// Runs `telextilesd args` with stdout a pipe whose read end is closed, so
/// the first write to it fails with EPIPE (deterministically: no reader
/// ever takes a byte).
fn run_into_closed_pipe(args: &[&str]) -> Output {
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    Command::new(BIN)
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
        .env("RUST_BACKTRACE", "0")
        .args(args)
        .stdin(Stdio::null())
        .stdout(writer)
        .output()
        .expect("run telextilesd")
}

#[test]
fn a_closed_stdout_ends_a_one_shot_command_quietly() {
    for args in [
        &["sim", "list"][..],
        &["sim", "list", "--catalogue", "2"],
        &["sim", "dataset", "--stream", "--limit", "500"],
        &["index", "inspect", "models/index.tlxi"],
        &["index", "inspect", "--json", "models/index.tlxi"],
    ] {
        let out = run_into_closed_pipe(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success(),
            "telextilesd {args:?}: {:?}\n{stderr}",
            out.status
        );
        assert!(
            !stderr.contains("panicked") && !stderr.contains("Broken pipe"),
            "telextilesd {args:?}:\n{stderr}"
        );
    }
}

#[test]
fn a_command_s_own_error_is_still_an_error_when_stdout_is_closed() {
    let out = run_into_closed_pipe(&["index", "inspect", "no-such-index.tlxi"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("no-such-index.tlxi"), "{stderr}");
}
