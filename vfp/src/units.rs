//! The units reports and figures show numbers in: `--units VOLUME,PRESSURE` (e.g. `mL,cmH2O`),
//! by default the units the file was read in with `--columns`, else the format's own (mm³, kPa).
//!
//! Every computation runs in the format's units (mm³, mm³/s, kPa); a [`DisplayUnits`] converts a
//! number only where it is printed or drawn. The unit names and their factors are those of
//! `--columns` ([`sysid::columns::Quantity::units`]): one table for reading and showing. Derived
//! units follow: flow is volume per second, stiffness pressure per volume, damping pressure·s per
//! volume, a polynomial coefficient αᵢⱼ of vⁱ v̇ʲ pressure per volumeⁱ⁺ʲ (times sʲ). Time (s),
//! frequency (Hz) and force (N, mN) are never converted. JSON documents stay in the format's units
//! (their `units` field says so): `--units` changes text and figures only.

use std::fmt;
use std::str::FromStr;

use sysid::columns::{ColumnMap, Quantity};

/// The volume and pressure units of a report or figure, with their factors to the format's units
/// (mm³, kPa): a number in the format's unit divided by the factor is the number in this unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisplayUnits {
    volume: (&'static str, f64),
    pressure: (&'static str, f64),
}

impl Default for DisplayUnits {
    /// The format's own units, mm³ and kPa.
    fn default() -> Self {
        Self {
            volume: Quantity::Volume.units()[0],
            pressure: Quantity::Pressure.units()[0],
        }
    }
}

/// The accepted names of `q`, comma-separated.
fn names(q: Quantity) -> String {
    q.units()
        .iter()
        .map(|(u, _)| *u)
        .collect::<Vec<_>>()
        .join(", ")
}

impl FromStr for DisplayUnits {
    type Err = String;

    /// `VOLUME,PRESSURE` in either order, or one of them (the other stays the format's), names
    /// matched ignoring case as `--columns` matches them.
    fn from_str(s: &str) -> Result<Self, String> {
        let mut u = DisplayUnits::default();
        let (mut vol, mut pres) = (false, false);
        for item in s.split(',').map(str::trim) {
            if let Some(v) = Quantity::Volume.factor(item) {
                if std::mem::replace(&mut vol, true) {
                    return Err(format!("`{s}` names two volume units"));
                }
                u.volume = v;
            } else if let Some(p) = Quantity::Pressure.factor(item) {
                if std::mem::replace(&mut pres, true) {
                    return Err(format!("`{s}` names two pressure units"));
                }
                u.pressure = p;
            } else {
                return Err(format!(
                    "unknown unit `{item}`: expected VOLUME,PRESSURE, e.g. mL,cmH2O (volume: {}; \
                     pressure: {})",
                    names(Quantity::Volume),
                    names(Quantity::Pressure)
                ));
            }
        }
        Ok(u)
    }
}

impl fmt::Display for DisplayUnits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{}", self.volume.0, self.pressure.0)
    }
}

impl DisplayUnits {
    /// The units a file was read in with `--columns`: its volume unit (else its flow unit's
    /// volume, `mL/min` giving mL) and its pressure unit; the format's for what it does not give.
    pub fn of_columns(columns: &ColumnMap) -> Self {
        let mut u = DisplayUnits::default();
        let vol = columns.get(Quantity::Volume);
        let flow = columns.get(Quantity::Flow);
        if vol.given {
            u.volume = (vol.unit, vol.factor);
        } else if flow.given {
            let name = flow.unit.split('/').next().unwrap_or(flow.unit);
            if let Some(v) = Quantity::Volume.factor(name) {
                u.volume = v;
            }
        }
        let p = columns.get(Quantity::Pressure);
        if p.given {
            u.pressure = (p.unit, p.factor);
        }
        u
    }

    /// Whether these are the format's own units (nothing is converted).
    pub fn is_canonical(&self) -> bool {
        *self == DisplayUnits::default()
    }

