//! `mirror_proc`: see `mirror_proc --help`.

fn main() -> std::process::ExitCode {
    messages::init_logging("mirror_proc");
    let code = mirror_proc::cli::main();
    messages::trace::flush();
    code
}
