//! Step planning with trapezoidal acceleration ramps, one step at a time.
//!
//! The planner keeps the speed *squared* (`v2`, in (microsteps/s)^2) as its
//! state. Under constant acceleration `a`, one step changes `v^2` by exactly
//! `2a`, and the step takes `2 / (v + v')` seconds, so ramps are exact in
//! integer arithmetic (no floating point, no `libm`, deterministic on every
//! target). Before each step the planner picks the fastest speed after the
//! step that still lets it stop on the target:
//!
//! ```text
//! v'^2 = max(v^2 - 2a, min(v^2 + 2a, vmax^2, 2a * (remaining - 1)))
//! ```
//!
//! When the target moves behind the wheel (re-targeting mid-move) the
//! remaining distance is <= 0 and the planner decelerates at `a`, stops and
//! reverses: direction changes are always smooth. Time is only ever passed
//! in (`now_us`); there is no clock inside.

/// Speed limits the planner accepts (keeps every product inside `u64`).
pub const MAX_SPEED_LIMIT: u32 = 200_000;
pub const MAX_ACCEL_LIMIT: u32 = 10_000_000;

/// One step taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepInfo {
    /// +1 clockwise, -1 counter-clockwise.
    pub dir: i8,
    /// When the step was due (microseconds).
    pub at: u64,
    /// Speed squared reached by this step. (From at most `2 * accel`, i.e. at
    /// most one step's worth of speed, the wheel may stop at once: that is
    /// how moves end and how the wheel turns round.)
    pub speed_squared: u64,
}

#[derive(Clone, Debug)]
pub struct Planner {
    pos: i64,
    target: i64,
    /// Speed squared at the last step.
    v2: u64,
    /// Direction of travel, +1 clockwise, -1 counter-clockwise.
    dir: i8,
    max_speed: u32,
    accel: u32,
    /// The next step, if one is planned: (time, direction, speed squared after it).
    next: Option<(u64, i8, u64)>,
}

/// Integer square root (floor).
fn isqrt(x: u64) -> u64 {
    x.isqrt()
}

impl Planner {
    pub fn new(max_speed: u32, accel: u32) -> Planner {
        Planner {
            pos: 0,
            target: 0,
            v2: 0,
            dir: 1,
            max_speed: max_speed.clamp(1, MAX_SPEED_LIMIT),
            accel: accel.clamp(1, MAX_ACCEL_LIMIT),
            next: None,
        }
    }

    /// Position in microsteps, unwrapped (not reduced modulo a turn).
    pub fn position(&self) -> i64 {
        self.pos
    }

    pub fn target(&self) -> i64 {
        self.target
    }

    pub fn max_speed(&self) -> u32 {
        self.max_speed
    }

    pub fn accel(&self) -> u32 {
        self.accel
    }

    /// Signed speed in microsteps/s (positive = clockwise).
    pub fn speed(&self) -> i32 {
        (isqrt(self.v2) as i64 * self.dir as i64) as i32
    }

    /// Speed squared, (microsteps/s)^2: exact, changes by at most `2 * accel` per step.
    pub fn speed_squared(&self) -> u64 {
        self.v2
    }

    pub fn is_moving(&self) -> bool {
        self.next.is_some()
    }

    /// When the next step is due, if one is planned.
    pub fn next_step_at(&self) -> Option<u64> {
        self.next.map(|n| n.0)
    }

    /// Where the wheel would come to rest if it decelerated now (after the
    /// step already planned).
    pub fn stop_point(&self) -> i64 {
        match self.next {
            None => self.pos,
            Some((_, dir, v2n)) => {
                let d = (v2n / self.two_a()) as i64;
                self.pos + dir as i64 + dir as i64 * d
            }
        }
    }

    fn two_a(&self) -> u64 {
        2 * self.accel as u64
    }

    /// Changes the limits; a moving wheel above the new speed decelerates at
    /// the new acceleration.
    pub fn set_motion(&mut self, max_speed: u32, accel: u32) {
        self.max_speed = max_speed.clamp(1, MAX_SPEED_LIMIT);
        self.accel = accel.clamp(1, MAX_ACCEL_LIMIT);
    }

