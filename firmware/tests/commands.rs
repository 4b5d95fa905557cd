//! The firmware core driven through its byte interface: commands, replies,
//! the paper's geometry, re-targeting, the link watchdog.
use roller_firmware::{Config, Roller};
use telextiles_proto::roller::*;

struct Bench {
    fw: Roller,
    now: u64,
    dec: FrameDecoder,
    seq: u8,
    /// Direction of every step taken.
    steps: Vec<i8>,
}

impl Bench {
    /// A slow wheel (1 rev/s, 2 rev/s^2, common AccelStepper settings):
    /// moves long enough for the timing of replies to be checked.
    fn new() -> Bench {
        Bench::with(Config {
            max_speed: 3200,
            accel: 6400,
            ..Config::default()
        })
    }

    fn with(cfg: Config) -> Bench {
        Bench {
            fw: Roller::new(cfg),
            now: 0,
            dec: FrameDecoder::new(),
            seq: 0,
            steps: Vec::new(),
        }
    }

    fn replies(&mut self) -> Vec<(u8, Reply)> {
        let mut buf = [0u8; 1024];
        let n = self.fw.take_output(&mut buf);
        self.dec
            .feed(&buf[..n])
            .map(|f| {
                let f = f.expect("firmware frames are well formed");
                (f.seq, Reply::from_frame(&f).expect("a known reply"))
            })
            .collect()
    }

    /// Sends a command; returns the replies it caused (earlier output is dropped).
    fn send(&mut self, c: Command) -> Vec<(u8, Reply)> {
        self.replies();
        self.seq = self.seq.wrapping_add(1);
        let f = c.encode(self.seq);
        self.fw.receive(f.as_bytes(), self.now);
        self.replies()
    }

    /// Runs the motor until `until` (or until rest when `None`).
    fn run(&mut self, until: Option<u64>) {
        while let Some(t) = self.fw.next_event_at() {
            if until.is_some_and(|u| t > u) {
                break;
            }
            self.now = self.now.max(t);
            self.fw.check_and_tick(self.now, &mut self.steps);
            if until.is_none() && !self.fw.planner().is_moving() {
                break;
            }
        }
        if let Some(u) = until {
            self.now = self.now.max(u);
            self.fw.check_and_tick(self.now, &mut self.steps);
        }
    }
}

trait TickExt {
    fn check_and_tick(&mut self, now: u64, steps: &mut Vec<i8>);
}

impl TickExt for Roller {
    fn check_and_tick(&mut self, now: u64, steps: &mut Vec<i8>) {
        // Step one at a time, like the hardware binding, recording directions.
        while let Some(d) = self.step(now) {
            steps.push(d);
        }
        self.tick(now);
    }
}

fn ack(r: &[(u8, Reply)]) -> Status {
    match r.first() {
        Some((_, Reply::Ack(s))) => *s,
        other => panic!("expected Ack, got {other:?}"),
    }
}

#[test]
fn hello_reports_version_and_geometry() {
    let mut b = Bench::new();
    let r = b.send(Command::Hello {
        protocol: PROTOCOL_VERSION,
    });
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].0, 1);
    let Reply::Version(v) = r[0].1 else {
        panic!("{r:?}")
    };
    assert_eq!(v.protocol, PROTOCOL_VERSION);
    assert_eq!(v.steps_per_rev, 3200);
    assert_eq!(v.slots, 16);
    assert_eq!(v.watchdog_ms, 2000);
}

#[test]
fn goto_slot_acks_then_arrives_with_the_same_sequence() {
    let mut b = Bench::new();
    let r = b.send(Command::GotoSlot { slot: 2 });
    let s = ack(&r);
    assert_eq!(s.target, 400);
    assert!(s.moving() && s.enabled());
    b.run(None);
    let r = b.replies();
    let (seq, Reply::Arrived(s)) = *r.last().unwrap() else {
        panic!("{r:?}")
    };
    assert_eq!(seq, 1);
    assert_eq!(s.position, 400);
    assert!(!s.moving());
    // Periodic status frames were sent while moving (a ~0.5 s move, every 100 ms).
    let statuses = r.iter().filter(|x| matches!(x.1, Reply::Status(_))).count();
    assert!((3..=6).contains(&statuses), "{statuses}");
    assert_eq!(b.steps.len(), 400);
}

