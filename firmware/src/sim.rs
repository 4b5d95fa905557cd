//! Host simulator: the firmware core on a pseudo-terminal, in real time.
//!
//! [`SimRoller::spawn`] opens a pty, optionally points a symlink at its slave
//! side (a stable path like `/tmp/roller0` for the daemon), and runs the very
//! same [`Roller`] core on a thread: bytes from the pty go into
//! [`Roller::receive`], [`Roller::tick`] moves the simulated motor on the
//! wall clock (times a speed factor), replies go back out. The simulated
//! wheel's position is the firmware's step count: the ground truth tests
//! compare the driver's view against.
//!
//! Link faults for tests: [`SimRoller::disconnect`] closes the pty (the
//! daemon's port reports an error, like a Bluetooth drop; the firmware keeps
//! running), [`SimRoller::reconnect`] opens a new pty and repoints the
//! symlink; garbage can be injected in either direction, and random
//! corruption switched on with [`Noise`].

use crate::{Config, Roller};
use serialport::{SerialPort, TTYPort};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use telextiles_proto::roller::Status;

/// Random line corruption.
#[derive(Clone, Copy, Debug)]
pub struct Noise {
    /// Probability that a byte (either direction) gets one bit flipped.
    pub corrupt_per_byte: f64,
    pub seed: u64,
}

/// Simulator settings. Durations are wall-clock; the simulator scales them
/// into firmware time by `speed`.
#[derive(Clone, Debug)]
pub struct SimConfig {
    pub slots: u16,
    /// Firmware time runs this many times faster than the wall clock
    /// (1.0 = a real roller; tests use 10-40 to keep each move short).
    pub speed: f64,
    /// Maximum speed and acceleration in firmware units (microsteps/s, /s^2).
    pub max_speed: u32,
    pub accel: u32,
    /// Link watchdog (wall clock).
    pub watchdog: Duration,
    /// Status report period while moving (wall clock).
    pub status_interval: Duration,
    /// A symlink to create (atomically replaced) pointing at the pty's slave.
    pub link: Option<PathBuf>,
    /// Start position in microsteps (unwrapped), e.g. to model a restart.
    pub initial_steps: i64,
    pub noise: Option<Noise>,
}

impl Default for SimConfig {
    fn default() -> Self {
        let c = Config::default();
        SimConfig {
            slots: c.slots,
            speed: 1.0,
            max_speed: c.max_speed,
            accel: c.accel,
            watchdog: Duration::from_micros(c.watchdog_us),
            status_interval: Duration::from_micros(c.status_interval_us),
            link: None,
            initial_steps: 0,
            noise: None,
        }
    }
}

struct Pty {
    master: TTYPort,
    /// Held open so the master never sees EIO while the host has the port
    /// closed; it is never read.
    _slave: TTYPort,
    path: PathBuf,
}

struct Shared {
    fw: Roller,
    pty: Option<Pty>,
    to_host: Vec<u8>,
    to_fw: Vec<u8>,
    rng: u64,
    noise: Option<Noise>,
    bytes_in: u64,
    bytes_out: u64,
}

/// A simulated roller on a pty, running on its own thread.
pub struct SimRoller {
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    link: Option<PathBuf>,
    speed: f64,
    epoch: Instant,
}

fn open_pty() -> io::Result<Pty> {
    // `pair` takes no locks (no TIOCEXCL, no flock), so the host can open the
    // slave path (even exclusively) while we hold our end of it.
    let (mut master, slave) = TTYPort::pair().map_err(io::Error::other)?;
    master
        .set_timeout(Duration::from_millis(0))
        .map_err(io::Error::other)?;
    let path = slave
        .name()
        .map(PathBuf::from)
        .ok_or_else(|| io::Error::other("pty slave has no name"))?;
    Ok(Pty {
        master,
        _slave: slave,
        path,
    })
}

