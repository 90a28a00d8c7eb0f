//! Records the git commit the crate is built from (`WTMM_BUILD`), so that
//! outputs of two builds with the same version number can be told apart.
//! Hand-written (a dozen lines) rather than a build-info crate: one `git`
//! call, and "unknown" where there is no repository (a packaged crate).
use std::process::Command;

fn main() {
    let commit = Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=WTMM_BUILD={commit}");
    // a new commit moves HEAD or the branch it names
    for p in [".git/HEAD", ".git/refs/heads", ".git/packed-refs"] {
        if std::path::Path::new(p).exists() {
            println!("cargo:rerun-if-changed={p}");
        }
    }
    println!("cargo:rerun-if-changed=build.rs");
}
