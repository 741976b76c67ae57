//! `mirror_proc`: see `mirror_proc --help`.

fn main() -> std::process::ExitCode {
    mirror_proc::cli::main()
}
