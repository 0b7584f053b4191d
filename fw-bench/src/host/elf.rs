//! The bench program's ELF: marker symbols and the code's instruction kinds.

use std::collections::HashMap;

use object::{Object, ObjectSection, ObjectSymbol, SectionKind};

use super::trace::{Layout, Role};

/// Markers every bench program must have.
const REQUIRED: [&str; 3] = ["fwb_end", "fwb_script_begin", "fwb_script_end"];

/// Read the layout the counter needs from the ELF bytes.
pub fn layout(data: &[u8]) -> Result<Layout, String> {
    let file = object::File::parse(data).map_err(|e| format!("not an ELF: {e}"))?;
    let mut l = Layout::default();
    let mut by_addr: HashMap<u32, String> = HashMap::new();
    let mut roles = Vec::new();
    for sym in file.symbols() {
        let Ok(name) = sym.name() else { continue };
        if !name.starts_with("fwb_") {
            continue;
        }
        // Thumb function symbols carry bit 0; the trace's PCs do not.
        let addr = u32::try_from(sym.address()).map_err(|_| format!("{name}: address"))? & !1;
        let role = if name == "fwb_end" {
            Role::End
        } else if name == "fwb_script_begin" {
            Role::ScriptBegin
        } else if name == "fwb_script_end" {
            Role::ScriptEnd
        } else if let Some(region) = name.strip_prefix("fwb_begin_") {
            Role::Begin(l.name_index(region))
        } else if let Some(region) = name.strip_prefix("fwb_retag_") {
            Role::Retag(l.name_index(region))
        } else {
            continue;
        };
        if let Some(other) = by_addr.insert(addr, name.to_owned()) {
            if other != name {
                return Err(format!(
                    "markers `{other}` and `{name}` share the address {addr:#010x} (merged?)"
                ));
            }
        }
        roles.push((addr, role, name.to_owned()));
    }
    for req in REQUIRED {
        if !by_addr.values().any(|n| n == req) {
            return Err(format!("marker `{req}` missing from the ELF"));
        }
    }
    for section in file.sections() {
        if section.kind() != SectionKind::Text {
            continue;
        }
        let bytes = section.data().map_err(|e| format!("section data: {e}"))?;
        let addr = u32::try_from(section.address()).map_err(|_| "section address")?;
        if !bytes.is_empty() {
            l.add_code(addr, bytes);
        }
    }
    if l.kinds.is_empty() {
        return Err("no code in the ELF".into());
    }
    for (addr, role, name) in roles {
        if !l.add_role(addr, role) {
            return Err(format!(
                "marker `{name}` ({addr:#010x}) is outside the code"
            ));
        }
    }
    Ok(l)
}
