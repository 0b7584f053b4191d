//! The start-up pressure zero on the binary: taken where the sensors read a plausible offset,
//! refused where a channel is pressurised at boot, so its over-pressure limit does not move.

use std::time::Duration;

use host_sim::PlantConfig;
use rig_emu::rig::status_flags;
use rig_emu::{default_elf, Rig, RigConfig};

#[test]
fn a_channel_pressurised_at_boot_is_not_zeroed_and_reads_its_pressure() {
    let mut plant = PlantConfig::default();
    // Chamber 1's sensor reads 30 kPa at rest (as if its syringe were pressurised at reset).
    plant.sensor.offset_kpa = [0.42, 30.0, 0.18];
    let mut rig = Rig::start(&RigConfig {
        elf: default_elf(),
        plant,
        seed: 3,
    })
    .expect("the virtual rig starts");
    rig.run_for(Duration::from_millis(2_500)).unwrap();
    let status = rig.command("status").unwrap().expect("a reply");
    let flags = status_flags(&status).expect("a flags field");
    assert!(
        flags & firmware::telemetry::Flags::NOT_ZEROED != 0,
        "the refused zero is reported: {status}"
    );
    assert_eq!(rig.command("telemetry on").unwrap().as_deref(), Some("ok"));
    rig.run_for(Duration::from_millis(200)).unwrap();
    let frame = *rig
        .with(|_, b| b.stream.frames())
        .unwrap()
        .last()
        .expect("frames");
    let p = frame.chambers.map(|c| c.p);
    // Channels 0 and 2 zeroed (about 0 kPa), channel 1 on the nominal transfer function.
    assert!(p[0].abs() < 0.1 && p[2].abs() < 0.1, "{p:?}");
    assert!((p[1] - 30.0).abs() < 0.2, "{p:?}");
}