#[test]
fn shortest_path_both_ways_and_across_zero() {
    let mut b = Bench::new();
    // 0 -> slot 15 (337.5 deg): counter-clockwise, 200 steps.
    b.send(Command::GotoSlot { slot: 15 });
    b.run(None);
    assert_eq!(b.fw.position_steps(), 3000);
    assert_eq!(b.fw.absolute_steps(), -200);
    assert!(b.steps.iter().all(|&d| d == -1) && b.steps.len() == 200);
    // slot 15 -> slot 2: clockwise across zero, 3 slots = 600 steps.
    b.steps.clear();
    b.send(Command::GotoSlot { slot: 2 });
    b.run(None);
    assert_eq!(b.fw.position_steps(), 400);
    assert_eq!(b.fw.absolute_steps(), 400);
    assert!(b.steps.iter().all(|&d| d == 1) && b.steps.len() == 600);
    // slot 2 -> slot 9: 7 slots clockwise (157.5 deg) is shorter than 9 back.
    b.steps.clear();
    b.send(Command::GotoSlot { slot: 9 });
    b.run(None);
    assert!(b.steps.iter().all(|&d| d == 1) && b.steps.len() == 1400);
    // slot 9 -> slot 1: exactly half a turn: counter-clockwise (not shorter clockwise).
    b.steps.clear();
    b.send(Command::GotoSlot { slot: 1 });
    b.run(None);
    assert_eq!(b.fw.position_steps(), 200);
    assert!(b.steps.iter().all(|&d| d == -1) && b.steps.len() == 1600);
    // Angles: 350 deg from 22.5 deg goes counter-clockwise 32.5 deg across zero.
    b.steps.clear();
    b.send(Command::GotoAngle { mdeg: 350_000 });
    b.run(None);
    assert_eq!(b.fw.position_steps(), 3111); // 350/360*3200 = 3111.1
    assert!(b.steps.iter().all(|&d| d == -1) && b.steps.len() == 289);
}

#[test]
fn other_slot_counts() {
    let mut b = Bench::new();
    ack(&b.send(Command::SetSlots { slots: 7 }));
    b.send(Command::GotoSlot { slot: 3 });
    b.run(None);
    assert_eq!(b.fw.position_steps(), 1371); // 3 * 3200 / 7 = 1371.4
    let r = b.send(Command::GotoSlot { slot: 7 });
    assert_eq!(
        r[0].1,
        Reply::Error {
            code: ErrorCode::BadArgument,
            command: kind::GOTO_SLOT
        }
    );
    let r = b.send(Command::SetSlots { slots: 4000 });
    assert!(matches!(
        r[0].1,
        Reply::Error {
            code: ErrorCode::BadArgument,
            ..
        }
    ));
}

#[test]
fn retarget_mid_move_reverses_once_and_lands() {
    let mut b = Bench::new();
    b.send(Command::GotoSlot { slot: 4 }); // 800 steps clockwise
    b.run(Some(400_000));
    assert!(b.fw.planner().is_moving());
    let mid = b.fw.absolute_steps();
    assert!(mid > 200 && mid < 800, "{mid}");
    let r = b.send(Command::GotoSlot { slot: 14 }); // 2 slots counter-clockwise of 0
    assert!(ack(&r).moving());
    b.run(None);
    assert_eq!(b.fw.position_steps(), 2800);
    let reversals = b.steps.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(reversals, 1);
    let r = b.replies();
    let arrived: Vec<_> = r
        .iter()
        .filter(|x| matches!(x.1, Reply::Arrived(_)))
        .collect();
    assert_eq!(arrived.len(), 1, "only the latest target reports arrival");
    assert_eq!(arrived[0].0, b.seq);
}

