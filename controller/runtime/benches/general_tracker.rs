//! Bench: a trained general tracker's tick — TWIST2 on the G1 with its 1432-value observation
//! (current block, ten past copies, the reference again) — following a retargeted walk on the
//! mirror in lockstep: the loop's compute per tick (observation, inference, action mapping,
//! safety) at p50/p99/max, and wall time per simulated second of the whole path (1 ms physics,
//! the emulated board at 500 Hz). The tick's allocations are tested, not benched
//! (tests/tests/general_tracker.rs).
//!
//! `cargo bench` plays all of walk_001 (13.9 s); the smoke run of `cargo test --benches` 2 s.
//! Needs ../shared/third_party/twist2 (read in place): without it the bench says so and ends.
//!
//! Run: `cargo bench -p controller --bench general_tracker`

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use controller::clip::{Clip, Reference};
use controller::player::PlayOptions;
use controller::sim::lockstep_player;
use policy::PolicyLayout;
use robots::Robot;
use sim2real::config::MirrorConfig;
use test_support::fixtures::{twist2_dir, workspace_root};

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let Some(dir) = twist2_dir() else { return };
    let root = workspace_root();
    let robot = Robot::load(&root.join("robots/g1-twist2/robot.toml")).unwrap();
    let layout = PolicyLayout::load(&root.join("robots/g1-twist2/policies/twist2.toml"), &robot).unwrap();
    let clip = Clip::load(&dir.join("example_motions/0807_yanjie_walk_001.pkl")).unwrap();
    let reference = Reference::for_policy(&clip, &robot, &layout).unwrap();
    let obs = layout.obs_len;
    let options = PlayOptions {
        max_ticks: (!full).then_some(100),
        ..PlayOptions::default()
    };
    let (mut player, mut clock, _world) = lockstep_player(
        robot,
        layout,
        reference,
        options,
        MirrorConfig::default(),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let wall = Instant::now();
    let s = player.run(&mut clock).unwrap();
    let took = wall.elapsed().as_secs_f64();
    assert!(!s.fell, "TWIST2 fell in the bench run");
    let simulated = s.ticks as f64 * 0.02;
    let us = |p: f64| s.compute.quantile(p).as_secs_f64() * 1e6;
    println!("TWIST2 on the G1, walk_001, {obs}-value observation, lockstep, one core");
    println!(
        "  tick compute: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} ticks",
        us(0.5),
        us(0.99),
        s.compute.max().as_secs_f64() * 1e6,
        s.compute.count()
    );
    println!(
        "  whole path: {simulated:.1} s simulated in {took:.2} s wall ({:.3} s per simulated s)",
        took / simulated
    );
}
