//! Inertance: the water column's mass, one added column `L·v̈` (v̈ the volumetric acceleration),
//! no searched parameter; admissible only with `L ≥ 0`.

use super::{param, Column, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared};

/// Fluid inertance of the line (v̈ term).
pub struct Inertance;

impl EffectModel for Inertance {
    fn name(&self) -> &'static str {
        "inertance"
    }

    fn story(&self) -> &'static str {
        "The water column in the tube has mass, so accelerating the flow takes a pressure proportional to the volumetric acceleration."
    }

    fn columns(&self, _e: &Effect, prep: &Prepared) -> Vec<Column> {
        vec![Column::new(prep.series.vddot.clone(), "inertance vddot")]
    }

    fn unphysical(&self, _e: &Effect, coefs: &[f64]) -> Option<String> {
        let &l = coefs.first()?;
        (l < 0.0).then(|| {
            format!("inertance L = {l:.3e} kPa·s²/mm³ is negative, which no mass of water gives")
        })
    }

    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![param("inertance", f.coef(0), f.coef_se(0), "kPa*s^2/mm3")]
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device("L·v̈ with v̈ taken as the backward difference (v̇(t) − v̇(t−1))/Δt is the AR(1) flow term β·v̇(t−1) plus a change of the v̇ coefficient, which PolyModel evaluates")
    }
}