/// Points `link` at `target`, replacing any previous link atomically.
fn set_link(link: &Path, target: &Path) -> io::Result<()> {
    let mut tmp = link.as_os_str().to_owned();
    tmp.push(format!(".tmp{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

impl Shared {
    fn next_rand(&mut self) -> u64 {
        // xorshift64*
        let mut x = self.rng;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.rng = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn corrupt(&mut self, bytes: &mut [u8]) {
        let Some(n) = self.noise else { return };
        for b in bytes.iter_mut() {
            let r = self.next_rand();
            if ((r >> 11) as f64 / (1u64 << 53) as f64) < n.corrupt_per_byte {
                *b ^= 1 << (r & 7);
            }
        }
    }

    /// One round: read, feed the firmware, move the motor, write replies.
    fn pump(&mut self, now_us: u64) {
        let mut buf = [0u8; 512];
        let mut input = std::mem::take(&mut self.to_fw);
        let mut line = Vec::new();
        if let Some(pty) = self.pty.as_mut() {
            loop {
                match pty.master.read(&mut buf) {
                    Ok(0) => break,
                    Ok(n) => {
                        line.extend_from_slice(&buf[..n]);
                        if n < buf.len() {
                            break;
                        }
                    }
                    Err(_) => break,
                }
            }
        }
        self.corrupt(&mut line);
        input.extend_from_slice(&line);
        self.bytes_in += input.len() as u64;
        if !input.is_empty() {
            self.fw.receive(&input, now_us);
        }
        self.fw.tick(now_us);
        let mut out = std::mem::take(&mut self.to_host);
        loop {
            let n = self.fw.take_output(&mut buf);
            if n == 0 {
                break;
            }
            let mut chunk = buf[..n].to_vec();
            self.corrupt(&mut chunk);
            out.extend_from_slice(&chunk);
        }
        if let Some(pty) = self.pty.as_mut() {
            // A full pty buffer (nobody reading) drops bytes, like a UART.
            let mut rest = &out[..];
            while !rest.is_empty() {
                match pty.master.write(rest) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => rest = &rest[n..],
                }
            }
            self.bytes_out += (out.len() - rest.len()) as u64;
        }
    }
}

impl SimRoller {
    /// Opens a pty, creates the link (if asked) and starts the simulator thread.
    pub fn spawn(cfg: SimConfig) -> io::Result<SimRoller> {
        if !(cfg.speed.is_finite() && cfg.speed > 0.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("simulator speed factor must be > 0, got {}", cfg.speed),
            ));
        }
        let scale = |d: Duration| (d.as_micros() as f64 * cfg.speed) as u64;
        let fw_cfg = Config {
            slots: cfg.slots.max(1),
            max_speed: cfg.max_speed,
            accel: cfg.accel,
            watchdog_us: scale(cfg.watchdog).max(1),
            status_interval_us: scale(cfg.status_interval).max(1),
            ..Config::default()
        };
        let fw = Roller::new(fw_cfg).with_position(cfg.initial_steps);
        let pty = open_pty()?;
        if let Some(link) = &cfg.link {
            set_link(link, &pty.path)?;
        }
        let shared = Arc::new(Mutex::new(Shared {
            fw,
            pty: Some(pty),
            to_host: Vec::new(),
            to_fw: Vec::new(),
            rng: cfg.noise.map_or(1, |n| n.seed | 1),
            noise: cfg.noise,
            bytes_in: 0,
            bytes_out: 0,
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let epoch = Instant::now();
        let speed = cfg.speed;
        let thread = {
            let shared = shared.clone();
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("roller-sim".into())
                .spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        let now_us = (epoch.elapsed().as_micros() as f64 * speed) as u64;
                        let wait = {
                            let mut s = shared.lock().unwrap_or_else(|e| e.into_inner());
                            s.pump(now_us);
                            s.fw.next_event_at()
                        };
                        let real_wait = wait
                            .map(|t| t.saturating_sub(now_us) as f64 / speed)
                            .unwrap_or(1000.0)
                            .clamp(50.0, 1000.0);
                        std::thread::sleep(Duration::from_micros(real_wait as u64));
                    }
                })?
        };
        Ok(SimRoller {
            shared,
            stop,
            thread: Some(thread),
            link: cfg.link,
            speed,
            epoch,
        })
    }

    fn lock(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The path a driver should open: the link if one was asked for, else
    /// the current pty slave.
    pub fn path(&self) -> PathBuf {
        match &self.link {
            Some(l) => l.clone(),
            None => self.slave_path().unwrap_or_default(),
        }
    }

    /// The current pty slave (`None` while disconnected).
    pub fn slave_path(&self) -> Option<PathBuf> {
        self.lock().pty.as_ref().map(|p| p.path.clone())
    }

    /// Firmware time now, in microseconds.
    pub fn now_us(&self) -> u64 {
        (self.epoch.elapsed().as_micros() as f64 * self.speed) as u64
    }

    /// The simulated wheel's position, microsteps `0..steps_per_rev`.
    pub fn position_steps(&self) -> u32 {
        self.lock().fw.position_steps()
    }

    /// Unwrapped position (counts whole turns).
    pub fn absolute_steps(&self) -> i64 {
        self.lock().fw.absolute_steps()
    }

    pub fn steps_per_rev(&self) -> u32 {
        self.lock().fw.steps_per_rev()
    }

    pub fn status(&self) -> Status {
        self.lock().fw.status()
    }

    pub fn is_moving(&self) -> bool {
        self.lock().fw.planner().is_moving()
    }

    /// Bytes received from / sent to the host so far.
    pub fn traffic(&self) -> (u64, u64) {
        let s = self.lock();
        (s.bytes_in, s.bytes_out)
    }

    /// Frames the firmware dropped for bad checksums or lengths.
    pub fn bad_frames(&self) -> u32 {
        self.lock().fw.bad_frames()
    }

    /// Runs `f` on the firmware (for tests that inspect its state).
    pub fn with_firmware<R>(&self, f: impl FnOnce(&Roller) -> R) -> R {
        f(&self.lock().fw)
    }

    /// Closes the pty: the host's open port sees an error, the slave path
    /// vanishes and so does the link (like an unplugged USB adapter or a
    /// dropped rfcomm device; it also keeps a host from reopening a pty
    /// number the system hands to someone else meanwhile). The firmware
    /// keeps running.
    pub fn disconnect(&self) {
        let mut s = self.lock();
        if let Some(link) = &self.link {
            let _ = std::fs::remove_file(link);
        }
        s.pty = None;
    }

    /// Opens a fresh pty and repoints the link at it.
    pub fn reconnect(&self) -> io::Result<PathBuf> {
        let pty = open_pty()?;
        let path = pty.path.clone();
        if let Some(link) = &self.link {
            set_link(link, &path)?;
        }
        self.lock().pty = Some(pty);
        Ok(path)
    }

    /// Sends raw bytes towards the host (line noise).
    pub fn inject_to_host(&self, bytes: &[u8]) {
        self.lock().to_host.extend_from_slice(bytes);
    }

    /// Feeds raw bytes to the firmware as if received on the line.
    pub fn inject_to_firmware(&self, bytes: &[u8]) {
        self.lock().to_fw.extend_from_slice(bytes);
    }

    /// Switches random corruption on or off.
    pub fn set_noise(&self, noise: Option<Noise>) {
        let mut s = self.lock();
        if let Some(n) = noise {
            s.rng = n.seed | 1;
        }
        s.noise = noise;
    }

    /// Stops the thread, closes the pty and removes the link.
    pub fn shutdown(mut self) {
        self.stop_inner();
    }

    fn stop_inner(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.lock().pty = None;
        if let Some(link) = &self.link {
            let _ = std::fs::remove_file(link);
        }
    }
}

impl Drop for SimRoller {
    fn drop(&mut self) {
        self.stop_inner();
    }
}