    /// The volume unit's name, e.g. `mm3`, `mL`.
    pub fn volume(&self) -> &'static str {
        self.volume.0
    }

    /// The flow unit's name: the volume unit per second.
    pub fn flow(&self) -> String {
        format!("{}/s", self.volume.0)
    }

    /// The pressure unit's name, e.g. `kPa`, `cmH2O`.
    pub fn pressure(&self) -> &'static str {
        self.pressure.0
    }

    /// Stiffness dP/dv: `kPa/mm3`.
    pub fn stiffness(&self) -> String {
        format!("{}/{}", self.pressure.0, self.volume.0)
    }

    /// Damping dP/dv̇: `kPa s/mm3`.
    pub fn damping(&self) -> String {
        format!("{} s/{}", self.pressure.0, self.volume.0)
    }

    /// A unit name for a figure: `mm3` as `mm³`, `cm3` as `cm³`.
    pub fn pretty(name: &str) -> String {
        name.replace("mm3", "mm³").replace("cm3", "cm³")
    }

    /// A volume (mm³) in this unit.
    pub fn v(&self, mm3: f64) -> f64 {
        mm3 / self.volume.1
    }

    /// A flow (mm³/s) in this unit.
    pub fn q(&self, mm3_s: f64) -> f64 {
        mm3_s / self.volume.1
    }

    /// A pressure (kPa) in this unit.
    pub fn p(&self, kpa: f64) -> f64 {
        kpa / self.pressure.1
    }

    /// A stiffness (kPa/mm³) or damping (kPa·s/mm³) in this unit.
    pub fn k(&self, kpa_mm3: f64) -> f64 {
        kpa_mm3 * self.volume.1 / self.pressure.1
    }

    /// The polynomial's coefficient αᵢⱼ of vⁱ v̇ʲ (kPa/(mm³)ⁱ/(mm³/s)ʲ) in this unit: P = Σ αᵢⱼ vⁱ
    /// v̇ʲ holds with P, v and v̇ all in these units.
    pub fn coefficient(&self, alpha: f64, i: usize, j: usize) -> f64 {
        alpha * self.volume.1.powi((i + j) as i32) / self.pressure.1
    }

    /// A number with one of the units the library writes (`mm3`, `mm3/s`, `kPa`, `kPa2`,
    /// `mm3/(kPa*s)`, `kPa*s^2/mm3`, `kPa*s^2/mm6`, and in its sentences `mm³`, `mm³/s`,
    /// `kPa·s²/mm³`; anything else — s, Hz, 1 — as it is) in these units, with its unit's name.
    pub fn convert(&self, value: f64, unit: &str) -> (f64, String) {
        let (v, p) = (self.volume.0, self.pressure.0);
        // (the value's powers of the volume and the pressure unit, the unit's name)
        let (ev, ep, name) = match unit {
            "mm3" => (1, 0, v.to_string()),
            "mm3/s" => (1, 0, format!("{v}/s")),
            "kPa" => (0, 1, p.to_string()),
            "kPa2" => (0, 2, format!("{p}2")),
            "mm3/(kPa*s)" => (1, -1, format!("{v}/({p}*s)")),
            "kPa*s^2/mm3" => (-1, 1, format!("{p}*s^2/{v}")),
            "kPa*s^2/mm6" => (-2, 1, format!("{p}*s^2/{v}^2")),
            // As the library's sentences spell them.
            "mm³" => (1, 0, Self::pretty(v)),
            "mm³/s" => (1, 0, format!("{}/s", Self::pretty(v))),
            "kPa·s²/mm³" => (-1, 1, format!("{p}·s²/{}", Self::pretty(v))),
            _ => return (value, unit.to_string()),
        };
        if self.is_canonical() {
            return (value, unit.to_string());
        }
        (
            value / self.volume.1.powi(ev) / self.pressure.1.powi(ep),
            name,
        )
    }

    /// An effect parameter's name in these units: names that carry a flow
    /// (`count_lag_at_0.500_mm3_s`) get the flow converted.
    pub fn param_name(&self, name: &str) -> String {
        if self.is_canonical() {
            return name.to_string();
        }
        let Some(q) = name
            .strip_prefix("count_lag_at_")
            .and_then(|r| r.strip_suffix("_mm3_s"))
            .and_then(|q| q.parse::<f64>().ok())
        else {
            return name.to_string();
        };
        format!(
            "count_lag_at_{}_{}_s",
            crate::figure::tick(self.q(q)),
            self.volume.0
        )
    }

    /// A sentence the library wrote in the format's units with every "NUMBER UNIT" (and "NUMBER
    /// to NUMBER UNIT", also with → or against) of a volume, flow or pressure unit rewritten in
    /// these units, each number with the precision it had.
    pub fn sentence(&self, s: &str) -> String {
        if self.is_canonical() {
            return s.to_string();
        }
        let mut words: Vec<String> = s.split(' ').map(str::to_string).collect();
        for i in 1..words.len() {
            let unit: String = words[i]
                .trim_end_matches([',', ';', ')', '.', ':'])
                .to_string();
            let rest = words[i][unit.len()..].to_string();
            let probe = self.convert(1.0, &unit);
            if probe.1 == unit {
                continue;
            }
            let Some(x) = number(&words[i - 1]) else {
                continue;
            };
            words[i - 1] = x.redo(self.convert(x.value, &unit).0);
            // "X to Y kPa", "X → Y kPa", "X against Y kPa": X is in the same unit.
            if i >= 3 && ["to", "→", "->", "against"].contains(&words[i - 2].as_str()) {
                if let Some(lo) = number(&words[i - 3]) {
                    words[i - 3] = lo.redo(self.convert(lo.value, &unit).0);
                }
            }
            words[i] = probe.1 + &rest;
        }
        words.join(" ")
    }
}

