//! Moves on the real firmware: the steps the plant takes are the planner's, at the planner's
//! instants, and the plant's pressure comes back through the ADC into the frames.

use std::time::Duration;

use firmware::motion::Trapezoid;
use rig_emu::{default_elf, Rig, RigConfig, StepEvent};

#[test]
fn a_three_axis_move_takes_the_planners_steps_at_the_planners_instants() {
    let mut rig = Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts");
    let status = rig.ready().unwrap();
    assert!(status.starts_with("ok flags 0 "), "{status}");
    assert_eq!(rig.command("telemetry on").unwrap().as_deref(), Some("ok"));
    // 20 mm³ at 50 mm³/s with 500 mm³/s²: 500 steps of 0.04 mm³ per axis, on all three at once.
    let reply = rig.command("move 012 20 50 500").unwrap().expect("a reply");
    assert_eq!(reply, "ok");
    rig.run_for(Duration::from_millis(800)).unwrap();
    let (steps, net, disabled) = rig
        .with(|_, b| (b.steps.clone(), b.net_steps(), b.steps_while_disabled))
        .unwrap();
    assert_eq!(net, [500, 500, 500], "net steps by axis");
    assert_eq!(disabled, 0, "no STEP edge while the drivers were disabled");
    let plan = Trapezoid::new(500, 0.04, 50.0, 500.0);
    let mut worst = 0i64;
    for axis in 0..3 {
        let mine: Vec<&StepEvent> = steps.iter().filter(|s| s.axis == axis).collect();
        assert_eq!(mine.len(), 500);
        assert!(
            mine.iter().all(|s| s.inflate),
            "axis {axis}: DIR high (inflate) on every step"
        );
        let t1 = mine[0].at_ns as i64;
        for (k, s) in mine.iter().enumerate() {
            let k = k as u32 + 1;
            let planned_us = plan.step_offset_us(k) as i64 - plan.step_offset_us(1) as i64;
            let seen_us = (s.at_ns as i64 - t1) / 1000;
            worst = worst.max((seen_us - planned_us).abs());
        }
    }
    // A step is late by the time driver's alarm plus the executor's poll: a few µs.
    assert!(worst <= 20, "a step {worst} µs off its planned instant");
    // The move ran its planned duration (first to last step).
    let last = steps.iter().map(|s| s.at_ns).max().unwrap() as i64;
    let first = steps.iter().map(|s| s.at_ns).min().unwrap() as i64;
    let planned = (plan.step_offset_us(500) - plan.step_offset_us(1)) as i64;
    assert!(((last - first) / 1000 - planned).abs() <= 20);
    let status = rig.command("status").unwrap().unwrap();
    assert!(status.contains(" v 20 20 20 "), "{status}");
    // The plant's chambers took the 20 mm³, and the pressure the board reports (sensor, ADC pin,
    // conversion, the firmware's transfer function and zero) is the plant's: within the sensor
    // noise averaged over a frame (0.05 kPa, 15 conversions) and a count (0.032 kPa).
    rig.run_for(Duration::from_millis(200)).unwrap();
    let (truth, frame) = rig
        .with(|_, b| {
            let truth: [(f64, f64); 3] = core::array::from_fn(|i| {
                let t = b.plant.truth(i);
                (t.chamber_mm3, t.sensed_kpa)
            });
            (truth, *b.stream.frames().last().expect("frames"))
        })
        .unwrap();
    for (i, (v, p)) in truth.iter().enumerate() {
        assert!((v - 20.0).abs() < 0.05, "chamber {i} holds {v} mm³");
        let seen = f64::from(frame.chambers[i].p);
        assert!(*p > 0.1, "chamber {i} at {p} kPa");
        assert!(
            (seen - p).abs() < 0.06,
            "chamber {i}: board {seen} kPa, plant {p} kPa"
        );
        assert_eq!(frame.chambers[i].v, 20.0);
    }
}