#[test]
fn repeating_the_current_target_does_not_change_course() {
    let mut b = Bench::new();
    b.send(Command::GotoSlot { slot: 8 }); // half turn: counter-clockwise
    b.run(Some(500_000));
    let before = b.fw.planner().target();
    // The same decision again (or a retry) while moving: no new shortest-path choice.
    b.send(Command::GotoSlot { slot: 8 });
    assert_eq!(b.fw.planner().target(), before);
    b.run(None);
    assert_eq!(b.fw.absolute_steps(), -1600);
}

#[test]
fn zero_only_at_rest_and_stop_stops() {
    let mut b = Bench::new();
    b.send(Command::GotoSlot { slot: 4 });
    b.run(Some(300_000));
    let r = b.send(Command::Zero);
    assert_eq!(
        r[0].1,
        Reply::Error {
            code: ErrorCode::Busy,
            command: kind::ZERO
        }
    );
    b.send(Command::Stop);
    b.run(None);
    let p = b.fw.position_steps();
    assert!(p > 0 && p < 800, "{p}");
    assert!(matches!(b.replies().last(), Some((_, Reply::Arrived(_)))));
    ack(&b.send(Command::Zero));
    assert_eq!(b.fw.position_steps(), 0);
    b.send(Command::GotoSlot { slot: 1 });
    b.run(None);
    assert_eq!(b.fw.absolute_steps(), 200);
}

#[test]
fn set_motion_changes_timing() {
    let mut b = Bench::new();
    ack(&b.send(Command::SetMotion {
        max_speed: 6400,
        accel: 25_600,
    }));
    b.send(Command::GotoSlot { slot: 8 });
    let t0 = b.now;
    b.run(None);
    // Triangular half turn at 4x the acceleration: 2 * sqrt(1600 / 25600) = 0.5 s.
    let dt = b.now - t0;
    assert!((480_000..=520_000).contains(&dt), "{dt}");
    let r = b.send(Command::SetMotion {
        max_speed: 1_000_000,
        accel: 1,
    });
    assert!(matches!(
        r[0].1,
        Reply::Error {
            code: ErrorCode::BadArgument,
            ..
        }
    ));
}

#[test]
fn bad_frames_get_no_reply_unknown_commands_get_an_error() {
    let mut b = Bench::new();
    let mut f = Command::GotoSlot { slot: 3 }.encode(9).as_bytes().to_vec();
    f[6] ^= 1;
    b.fw.receive(&f, 0);
    assert!(b.replies().is_empty());
    assert_eq!(b.fw.bad_frames(), 1);
    assert!(!b.fw.planner().is_moving());
    let unknown = Frame::new(5, 0x33, &[1, 2]).unwrap().encode();
    b.fw.receive(unknown.as_bytes(), 0);
    assert_eq!(
        b.replies(),
        vec![(
            5,
            Reply::Error {
                code: ErrorCode::UnknownCommand,
                command: 0x33
            }
        )]
    );
    // Garbage around a good frame: the good frame still gets through.
    let mut line = vec![0xA5, 0x00, 0xFF, 0xA5, 0x5A, 0x30];
    line.extend_from_slice(Command::QueryStatus.encode(6).as_bytes());
    b.fw.receive(&line, 0);
    assert!(matches!(b.replies()[..], [(6, Reply::Status(_))]));
}

