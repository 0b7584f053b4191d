//! The firmware's force estimate against the simulator's truth during 1 Hz pushes:
//! `cargo run -p host-sim --example force_error [-- <peak_n> <seconds>]`.
use host_sim::{simulate, Scenario};

fn main() {
    let args: Vec<f64> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let sc = Scenario::force_pushes(
        args.first().copied().unwrap_or(0.3),
        args.get(1).copied().unwrap_or(20.0),
    );
    let run = simulate(&sc).expect("valid scenario");
    let push = &sc.force[0];
    let errs: Vec<f64> = run
        .frames
        .iter()
        .zip(&run.truth)
        .filter(|(f, _)| {
            let t = f.t_us as f64 * 1e-6;
            t >= push.start_s && t < push.start_s + push.duration_s
        })
        .map(|(f, t)| f.force_n as f64 - t.force_n)
        .collect();
    let n = errs.len() as f64;
    let mean = errs.iter().sum::<f64>() / n;
    let sd = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    println!(
        "{} frames, peak {} N: error mean {:.2} mN, sd {:.2} mN (paper, real rig: 1.60 ± 7.50 mN)",
        errs.len(),
        push.peak_n,
        mean * 1e3,
        sd * 1e3
    );
}
