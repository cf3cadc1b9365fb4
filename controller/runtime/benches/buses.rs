//! Bench: every bus at its own rate under the 50 Hz policy, on the reference robot.
//!
//! Per bus: the rate achieved, cycle time p50/p99 (send to last reply), bus load (worst-case wire
//! time over the period), overruns, and the age of each joint's feedback when the policy tick
//! reads it (p50/p99), in lockstep on the mirror and in real time over socketcand and
//! pseudo-terminals. Then the stale-detection latency: a Dynamixel servo and an MIT motor vanish
//! between two ticks; how long until their bus damps itself and until the loop damps the robot.
//!
//! Run: `cargo bench -p controller --bench buses` (`-- --bench` for a 30 s wall-clock run; the
//! smoke run takes 3 s).

use std::fmt::Write as _;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use controller::player::{EndMode, PlayOptions, Player};
use controller::safety::Mode;
use controller::sim::{lockstep_player, wired_player};
use firmware_bridge::time::SimWorld;
use robot_link::{RobotLink, TickClock};
use sim2real::config::{FaultKind, MirrorConfig, ScheduledFault};
use test_support::stats::Summary;

#[path = "common/mod.rs"]
mod common;
use common::files;

fn options(ticks: u64) -> PlayOptions {
    PlayOptions {
        end: EndMode::Loop,
        max_ticks: Some(ticks),
        ..PlayOptions::default()
    }
}

/// Runs `p` tick by tick for `ticks`, collecting each bus's feedback ages at every tick.
fn run_collecting_ages<L: RobotLink>(
    p: &mut Player<L>,
    clock: &mut dyn TickClock,
    ticks: u32,
) -> (Vec<Vec<Duration>>, Duration) {
    p.identify().unwrap();
    let robot = p.robot().clone();
    let names = p.link().bus_names().to_vec();
    let mut ages = vec![Vec::with_capacity(ticks as usize * 8); names.len()];
    let period = Duration::from_millis(20);
    let start = clock.elapsed();
    for k in 1..=ticks {
        p.step(clock).unwrap();
        if k > 60 {
            for (b, name) in names.iter().enumerate() {
                for (i, _) in robot.joints_on(name) {
                    ages[b].push(p.state().age[i]);
                }
            }
        }
        p.wait_until(clock, start + period * k);
    }
    (ages, clock.elapsed() - start)
}

fn table<L: RobotLink>(p: &Player<L>, ages: &mut [Vec<Duration>], elapsed: Duration) -> String {
    let robot = p.robot();
    let mut out = String::new();
    let _ = writeln!(
        out,
        "  {:<6} {:>9} {:>9} {:>6} {:>14} {:>9} {:>16} {:>18}",
        "bus",
        "set Hz",
        "achieved",
        "load",
        "cycle p50/p99",
        "overruns",
        "age p50/p99",
        "targets out p50/p99"
    );
    for ((name, st), ages) in p.link().bus_names().iter().zip(p.link().bus_stats()).zip(ages) {
        let timing = robot.bus_timing(name).unwrap();
        let ms = |d: Option<Duration>| d.map_or("> 20".into(), |d| format!("{:.2}", d.as_secs_f64() * 1e3));
        let age = Summary::of(ages).unwrap();
        let _ = writeln!(
            out,
            "  {:<6} {:>9.0} {:>9.1} {:>5.0}% {:>6}/{:<6}ms {:>9} {:>7.2}/{:<5.2} ms {:>9}/{:<5} ms",
            name,
            timing.rate_hz,
            st.cycles as f64 / elapsed.as_secs_f64(),
            timing.load() * 100.0,
            ms(st.cycle_times.quantile(0.5)),
            ms(st.cycle_times.quantile(0.99)),
            st.overruns,
            age.p50_us / 1e3,
            age.p99_us / 1e3,
            ms(st.command_latency.quantile(0.5)),
            ms(st.command_latency.quantile(0.99)),
        );
    }
    out
}

fn lockstep(ticks: u32) -> String {
    let (robot, layout, reference) = files();
    let stop = Arc::new(AtomicBool::new(false));
    let (mut p, mut clock, _world) = lockstep_player(
        robot,
        layout,
        reference,
        options(u64::from(ticks) + 10),
        MirrorConfig::default(),
        stop,
    )
    .unwrap();
    let (mut ages, elapsed) = run_collecting_ages(&mut p, &mut clock, ticks);
    table(&p, &mut ages, elapsed)
}

