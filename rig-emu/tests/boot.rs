//! The ELF boots on the virtual board and answers on its command port.

use std::time::Duration;

use rig_emu::{default_elf, Rig, RigConfig};

fn rig() -> Rig {
    Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts")
}

#[test]
fn boots_and_answers_status() {
    let mut rig = rig();
    rig.run_for(Duration::from_millis(200)).unwrap();
    let reply = rig.command("status").unwrap();
    eprintln!("lines: {:?}", rig.lines().unwrap());
    let reply = reply.expect("a reply to status within a virtual second");
    assert!(reply.starts_with("ok"), "{reply}");
    let out = rig.finish().unwrap();
    eprintln!("unimplemented: {:?}", out.unimplemented);
    eprintln!("unmapped: {:?}", out.unmapped);
    eprintln!("resets: {:?}", out.resets);
}
