//! A polynomial identified and exported by sysid, loaded into the simulated firmware through its
//! serial port, predicts on the board the pressure sysid predicts, to float precision; and
//! `vfp deploy`'s upload reads back bit for bit from the firmware's installed model.

use e2e_tests::short_protocol;
use host_sim::{simulate, PlantConfig, Scenario, TimedCommand};
use sysid::board::deploy::{deploy, parse_lines, FirmwarePort, Readback};
use sysid::board::export::command_lines;
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::poly::{fit, Scaling, Xy};

#[test]
fn exported_model_predicts_on_the_board_as_in_sysid() {
    // Identify on a short characterisation run of the simulated rig.
    let ident = simulate(&short_protocol(PlantConfig::default())).expect("valid scenario");
    let mut csv = Vec::new();
    ident.write_log(&mut csv).expect("in memory");
    let log = sysid::log::parse_log(&csv[..], "ident.csv").expect("valid log");
    let mut fits = Vec::new();
    let mut lines = Vec::new();
    for c in 0..3u8 {
        let ds = Dataset::from_log(&log, c, &DatasetConfig::default()).expect("dataset");
        let all = ds.all();
        let sc = Scaling::from_data(&all.v, &all.vdot).expect("scaling");
        let f = fit(Xy::from(&ds.train()), 3, 2, Some(sc)).expect("fit");
        lines.extend(command_lines(c, &f.to_model_core().expect("device model")));
        fits.push(f);
    }

    // A fresh board: the lines through its serial port, then moves at several flows.
    let mut cmds: Vec<TimedCommand> = vfp::cmd::demo::upload_commands(&lines);
    for (at_s, line) in [
        (1.5, "move all 400 80"),
        (8.0, "move all 150 35"),
        (17.0, "move all 300 60"),
    ] {
        cmds.push(TimedCommand::new(at_s, line));
    }
    let sc = Scenario {
        name: "e2e-deploy".into(),
        duration_s: 22.0,
        commands: cmds,
        ..Scenario::default()
    };
    let run = simulate(&sc).expect("valid scenario");
    let replies: Vec<&str> = run.replies.iter().map(|r| r.1.as_str()).collect();
    assert_eq!(
        &replies[..lines.len()],
        vec!["ok"; lines.len()].as_slice(),
        "every model line acknowledged"
    );
    let loaded = run
        .events
        .iter()
        .filter(|e| matches!(e.kind, firmware::telemetry::EventKind::ModelLoaded { .. }))
        .count();
    assert_eq!(loaded, 3);

    // Float precision: the board evaluates in f32 on coefficients rounded to f32. With scaled
    // inputs |x|, |y| ≲ 1 and unit roundoff u = 2⁻²⁴, Horner's error is below (n + m + 2)·u·Σ|b|;
    // rounding the coefficients and the scaled inputs adds a few u·Σ|b| more. 32·u·Σ|b| bounds it.
    let u = f64::from(f32::EPSILON) / 2.0;
    let mut compared = 0;
    for (c, f) in fits.iter().enumerate() {
        let model = f.to_model_core().unwrap();
        let sum_b: f64 = model.scaled().iter().map(|b| f64::from(b.abs())).sum();
        let tol = 32.0 * u * sum_b;
        let mut worst = 0.0f64;
        for fr in run.frames.iter().filter(|fr| fr.t_us > 1_200_000) {
            let ch = &fr.chambers[c];
            let sysid = f.predict(f64::from(ch.v), f64::from(ch.vdot));
            let d = (f64::from(ch.p_hat) - sysid).abs();
            assert!(
                d <= tol,
                "chamber {c} seq {}: board {} vs sysid {sysid} (tol {tol:.2e})",
                fr.seq,
                ch.p_hat
            );
            worst = worst.max(d);
            compared += 1;
        }
        // The bound is not vacuous: far below the sensor's 0.05 kPa noise.
        assert!(tol < 1e-3, "tol {tol}");
        eprintln!("chamber {c}: max |board − sysid| = {worst:.2e} kPa (bound {tol:.2e})");
    }
    assert!(compared > 1000, "{compared}");

    // `vfp deploy` over the firmware's own command handler: acknowledged, and read back exactly
    // with the firmware's `model <ch> read` (no stand-in).
    let uploads = parse_lines(&lines.join("\n"), "export").expect("export lines parse");
    let mut port = FirmwarePort::new();
    let results = deploy(&mut port, &uploads).expect("deploys");
    for (r, f) in results.iter().zip(&fits) {
        assert_eq!(r.readback, Readback::Verified { values: 7 + 12 });
        let installed = port.shared.lock(|s| *s.model(r.ch as usize));
        assert_eq!(installed, f.to_model_core().unwrap());
    }
}