#[test]
fn watchdog_stops_a_silent_link_and_a_command_revives_it() {
    let mut b = Bench::new();
    b.send(Command::GotoSteps { steps: 1600 });
    // Silent for more than the 2 s watchdog while a 1 s move runs? The move
    // ends first and the driver is switched off only after the silence.
    b.run(None);
    assert!(b.fw.motor_enabled());
    b.run(Some(b.now + 2_100_000));
    assert!(!b.fw.motor_enabled());
    assert!(b.fw.watchdog_tripped());
    let s = match b.send(Command::QueryStatus)[..] {
        [(_, Reply::Status(s))] => s,
        ref r => panic!("{r:?}"),
    };
    assert!(s.watchdog_tripped() && !s.enabled());

    // Mid-move silence: a long move at a low speed is cut short by a
    // controlled stop, without Arrived, and the driver is disabled.
    ack(&b.send(Command::SetMotion {
        max_speed: 400,
        accel: 6400,
    }));
    b.send(Command::GotoSteps { steps: 0 }); // 1600 steps at 400/s = 4 s
    let start = b.fw.absolute_steps();
    b.run(Some(b.now + 2_500_000));
    assert!(!b.fw.planner().is_moving());
    assert!(!b.fw.motor_enabled());
    let moved = (b.fw.absolute_steps() - start).abs();
    assert!((700..=900).contains(&moved), "{moved}"); // ~2 s at 400/s
    assert!(!b.replies().iter().any(|r| matches!(r.1, Reply::Arrived(_))));
    // The host comes back and re-sends the target: it completes.
    let s = ack(&b.send(Command::GotoSteps { steps: 0 }));
    assert!(s.enabled() && !s.watchdog_tripped());
    b.run(None);
    assert_eq!(b.fw.position_steps(), 0);
}

#[test]
fn at_target_already_arrives_immediately() {
    let mut b = Bench::new();
    let r = b.send(Command::GotoSlot { slot: 0 });
    assert!(
        matches!(r[..], [(1, Reply::Ack(_)), (1, Reply::Arrived(_))]),
        "{r:?}"
    );
}

/// The default configuration is the paper's wheel (16 slots, 1/16
/// microstepping, 3 rev/s, 30 rev/s^2): one slot in about 91 ms, a quarter
/// turn in 183 ms, a half turn in 267 ms, rest to rest, in simulated time.
#[test]
fn the_paper_wheel_moves_a_slot_a_quarter_and_a_half_turn_in_time() {
    for (slot, ideal_ms) in [(1u16, 91.3), (4, 182.6), (8, 266.7)] {
        let mut b = Bench::with(Config::default());
        let t0 = b.now;
        b.send(Command::GotoSlot { slot });
        b.run(None);
        assert_eq!(b.fw.position_steps(), slot as u32 * 200);
        let ms = (b.now - t0) as f64 / 1000.0;
        assert!((ms - ideal_ms).abs() < 3.0, "slot {slot}: {ms} ms");
    }
}

/// A new target while moving, further the same way, is taken from the
/// current speed: the wheel never stops on the way, and arrives sooner than
/// stopping at the first target and starting again would.
#[test]
fn a_new_target_while_moving_is_taken_without_stopping() {
    let mut b = Bench::with(Config::default());
    b.send(Command::GotoSlot { slot: 2 });
    b.run(Some(50_000));
    assert!(b.fw.planner().is_moving());
    b.send(Command::GotoSlot { slot: 6 });
    let mut stopped_on_the_way = false;
    while b.fw.planner().is_moving() {
        let t = b.fw.next_event_at().unwrap();
        b.now = b.now.max(t);
        b.fw.check_and_tick(b.now, &mut b.steps);
        if b.fw.planner().speed_squared() == 0 && b.fw.planner().is_moving() {
            stopped_on_the_way = true;
        }
    }
    assert!(!stopped_on_the_way);
    assert_eq!(b.fw.position_steps(), 1200);
    assert!(b.steps.iter().all(|&d| d == 1), "no reversal");
    // Straight to slot 6 from rest: 2 * sqrt(1200 / 96000) = 224 ms (the
    // target came 50 ms in, on the way): well under 50 + 224 + a stop.
    assert!(b.now < 235_000, "{} us", b.now);
}
