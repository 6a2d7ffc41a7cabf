//! The `subnav` command-line tool's library: one module per subcommand (clap `Args` + `run`)
//! over the host crates. The binary (`src/main.rs`) only dispatches.

pub mod cli;
