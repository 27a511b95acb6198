fn main() -> std::process::ExitCode {
    easycalib::cli::main()
}
