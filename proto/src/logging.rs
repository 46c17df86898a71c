//! Logging set-up shared by every edgepoint process: `tracing` to stderr, filtered by
//! `RUST_LOG` (else the process's default), with ANSI colours only when stderr is a
//! terminal and `NO_COLOR` is unset — colour codes in a redirected log or a CI log are noise.
use std::io::IsTerminal;

/// Whether log lines should carry colour codes.
pub fn use_colour() -> bool {
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty())
}

/// Installs the global subscriber; `default_filter` applies when `RUST_LOG` is unset or bad.
pub fn init(default_filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(use_colour()).init();
}
