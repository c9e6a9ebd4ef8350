//! `nrc`: the neural radiance cache command line. Subcommands are added by the crates as they land.
fn main() {
    eprintln!("nrc: no subcommands yet");
    std::process::exit(2);
}