    /// Sets a new absolute (unwrapped) target. A wheel at rest starts now; a
    /// moving one changes course at its next step.
    pub fn set_target(&mut self, target: i64, now_us: u64) {
        self.target = target;
        if self.next.is_none() {
            self.v2 = 0;
            self.plan(now_us);
        }
    }

    /// Decelerates to a stop as fast as the acceleration allows.
    pub fn stop(&mut self, now_us: u64) {
        let p = self.stop_point();
        self.set_target(p, now_us);
    }

    /// Declares the current position to be `pos` (only at rest; returns
    /// false while moving).
    pub fn set_position(&mut self, pos: i64) -> bool {
        if self.next.is_some() {
            return false;
        }
        self.pos = pos;
        self.target = pos;
        true
    }

    /// Takes the planned step if it is due at or before `now_us`.
    pub fn step(&mut self, now_us: u64) -> Option<StepInfo> {
        let (at, dir, v2n) = self.next?;
        if at > now_us {
            return None;
        }
        self.pos += dir as i64;
        self.dir = dir;
        self.v2 = v2n;
        self.next = None;
        if self.pos == self.target && self.v2 <= self.two_a() {
            self.v2 = 0;
        } else {
            self.plan(at);
        }
        Some(StepInfo {
            dir,
            at,
            speed_squared: v2n,
        })
    }

    /// Plans the next step starting from time `t0` (the last step, or now
    /// when starting from rest).
    fn plan(&mut self, mut t0: u64) {
        let two_a = self.two_a();
        let vmax2 = (self.max_speed as u64) * (self.max_speed as u64);
        for _ in 0..3 {
            if self.v2 == 0 {
                if self.pos == self.target {
                    self.next = None;
                    return;
                }
                self.dir = if self.target > self.pos { 1 } else { -1 };
            }
            let rem = (self.target - self.pos) * self.dir as i64;
            let v2n = if rem <= 0 {
                if self.v2 <= two_a {
                    // Stops within this step's time; turn round from rest.
                    t0 += isqrt(self.v2) * 1_000_000 / self.accel as u64;
                    self.v2 = 0;
                    continue;
                }
                self.v2 - two_a
            } else {
                // After this step rem - 1 steps remain, in which v'^2 must
                // come down to zero at `accel`.
                let limit = vmax2.min(two_a.saturating_mul(rem as u64 - 1));
                let faster = self.v2 + two_a;
                let slower = self.v2.saturating_sub(two_a);
                slower.max(faster.min(limit))
            };
            let v = isqrt(self.v2);
            let vn = isqrt(v2n);
            // (v + vn == 0: a one-step move from rest, half accelerating,
            // half braking.)
            let interval = 2_000_000u64
                .checked_div(v + vn)
                .unwrap_or(2_000_000 / isqrt(self.accel as u64).max(1))
                .max(1);
            self.next = Some((t0 + interval, self.dir, v2n));
            return;
        }
        self.next = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_to_rest(p: &mut Planner, mut now: u64) -> (u64, u32) {
        let mut steps = 0;
        while let Some(at) = p.next_step_at() {
            now = at;
            p.step(now).unwrap();
            steps += 1;
            assert!(steps < 10_000_000, "runaway");
        }
        (now, steps)
    }

    #[test]
    fn first_step_from_rest_is_exact() {
        let mut p = Planner::new(3200, 6400);
        p.set_target(10, 1000);
        // sqrt(2 / a) = 17.68 ms for the first step from rest.
        assert_eq!(p.next_step_at(), Some(1000 + 2_000_000 / 113));
    }

    #[test]
    fn half_turn_is_triangular_and_takes_about_one_second() {
        let mut p = Planner::new(3200, 6400);
        p.set_target(1600, 0);
        let (t, steps) = run_to_rest(&mut p, 0);
        assert_eq!(steps, 1600);
        assert_eq!(p.position(), 1600);
        // Ideal: 2 * sqrt(800 / 6400 * 2) = 1.0 s.
        assert!((995_000..=1_005_000).contains(&t), "{t}");
    }
}
