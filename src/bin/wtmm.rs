//! The `wtmm` command: all logic lives in the library's `cli` module.
fn main() {
    std::process::exit(wtmm::cli::run());
}