/// A number as a sentence printed it: what came before it (`(`), its sign, precision and form.
struct Printed {
    lead: String,
    value: f64,
    plus: bool,
    decimals: usize,
    sci: bool,
}

impl Printed {
    /// `x` printed as this number was.
    fn redo(&self, x: f64) -> String {
        let d = self.decimals;
        let body = match (self.sci, self.plus) {
            (true, true) => format!("{x:+.d$e}"),
            (true, false) => format!("{x:.d$e}"),
            (false, true) => format!("{x:+.d$}"),
            (false, false) => format!("{x:.d$}"),
        };
        format!("{}{body}", self.lead)
    }
}

fn number(word: &str) -> Option<Printed> {
    let lead_len = word.len() - word.trim_start_matches(['(', '[']).len();
    let (lead, body) = word.split_at(lead_len);
    let value: f64 = body.parse().ok()?;
    let mantissa = body.split(['e', 'E']).next().unwrap_or(body);
    let decimals = mantissa.split_once('.').map_or(0, |(_, f)| f.len());
    Some(Printed {
        lead: lead.to_string(),
        value,
        plus: body.starts_with('+'),
        decimals,
        sci: body.contains(['e', 'E']),
    })
}

#[cfg(test)]
mod tests {
    use super::DisplayUnits;

    #[test]
    fn names_factors_and_errors() {
        let u: DisplayUnits = "ml,CMH2O".parse().unwrap();
        assert_eq!((u.volume(), u.pressure()), ("mL", "cmH2O"));
        assert_eq!(u.v(1000.0), 1.0);
        assert!((u.p(0.0980665) - 1.0).abs() < 1e-15);
        assert_eq!("cmH2O,mL".parse::<DisplayUnits>().unwrap(), u);
        let only: DisplayUnits = "psi".parse().unwrap();
        assert_eq!((only.volume(), only.pressure()), ("mm3", "psi"));
        let e = "mL,furlong".parse::<DisplayUnits>().unwrap_err();
        assert!(e.contains("unknown unit `furlong`") && e.contains("cmH2O") && !e.contains('\n'));
        assert!("mL,L".parse::<DisplayUnits>().is_err());
        assert!(DisplayUnits::default().is_canonical());
        // αᵢⱼ of v² v̇: kPa/(mm³)²/(mm³/s) → cmH2O/mL²/(mL/s): × 1000³ / 0.0980665.
        let a = u.coefficient(1.0, 2, 1);
        assert!((a - 1e9 / 0.0980665).abs() < 1e-3 * a);
    }

    #[test]
    fn sentences_convert_number_unit_pairs_only() {
        let u: DisplayUnits = "mL,cmH2O".parse().unwrap();
        let s = u.sentence(
            "residual differs by direction: +0.0981 kPa inflating vs -0.196 kPa deflating (t = 4.0); \
             interval (1.000e3 to 2.000e3 mm3) at 0.500 s; 0.0981 → 0.1961 kPa; a play of \
             2.0000e3 mm³ is 4 % of the stroke (5.0000e4 mm³), L = -1.000e-7 kPa·s²/mm³",
        );
        assert_eq!(
            s,
            "residual differs by direction: +1.0003 cmH2O inflating vs -1.999 cmH2O deflating (t = 4.0); \
             interval (1.000e0 to 2.000e0 mL) at 0.500 s; 1.0003 → 1.9997 cmH2O; a play of \
             2.0000e0 mL is 4 % of the stroke (5.0000e1 mL), L = -1.020e-3 cmH2O·s²/mL"
        );
        let same = "held-out 0.1234 kPa";
        assert_eq!(DisplayUnits::default().sentence(same), same);
    }
}
