//! `mirror_proc`: see `mirror_proc --help`.

mod cli;

fn main() -> std::process::ExitCode {
    runtime::init_logging("mirror_proc");
    let code = cli::main();
    runtime::trace::flush();
    code
}
