//! A lab's own column names and units, mapped onto the log format's: the `--columns` option.
//!
//! A spec is a comma-separated list of `QUANTITY=HEADER[:UNIT]` items, e.g.
//! `time=t,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O`. Quantities are `time`,
//! `chamber`, `volume`, `flow`, `pressure` and `force`; a quantity left out keeps the format's
//! own column name (`time_s`, …) and unit. The unit is split off at the last `:`; without one,
//! the format's unit is meant. Units are matched ignoring case. Each is converted to the format's
//! unit by one factor from its definition:
//!
//! | quantity | format's unit | accepted units (factor to the format's unit) |
//! | --- | --- | --- |
//! | time | s | s (1), ms (10⁻³), us (10⁻⁶), min (60) |
//! | volume | mm³ | mm3 (1), uL (1), mL (10³), cm3 (10³), L (10⁶) |
//! | flow | mm³/s | mm3/s (1), uL/s (1), mL/s (10³), mL/min (10³/60), L/s (10⁶), L/min (10⁶/60) |
//! | pressure | kPa | kPa (1), Pa (10⁻³), hPa (0.1), mbar (0.1), bar (100), cmH2O (0.0980665), mmHg (0.133322387415), psi (6.894757293168361) |
//! | force | N | N (1), mN (10⁻³) |
//!
//! cmH2O is the conventional centimetre of water, 1 cm × 1000 kg/m³ × g₀ (9.80665 m/s²)
//! = 98.0665 Pa; mmHg the conventional millimetre of mercury, 1 mm × 13 595.1 kg/m³ × g₀
//! = 133.322387415 Pa; psi one pound-force (0.45359237 kg × g₀) per square inch (0.0254² m²)
//! = 6894.757293168361 Pa.

use std::fmt;
use std::str::FromStr;

/// A quantity the log format knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// `time_s`.
    Time,
    /// `chamber`.
    Chamber,
    /// `volume_mm3`.
    Volume,
    /// `flow_mm3_s`.
    Flow,
    /// `pressure_kpa`.
    Pressure,
    /// `force_n`.
    Force,
}

impl Quantity {
    /// Every quantity, in the format's column order.
    pub const ALL: [Quantity; 6] = [
        Quantity::Time,
        Quantity::Chamber,
        Quantity::Volume,
        Quantity::Flow,
        Quantity::Pressure,
        Quantity::Force,
    ];

    /// The key in a `--columns` spec.
    pub fn key(self) -> &'static str {
        match self {
            Quantity::Time => "time",
            Quantity::Chamber => "chamber",
            Quantity::Volume => "volume",
            Quantity::Flow => "flow",
            Quantity::Pressure => "pressure",
            Quantity::Force => "force",
        }
    }

    /// The format's column name.
    pub fn column(self) -> &'static str {
        match self {
            Quantity::Time => "time_s",
            Quantity::Chamber => "chamber",
            Quantity::Volume => "volume_mm3",
            Quantity::Flow => "flow_mm3_s",
            Quantity::Pressure => "pressure_kpa",
            Quantity::Force => "force_n",
        }
    }

    /// Accepted units with their factor to the format's unit; the first is the format's own.
    pub fn units(self) -> &'static [(&'static str, f64)] {
        match self {
            Quantity::Time => &[("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("min", 60.0)],
            Quantity::Chamber => &[("index", 1.0)],
            Quantity::Volume => &[
                ("mm3", 1.0),
                ("uL", 1.0),
                ("mL", 1e3),
                ("cm3", 1e3),
                ("L", 1e6),
            ],
            Quantity::Flow => &[
                ("mm3/s", 1.0),
                ("uL/s", 1.0),
                ("mL/s", 1e3),
                ("mL/min", 1e3 / 60.0),
                ("L/s", 1e6),
                ("L/min", 1e6 / 60.0),
            ],
            Quantity::Pressure => &[
                ("kPa", 1.0),
                ("Pa", 1e-3),
                ("hPa", 0.1),
                ("mbar", 0.1),
                ("bar", 100.0),
                ("cmH2O", 0.0980665),
                ("mmHg", 0.133322387415),
                ("psi", 6.894757293168361),
            ],
            Quantity::Force => &[("N", 1.0), ("mN", 1e-3)],
        }
    }

    /// The factor of `unit` (ignoring case) to the format's unit.
    pub fn factor(self, unit: &str) -> Option<(&'static str, f64)> {
        self.units()
            .iter()
            .find(|(u, _)| u.eq_ignore_ascii_case(unit))
            .copied()
    }
}

/// Where one quantity is in a file, and in which unit.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// The file's header name.
    pub header: String,
    /// The unit as the table spells it.
    pub unit: &'static str,
    /// Multiply a cell by this to get the format's unit.
    pub factor: f64,
    /// Whether `--columns` named it (else it is the format's own name and unit).
    pub given: bool,
}

