//! The `odocal` binary: the command line is run by [`odocal_cli::main`].

fn main() -> std::process::ExitCode {
    odocal_cli::main()
}
