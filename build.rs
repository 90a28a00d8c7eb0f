//! Records the git commit the crate is built from (`WTMM_BUILD`), so that
//! outputs of two builds with the same version number can be told apart,
//! with `-dirty` when the sources that make the library and binary differ
//! from that commit (outputs of an uncommitted build would otherwise carry
//! the id of code that did not make them).
//! Hand-written (a few lines) rather than a build-info crate: two `git`
//! calls, and "unknown" where there is no repository (a packaged crate).
use std::process::Command;

/// What the library and the binary are built from.
const SOURCES: [&str; 5] = ["src", "Cargo.toml", "Cargo.lock", "build.rs", "assets"];

fn git(args: &[&str]) -> Option<String> {
    Command::new("git")
        .args(args)
        .output()
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8(o.stdout).ok())
}

fn main() {
    let commit = git(&["rev-parse", "--short=12", "HEAD"])
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty());
    let id = match commit {
        Some(c) => {
            // --no-optional-locks: a plain `status` refreshes the stat data
            // in .git/index, which is watched below, so the next build
            // would run again for nothing
            let mut args = vec![
                "--no-optional-locks",
                "status",
                "--porcelain",
                "--untracked-files=no",
                "--",
            ];
            args.extend(SOURCES);
            match git(&args) {
                Some(s) if s.trim().is_empty() => c,
                _ => format!("{c}-dirty"),
            }
        }
        None => "unknown".into(),
    };
    println!("cargo:rustc-env=WTMM_BUILD={id}");
    // a new commit moves HEAD or the branch it names; an edit or a commit
    // changes the index or the sources (a directory is watched whole)
    for p in [
        ".git/HEAD",
        ".git/refs/heads",
        ".git/packed-refs",
        ".git/index",
    ] {
        if std::path::Path::new(p).exists() {
            println!("cargo:rerun-if-changed={p}");
        }
    }
    for p in SOURCES {
        println!("cargo:rerun-if-changed={p}");
    }
}