fn wall(seconds: f64, realtime: bool) -> String {
    let (robot, layout, reference) = files();
    let mut out = String::new();
    let on_start: fn() = if realtime {
        let cpus = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
        for step in controller::realtime::setup(80, Some(cpus - 1)).steps {
            let _ = writeln!(out, "  realtime: {step}");
        }
        controller::realtime::bus_thread
    } else {
        || {}
    };
    let ticks = (seconds * 50.0) as u32;
    let mirror = MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    // The served mirror shares two cores with the loop and a dozen threads: a pseudo-terminal or
    // socket now and then answers 10–20 ms late. The run goes on through that (8 silent cycles
    // stop it, not 2) so the whole run is measured; the lateness shows in the p99s.
    let mut opts = options(u64::from(ticks) + 10);
    opts.limits.stale_cycles = 8;
    let (mut p, mut clock, _served) =
        wired_player(robot, layout, reference, opts, mirror, stop, on_start).unwrap();
    let (mut ages, elapsed) = run_collecting_ages(&mut p, &mut clock, ticks);
    out.push_str(&table(&p, &mut ages, elapsed));
    if let Some(t) = p.transitions().iter().find(|t| t.cause.is_fault()) {
        let _ = writeln!(out, "  the run stopped at tick {}: {}", t.tick, t.cause);
    }
    out
}

/// A joint vanishes 7 ms after a tick; how long until its bus damps itself, and until the loop
/// goes to damping.
fn stale_detection(joint: &str, bus: &str) -> String {
    let (robot, layout, reference) = files();
    let vanish = Duration::from_millis(3007);
    let mirror = MirrorConfig {
        faults: vec![ScheduledFault {
            at_s: vanish.as_secs_f64(),
            joint: joint.into(),
            fault: FaultKind::Vanish,
        }],
        ..MirrorConfig::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (mut p, mut clock, world) =
        lockstep_player(robot, layout, reference, options(400), mirror, stop).unwrap();
    let s = p.run(&mut clock).unwrap();
    let mirror_now = world
        .lock()
        .unwrap()
        .now()
        .saturating_since(firmware_bridge::time::SimInstant::ZERO);
    let offset = mirror_now - clock.elapsed();
    let k = p.link().bus_names().iter().position(|n| n == bus).unwrap();
    let st = p.link().bus_stats()[k];
    let bus_ms = st.damped_at.map_or(f64::NAN, |t| {
        (t + offset).saturating_sub(vanish).as_secs_f64() * 1e3
    });
    let loop_ms = s
        .transitions
        .iter()
        .find(|t| t.to == Mode::Damped)
        .map_or(f64::NAN, |t| {
            (Duration::from_millis(20) * t.tick as u32 + offset)
                .saturating_sub(vanish)
                .as_secs_f64()
                * 1e3
        });
    format!(
        "  {joint} on {bus} ({} Hz): bus damped itself {bus_ms:.1} ms after the vanish, the loop damped the robot {loop_ms:.1} ms after",
        p.robot().bus_timing(bus).unwrap().rate_hz
    )
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    println!("rd-biped: 2 CAN buses of 6 MIT motors, 8 Dynamixel servos on one line, 50 Hz policy");
    println!(
        "lockstep on the mirror (simulated time), 20 s (replies are taken when due: the round trip's estimate plus a margin, so that is the cycle time here):\n{}",
        lockstep(1000)
    );
    let seconds = if quick { 3.0 } else { 20.0 };
    println!(
        "wall clock, {seconds:.0} s over socketcand + pseudo-terminals (the mirror served in real time, stale after 8 cycles):\n{}",
        wall(seconds, false)
    );
    println!("stale detection (lockstep):");
    println!("{}", stale_detection("left_elbow", "dxl0"));
    println!("{}", stale_detection("left_knee", "can0"));
    // Last: the process's loop thread stays under SCHED_FIFO after this.
    println!(
        "wall clock again, with the real-time set-up of `play --realtime` (loop SCHED_FIFO 80 pinned to the last CPU, bus threads SCHED_FIFO 85):\n{}",
        wall(seconds, true)
    );
}
