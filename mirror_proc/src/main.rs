//! `mirror_proc`: see `mirror_proc --help`.

fn main() -> std::process::ExitCode {
    runtime::init_logging("mirror_proc");
    let code = mirror_proc::cli::main();
    runtime::trace::flush();
    code
}