/// The columns of a file: per quantity, its header and unit. The default is the format's own.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ColumnMap {
    given: Vec<(Quantity, Mapping)>,
}

impl ColumnMap {
    /// Where `q` is: as given, else the format's column in the format's unit.
    pub fn get(&self, q: Quantity) -> Mapping {
        self.given
            .iter()
            .find(|(k, _)| *k == q)
            .map(|(_, m)| m.clone())
            .unwrap_or_else(|| Mapping {
                header: q.column().to_string(),
                unit: q.units()[0].0,
                factor: 1.0,
                given: false,
            })
    }

    /// Whether no quantity was mapped.
    pub fn is_empty(&self) -> bool {
        self.given.is_empty()
    }
}

/// Why a `--columns` spec was not understood: which item, where in the spec, and what.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("--columns: item {item} `{text}` (at character {at}): {problem}")]
pub struct ColumnSpecError {
    /// 1-based item number.
    pub item: usize,
    /// The item as written.
    pub text: String,
    /// 1-based character position of the item in the spec.
    pub at: usize,
    /// What is wrong, with what is accepted.
    pub problem: String,
}

impl FromStr for ColumnMap {
    type Err = ColumnSpecError;

    fn from_str(spec: &str) -> Result<Self, Self::Err> {
        let mut map = ColumnMap::default();
        let mut at = 1;
        for (i, raw) in spec.split(',').enumerate() {
            let fail = |problem: String| ColumnSpecError {
                item: i + 1,
                text: raw.to_string(),
                at,
                problem,
            };
            let (q, m) = parse_item(raw.trim()).map_err(fail)?;
            if map.given.iter().any(|(k, _)| *k == q) {
                return Err(fail(format!("`{}` is mapped twice", q.key())));
            }
            if let Some((k, _)) = map.given.iter().find(|(_, g)| g.header == m.header) {
                return Err(fail(format!(
                    "header `{}` is already mapped to `{}`",
                    m.header,
                    k.key()
                )));
            }
            map.given.push((q, m));
            at += raw.chars().count() + 1;
        }
        Ok(map)
    }
}

/// One `QUANTITY=HEADER[:UNIT]` item.
fn parse_item(item: &str) -> Result<(Quantity, Mapping), String> {
    let keys = || {
        Quantity::ALL
            .iter()
            .map(|q| q.key())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let Some((key, rest)) = item.split_once('=') else {
        return Err(format!(
            "expected QUANTITY=HEADER[:UNIT], e.g. pressure=P_cmH2O:cmH2O (quantities: {})",
            keys()
        ));
    };
    let key = key.trim();
    let q = Quantity::ALL
        .into_iter()
        .find(|q| q.key() == key)
        .ok_or_else(|| format!("unknown quantity `{key}` (quantities: {})", keys()))?;
    let (header, unit) = match rest.rsplit_once(':') {
        Some((h, u)) => (h.trim(), Some(u.trim())),
        None => (rest.trim(), None),
    };
    if header.is_empty() {
        return Err(format!("no header name after `{key}=`"));
    }
    let (unit, factor) = match unit {
        None => q.units()[0],
        Some(_) if q == Quantity::Chamber => {
            return Err("`chamber` takes no unit (see --chamber-base for 1-based numbers)".into())
        }
        Some(u) => q.factor(u).ok_or_else(|| {
            let known: Vec<&str> = q.units().iter().map(|(u, _)| *u).collect();
            format!("unknown {key} unit `{u}` (known: {})", known.join(", "))
        })?,
    };
    let mapping = Mapping {
        header: header.to_string(),
        unit,
        factor,
        given: true,
    };
    Ok((q, mapping))
}

impl fmt::Display for ColumnMap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (q, m)) in self.given.iter().enumerate() {
            let sep = if i == 0 { "" } else { "," };
            write!(f, "{sep}{}={}:{}", q.key(), m.header, m.unit)?;
        }
        Ok(())
    }
}

/// The format's units, which every JSON document's numbers are in (its `units` field): a report's
/// text and figures may show others (`vfp --units`), the machine-readable output never does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct FormatUnits {
    /// Time: s.
    pub time: &'static str,
    /// Volume: mm3.
    pub volume: &'static str,
    /// Flow: mm3/s.
    pub flow: &'static str,
    /// Pressure: kPa.
    pub pressure: &'static str,
}

/// The format's units: s, mm3, mm3/s, kPa.
pub const FORMAT_UNITS: FormatUnits = FormatUnits {
    time: "s",
    volume: "mm3",
    flow: "mm3/s",
    pressure: "kPa",
};

/// How to read a log whose layout is not quite the format's.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReadOptions {
    /// The file's column names and units.
    pub columns: ColumnMap,
    /// The number the file gives the first chamber: 0 (the format's) or 1.
    pub chamber_base: u8,
}
