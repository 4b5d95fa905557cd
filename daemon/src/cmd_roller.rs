//! `telextilesd roller ...`: run the simulated roller, or drive a roller directly.
use anyhow::{bail, Context, Result};
use clap::Subcommand;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use telextiles_roller::{
    DriverConfig, PortSpec, RollerDriver, RollerEvent, SimConfig, SimRoller, Target,
};

#[derive(Subcommand)]
pub enum Args {
    /// Run the simulated roller (the real firmware core) on a pseudo-terminal until Ctrl-C
    Sim {
        /// Symlink to create pointing at the pty, e.g. /tmp/roller0
        #[arg(long)]
        link: Option<PathBuf>,
        /// Number of slots on the wheel
        #[arg(long, default_value_t = 16)]
        slots: u16,
        /// Time factor (the simulated motor runs this many times faster)
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
    },
    /// Turn a roller to a slot or angle and wait until it arrives
    Goto {
        /// Serial port (/dev/ttyUSB0, /dev/rfcomm0, a simulator link); auto-detected if absent
        #[arg(long)]
        port: Option<PathBuf>,
        /// Run an in-process simulated roller instead of opening a port
        #[arg(long, conflicts_with = "port")]
        sim: bool,
        /// Target slot (angle = slot x 360 / N)
        #[arg(long, conflicts_with_all = ["angle"], required_unless_present = "angle")]
        slot: Option<u16>,
        /// Target angle in degrees
        #[arg(long)]
        angle: Option<f64>,
        /// Set the slot count N first
        #[arg(long)]
        slots: Option<u16>,
        /// Give up after this many seconds
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
    },
}

pub fn run(args: Args) -> Result<()> {
    let rt = tokio::runtime::Runtime::new().context("starting the tokio runtime")?;
    rt.block_on(async move {
        match args {
            Args::Sim { link, slots, speed } => sim(link, slots, speed).await,
            Args::Goto {
                port,
                sim,
                slot,
                angle,
                slots,
                timeout,
            } => goto(port, sim, slot, angle, slots, timeout).await,
        }
    })
}

async fn sim(link: Option<PathBuf>, slots: u16, speed: f64) -> Result<()> {
    let sim = SimRoller::spawn(SimConfig {
        slots,
        speed,
        link,
        ..SimConfig::default()
    })
    .context("starting the simulated roller")?;
    // The path for scripts (also on stderr); a closed stdout does not stop
    // the simulated roller.
    let _ = writeln!(crate::out::stdout(), "{}", sim.path().display());
    eprintln!(
        "simulated roller on {} ({slots} slots); Ctrl-C to stop",
        sim.path().display()
    );
    tokio::signal::ctrl_c()
        .await
        .context("waiting for Ctrl-C")?;
    sim.shutdown();
    Ok(())
}

async fn goto(
    port: Option<PathBuf>,
    use_sim: bool,
    slot: Option<u16>,
    angle: Option<f64>,
    slots: Option<u16>,
    timeout: f64,
) -> Result<()> {
    let target = match (slot, angle) {
        (Some(s), _) => Target::Slot(s),
        (None, Some(a)) if a.is_finite() => {
            Target::AngleMdeg((a.rem_euclid(360.0) * 1000.0).round() as u32 % 360_000)
        }
        _ => bail!("give --slot N or --angle DEGREES (a finite number)"),
    };
    if !(timeout.is_finite() && timeout > 0.0) {
        bail!("--timeout must be a positive number of seconds");
    }
    let sim = if use_sim {
        Some(SimRoller::spawn(SimConfig::default()).context("starting the simulated roller")?)
    } else {
        None
    };
    let port = match (&sim, port) {
        (Some(s), _) => PortSpec::Path(s.path()),
        (None, Some(p)) => PortSpec::Path(p),
        (None, None) => PortSpec::Auto,
    };
    let driver = RollerDriver::start(DriverConfig {
        port,
        slots,
        ..DriverConfig::auto()
    });
    let mut events = driver.subscribe();
    driver.set_target(target);
    let wait = driver.wait_arrived(target, Duration::from_secs_f64(timeout));
    tokio::pin!(wait);
    loop {
        tokio::select! {
            r = &mut wait => {
                let s = r.map_err(|e| {
                    let why = driver.state().port.map_or_else(
                        || " (no roller connected)".to_string(),
                        |p| format!(" on {p}"),
                    );
                    anyhow::anyhow!("{e}{why}")
                })?;
                writeln!(
                    crate::out::stdout(),
                    "arrived at {target:?}: position {} microsteps",
                    s.position
                )?;
                return Ok(());
            }
            e = events.recv() => match e {
                Ok(RollerEvent::Error { message }) => eprintln!("roller: {message}"),
                Ok(RollerEvent::Disconnected { reason }) => eprintln!("roller: {reason}"),
                Ok(RollerEvent::Connected { port, version }) => eprintln!(
                    "roller: connected on {port}: firmware {}.{}.{}, {} slots",
                    version.firmware[0], version.firmware[1], version.firmware[2], version.slots
                ),
                _ => {}
            }
        }
    }
}
