//! `op3dsg-layers`: the layering check of the op3dsg workspace (see the `op3dsg_layering`
//! crate documentation for the rules and the `[package.metadata.layers]` format).
//!
//! ```text
//! op3dsg-layers check                  # exit 1 and every violation listed, or exit 0
//! op3dsg-layers report --verbose       # per-crate figures, circles and every arrow
//! op3dsg-layers --root ../old check    # another checkout
//! ```

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use op3dsg_layering::{check, manifest, model, report};

/// Layers that point down: no crate depending on a crate of its own or a higher row where the
/// workspace declares `[workspace.metadata.layers] crates`, no import circle between a crate's
/// top-level modules, no upward import where a crate declares `[package.metadata.layers] rows`,
/// no oversized product file.
#[derive(Debug, Parser)]
#[command(name = "op3dsg-layers", version)]
struct Cli {
    /// The workspace to check (default: the first folder upward from here whose Cargo.toml has
    /// a [workspace], else the workspace this tool was built in).
    #[arg(long, global = true, value_name = "DIR")]
    root: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Every violation; exit status 1 if there is any.
    Check {
        /// Longest product file allowed, in lines.
        #[arg(long, default_value_t = 700, value_name = "LINES")]
        max_file_lines: usize,
    },
    /// Per crate: rows declared, top-level modules, arrows, circles (count, largest), largest
    /// product file.
    Report {
        /// Also each crate's circles and every arrow with the first file:line writing it.
        #[arg(long)]
        verbose: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let root = cli.root.unwrap_or_else(default_root);
    let crates = match model::load(&root) {
        Ok(crates) => crates,
        Err(e) => {
            eprintln!("op3dsg-layers: {e}");
            return ExitCode::from(2);
        }
    };
    match cli.command {
        Command::Check { max_file_lines } => {
            let mut violations = match op3dsg_layering::crates::violations(&root) {
                Ok(violations) => violations,
                Err(e) => {
                    eprintln!("op3dsg-layers: {e}");
                    return ExitCode::from(2);
                }
            };
            violations.extend(check::violations(&crates, max_file_lines));
            for violation in &violations {
                println!("{violation}");
            }
            if violations.is_empty() {
                println!("layering: {} crates, no violation", crates.len());
                ExitCode::SUCCESS
            } else {
                println!("layering: {} violations in {} crates", violations.len(), crates.len());
                ExitCode::FAILURE
            }
        }
        Command::Report { verbose } => {
            print!("{}", report::render(&crates, verbose));
            ExitCode::SUCCESS
        }
    }
}

fn default_root() -> PathBuf {
    let here = std::env::current_dir().unwrap_or_default();
    here.ancestors()
        .find(|dir| manifest::is_workspace_root(dir))
        .map(Path::to_path_buf)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."))
}
