// Library code answers bad input with an error, never a panic: no unwrap or
// expect outside tests (ARCHITECTURE.md, "Conventions").
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]
fn main() -> std::process::ExitCode {
    easycalib::cli::main()
}
