//! `camera_proc`: a stage of the live pipeline. Not implemented yet; the offline
//! tools live in `mirror_proc`.

fn main() -> std::process::ExitCode {
    eprintln!(
        "camera_proc: this live-pipeline stage is not implemented yet; use mirror_proc for the offline tools"
    );
    std::process::ExitCode::from(2)
}
