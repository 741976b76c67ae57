//! `mirror_proc`: see `mirror_proc --help`.

fn main() -> std::process::ExitCode {
    messages::init_logging();
    mirror_proc::cli::main()
}
