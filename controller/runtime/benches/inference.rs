//! Bench: single-observation ONNX inference of the fixture policy MLP (96 → 512 → 256 → 128 → 20,
//! ELU) on one thread, as the control loop runs it once per tick. Prints p50/p99 in µs.
//!
//! Run: `cargo bench -p controller --bench inference` (after `scripts/setup`).

use std::time::Instant;

use policy::onnx::OnnxModel;
use test_support::stats::Summary;

const WARMUP: usize = 200;
const SAMPLES: usize = 5000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // `cargo test --benches` runs benches with `--bench` absent; keep that run short.
    let quick = !std::env::args().any(|a| a == "--bench");
    let path = test_support::fixtures::fixture("mlp_obs96_act20.onnx");
    let mut model = OnnxModel::load(&path)?;
    let (_, n_in) = model.input();
    let (_, n_out) = model.output();
    let mut obs = vec![0.0f32; n_in];
    let mut act = vec![0.0f32; n_out];
    let (warmup, samples) = if quick { (5, 50) } else { (WARMUP, SAMPLES) };
    let mut times = Vec::with_capacity(samples);
    for i in 0..warmup + samples {
        // A changing observation, like a running robot's.
        for (k, x) in obs.iter_mut().enumerate() {
            *x = ((i * 31 + k * 7) % 97) as f32 / 97.0 - 0.5;
        }
        let t0 = Instant::now();
        model.run(&obs, &mut act)?;
        let dt = t0.elapsed();
        if i >= warmup {
            times.push(dt);
        }
        std::hint::black_box(&act);
    }
    let summary = Summary::of(&mut times).ok_or("no samples taken")?;
    println!("inference  mlp 96-512-256-128-20 ELU, batch 1, 1 thread:  {summary}");
    Ok(())
}
