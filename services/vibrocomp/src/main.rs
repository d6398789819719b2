//! `vibrocomp`: the command-line front door. All logic lives in the library.

fn main() -> std::process::ExitCode {
    vibrocomp::main_with_args(std::env::args_os())
}
