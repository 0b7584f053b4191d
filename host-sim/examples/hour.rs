//! Time one hour of rig time (the figure the benchmark measures, without criterion's repeats):
//! `cargo run --release -p host-sim --example hour [full]`.
use host_sim::{simulate, Scenario};

fn main() {
    let full = std::env::args().any(|a| a == "full");
    let sc = Scenario::rig_hour(full);
    let t = std::time::Instant::now();
    let run = simulate(&sc).expect("valid scenario");
    let dt = t.elapsed();
    let faults = run
        .events
        .iter()
        .filter(|e| matches!(e.kind, firmware::telemetry::EventKind::Fault { .. }))
        .count();
    println!(
        "{}: {:.0} s of rig time, {} frames, {} steps, {faults} faults, simulated in {:.2} s",
        if full { "full speed" } else { "paper rates" },
        run.stats.end_us as f64 * 1e-6,
        run.frames.len(),
        run.stats.steps,
        dt.as_secs_f64()
    );
}
