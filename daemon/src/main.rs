//! `telextilesd`: the Telextiles daemon and its command line.
use clap::{Parser, Subcommand};

mod classify_felt;
mod cmd_classify;
mod cmd_ctl;
#[cfg(feature = "sim")]
mod cmd_demo;
mod cmd_index;
mod cmd_map;
mod cmd_pair;
mod cmd_peers;
mod cmd_record;
mod cmd_relay;
mod cmd_roller;
mod cmd_sensors;
#[cfg(feature = "sim")]
mod cmd_sim;
mod config;
mod felt_chart;
mod index_choice;
mod index_sim;
mod live;
mod out;
mod press_dir;
mod record_idle;
mod trace;

#[derive(Parser)]
#[command(
    name = "telextilesd",
    version,
    about = "Feel, at a distance, the fabric another person is touching"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run the sensing pipeline on recorded or simulated presses
    Classify(cmd_classify::Args),
    /// Control a running daemon over its local socket
    Ctl(cmd_ctl::Args),
    /// Record labelled presses from the sensor (DIGIT, simulator or replay)
    Record(cmd_record::Args),
    /// Build or inspect the textile index
    #[command(subcommand)]
    Index(cmd_index::Args),
    /// Simulated DIGIT presses, the dataset protocol and the contact sheet
    #[cfg(feature = "sim")]
    Sim(cmd_sim::Args),
    /// Show this device's ID (creates the identity on first run)
    Id(cmd_peers::IdArgs),
    /// Pair with another device (show or enter a code), then run the live session
    Pair(cmd_pair::Args),
    /// Run the live session with the paired peers (as under systemd)
    Run(cmd_pair::RunArgs),
    /// Two daemons on this machine with simulated hardware: pair, press, feel
    #[cfg(feature = "sim")]
    Demo(cmd_demo::Args),
    /// List paired peers from the trust store
    Peers(cmd_peers::PeersArgs),
    /// Forget a paired peer (by device ID, unique ID prefix, or name)
    Unpair(cmd_peers::UnpairArgs),
    /// Serve the live 2D textile map in a browser (--demo: simulated presses)
    Map(cmd_map::Args),
    /// The tactile sensors plugged in: profile, modes, millimetres per pixel
    Sensors(cmd_sensors::Args),
    /// Drive a roller directly, or run the simulated roller on a pty
    #[command(subcommand)]
    Roller(cmd_roller::Args),
    /// Run the relay two devices on two networks meet through (on a host both reach)
    Relay(cmd_relay::Args),
}

/// The log filter of the running process, replaceable once the daemon's
/// configuration (`--log`, `TELEXTILESD_LOG`, `log` in the file) is known.
static LOG: std::sync::OnceLock<
    tracing_subscriber::reload::Handle<tracing_subscriber::EnvFilter, tracing_subscriber::Registry>,
> = std::sync::OnceLock::new();

/// Use `filter` from now on (the daemon's configured log level).
pub fn set_log_filter(filter: tracing_subscriber::EnvFilter) {
    if let Some(h) = LOG.get() {
        let _ = h.reload(filter);
    }
}

/// The error of a feature that needs the simulator in a daemon built
/// without it (`cargo build --no-default-features`).
#[cfg_attr(feature = "sim", allow(dead_code))]
pub(crate) fn sim_off(what: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "{what} needs the simulator, and this telextilesd was built without it \
         (cargo feature `sim`); use a DIGIT (`--sensor digit`) or recorded presses \
         (`--sensor replay:<dir>`, `--presses <dir>`)"
    )
}

fn main() -> anyhow::Result<()> {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    // RUST_LOG until a command loads its configuration.
    let (filter, handle) =
        tracing_subscriber::reload::Layer::new(tracing_subscriber::EnvFilter::from_default_env());
    let _ = LOG.set(handle);
    tracing_subscriber::registry()
        .with(filter)
        .with(tracing_subscriber::fmt::layer().with_writer(std::io::stderr))
        .init();
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Classify(a) => cmd_classify::run(a),
        Cmd::Ctl(a) => cmd_ctl::run(a),
        Cmd::Index(a) => cmd_index::run(a),
        Cmd::Record(a) => cmd_record::run(a),
        #[cfg(feature = "sim")]
        Cmd::Sim(a) => cmd_sim::run(a),
        Cmd::Id(a) => cmd_peers::id(a),
        Cmd::Pair(a) => cmd_pair::run(a),
        Cmd::Run(a) => cmd_pair::run_session(a),
        #[cfg(feature = "sim")]
        Cmd::Demo(a) => cmd_demo::run(a),
        Cmd::Peers(a) => cmd_peers::peers(a),
        Cmd::Unpair(a) => cmd_peers::unpair(a),
        Cmd::Map(a) => cmd_map::run(a),
        Cmd::Sensors(a) => cmd_sensors::run(a),
        Cmd::Roller(a) => cmd_roller::run(a),
        Cmd::Relay(a) => cmd_relay::run(a),
    };
    match result {
        // The reader of stdout went away (`telextilesd sim list | head`):
        // everything it wanted was written, so end quietly, as `cat` does.
        Err(e) if out::is_closed(&e) => Ok(()),
        r => r,
    }
}
