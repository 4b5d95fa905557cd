//! `roller-sim`: the roller firmware core on a pseudo-terminal.
//!
//! Prints the pty's slave path (and creates `--link` pointing at it), then
//! simulates the roller until killed. Point `telextilesd` (or any serial
//! tool) at the printed path.
use clap::Parser;
use roller_firmware::sim::{SimConfig, SimRoller};
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "roller-sim",
    version,
    about = "Simulated Telextiles roller on a pseudo-terminal"
)]
struct Args {
    /// Number of fabric slots on the wheel.
    #[arg(long, default_value_t = 16)]
    slots: u16,
    /// Create (or replace) this symlink pointing at the pty slave, e.g. /tmp/roller0.
    #[arg(long)]
    link: Option<PathBuf>,
    /// Time factor: the simulated motor runs this many times faster than real time.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Maximum speed in microsteps/s (3200 = one turn per second at 16x
    /// microstepping; the default is the paper's wheel, 3 turns per second).
    #[arg(long, default_value_t = roller_firmware::DEFAULT_MAX_SPEED)]
    max_speed: u32,
    /// Acceleration in microsteps/s^2.
    #[arg(long, default_value_t = roller_firmware::DEFAULT_ACCEL)]
    accel: u32,
    /// Link watchdog in milliseconds (wall clock).
    #[arg(long, default_value_t = 2000)]
    watchdog_ms: u64,
    /// Start position in microsteps.
    #[arg(long, default_value_t = 0)]
    initial_steps: i64,
    /// Print the position every this many milliseconds while moving (0 = never).
    #[arg(long, default_value_t = 0)]
    report_ms: u64,
}

fn main() {
    let a = Args::parse();
    let cfg = SimConfig {
        slots: a.slots,
        speed: a.speed,
        max_speed: a.max_speed,
        accel: a.accel,
        watchdog: Duration::from_millis(a.watchdog_ms),
        link: a.link.clone(),
        initial_steps: a.initial_steps,
        ..SimConfig::default()
    };
    let sim = match SimRoller::spawn(cfg) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("roller-sim: cannot start: {e}");
            std::process::exit(1);
        }
    };
    println!("{}", sim.slave_path().unwrap_or_default().display());
    if let Some(l) = &a.link {
        eprintln!(
            "roller-sim: {} -> {}",
            l.display(),
            sim.slave_path().unwrap_or_default().display()
        );
    }
    loop {
        if a.report_ms > 0 {
            std::thread::sleep(Duration::from_millis(a.report_ms));
            if sim.is_moving() {
                let s = sim.status();
                eprintln!(
                    "roller-sim: position {} target {} speed {}",
                    s.position, s.target, s.speed
                );
            }
        } else {
            std::thread::sleep(Duration::from_secs(3600));
        }
    }
}
