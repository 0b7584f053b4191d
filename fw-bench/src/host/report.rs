//! From region counts to the reported figures, the calibration check, budgets, table and JSON.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

use super::trace::{Counts, Layout};

/// The reported keys, in order.
pub const KEYS: [&str; 9] = [
    "step",
    "oversample",
    "frame",
    "frame_rls",
    "frame_rls_drift",
    "frame_chain",
    "telemetry_line",
    "command_max",
    "max_irq_off",
];

/// The regions whose maximum each key reports (`max_irq_off` comes from the windows).
fn sources(key: &str) -> &'static [&'static str] {
    match key {
        "step" => &["step_accel", "step_cruise"],
        "oversample" => &["oversample"],
        "frame" => &["frame"],
        "frame_rls" => &["frame_rls"],
        "frame_rls_drift" => &["frame_rls_drift"],
        "frame_chain" => &["frame_chain"],
        "telemetry_line" => &["telemetry_line"],
        _ => &[],
    }
}

/// Regions shown under the keys without a key of their own (no budget, not in the JSON).
const EXTRA_ROWS: [(&str, &str); 1] = [(
    "step_batch3",
    "a stepper wake-up issuing three same-instant steps",
)];

/// Calibration regions and their exact expected counts (region, interrupts-off window).
const CALIBRATION: [(&str, u64, u64); 5] = [
    ("calib_empty", 0, 0),
    ("calib_nop100", 100, 0),
    ("calib_loop50", 101, 0),
    ("calib_irq40", 42, 42),
    ("calib_cs40", 41, 40),
];

/// The JSON line: exactly the reported keys, numbers only.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct Figures {
    pub step: u64,
    pub oversample: u64,
    pub frame: u64,
    pub frame_rls: u64,
    pub frame_rls_drift: u64,
    /// A frame with a three-effect chain on every chamber.
    pub frame_chain: u64,
    pub telemetry_line: u64,
    pub command_max: u64,
    pub max_irq_off: u64,
}

impl Figures {
    /// The value of a key.
    pub fn get(&self, key: &str) -> Option<u64> {
        Some(match key {
            "step" => self.step,
            "oversample" => self.oversample,
            "frame" => self.frame,
            "frame_rls" => self.frame_rls,
            "frame_rls_drift" => self.frame_rls_drift,
            "frame_chain" => self.frame_chain,
            "telemetry_line" => self.telemetry_line,
            "command_max" => self.command_max,
            "max_irq_off" => self.max_irq_off,
            _ => return None,
        })
    }
}

/// Count statistics of one region.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stats {
    pub n: usize,
    pub min: u64,
    /// The middle value (the upper one of the two for an even count).
    pub median: u64,
    pub max: u64,
}

impl Stats {
    fn of(mut v: Vec<u64>) -> Option<Self> {
        v.sort_unstable();
        Some(Self {
            n: v.len(),
            min: *v.first()?,
            median: v[v.len() / 2],
            max: *v.last()?,
        })
    }
}

/// Everything reported.
#[derive(Debug)]
pub struct Report {
    pub figures: Figures,
    /// Per region name (calibration excluded).
    pub regions: BTreeMap<String, Stats>,
    /// The slowest command kind.
    pub command_max_kind: String,
    /// Where the longest interrupts-off window was: region name (or between regions) and PC.
    pub irq_off_at: String,
    pub script_insns: u64,
    pub script_windows: u64,
    pub total_insns: u64,
}

/// Check the calibration regions: each present once with exactly its expected count.
pub fn check_calibration(layout: &Layout, counts: &Counts) -> Result<String, String> {
    let mut errors = Vec::new();
    let mut seen = Vec::new();
    for (name, want, want_irq) in CALIBRATION {
        let got: Vec<_> = counts
            .regions
            .iter()
            .filter(|r| layout.names[r.name] == name)
            .collect();
        match got.as_slice() {
            [r] if r.insns == want && r.max_irq_off == want_irq => {
                seen.push(format!("{name} = {want}"));
            }
            [r] => errors.push(format!(
                "{name}: counted {} instructions (window {}), expected {want} (window {want_irq})",
                r.insns, r.max_irq_off
            )),
            _ => errors.push(format!("{name}: {} occurrences, expected 1", got.len())),
        }
    }
    if errors.is_empty() {
        Ok(seen.join(", "))
    } else {
        Err(format!("the counter is off: {}", errors.join("; ")))
    }
}

/// Aggregate the counts into the report.
pub fn report(layout: &Layout, counts: &Counts) -> Result<Report, String> {
    let mut by_name: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for r in &counts.regions {
        let name = &layout.names[r.name];
        if !name.starts_with("calib_") {
            by_name.entry(name.clone()).or_default().push(r.insns);
        }
    }
    let regions: BTreeMap<String, Stats> = by_name
        .into_iter()
        .filter_map(|(k, v)| Some((k, Stats::of(v)?)))
        .collect();
    let max_of = |names: &[&str]| -> Result<u64, String> {
        names
            .iter()
            .filter_map(|n| regions.get(*n).map(|s| s.max))
            .max()
            .ok_or_else(|| format!("no measurement of {}", names.join(" or ")))
    };
    let (command_max_kind, command_max) = regions
        .iter()
        .filter(|(k, _)| k.starts_with("cmd_"))
        .map(|(k, s)| (k.clone(), s.max))
        .max_by_key(|&(_, m)| m)
        .ok_or("no command measured")?;
    let w = counts
        .script_max_irq_off
        .ok_or("no interrupts-off window in the scripted run (the locks must show some)")?;
    let irq_off_at = format!(
        "{} (cpsid at {:#010x})",
        w.region
            .and_then(|i| counts.regions.get(i))
            .map_or("between regions", |r| layout.names[r.name].as_str()),
        w.start_pc
    );
    let figures = Figures {
        step: max_of(sources("step"))?,
        oversample: max_of(sources("oversample"))?,
        frame: max_of(sources("frame"))?,
        frame_rls: max_of(sources("frame_rls"))?,
        frame_rls_drift: max_of(sources("frame_rls_drift"))?,
        frame_chain: max_of(sources("frame_chain"))?,
        telemetry_line: max_of(sources("telemetry_line"))?,
        command_max,
        max_irq_off: w.len,
    };
    Ok(Report {
        figures,
        regions,
        command_max_kind: command_max_kind
            .trim_start_matches("cmd_")
            .replace('_', " "),
        irq_off_at,
        script_insns: counts.script_insns,
        script_windows: counts.script_windows,
        total_insns: counts.total,
    })
}

/// Budgets from the checked-in TOML: `key = instructions`, only the reported keys.
pub fn parse_budgets(text: &str) -> Result<BTreeMap<String, u64>, String> {
    let b: BTreeMap<String, u64> = toml::from_str(text).map_err(|e| format!("budgets: {e}"))?;
    if let Some(k) = b.keys().find(|k| !KEYS.contains(&k.as_str())) {
        return Err(format!(
            "budgets: unknown key `{k}` (keys: {})",
            KEYS.join(", ")
        ));
    }
    Ok(b)
}

/// The keys over budget, as `key = value > budget` lines.
pub fn over_budget(f: &Figures, budgets: &BTreeMap<String, u64>) -> Vec<String> {
    KEYS.iter()
        .filter_map(|&k| {
            let (v, b) = (f.get(k)?, *budgets.get(k)?);
            (v > b).then(|| format!("{k} = {} > budget {}", group(v), group(b)))
        })
        .collect()
}

/// 1234567 → "1,234,567".
pub fn group(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The table.
pub fn table(r: &Report, budgets: &BTreeMap<String, u64>) -> String {
    let mut t = String::new();
    let _ = writeln!(t, "| key | instructions | budget | what |");
    let _ = writeln!(t, "| --- | ---: | ---: | --- |");
    for key in KEYS {
        let v = r.figures.get(key).unwrap_or(0);
        let budget = budgets.get(key).map_or("—".to_owned(), |&b| {
            if v > b {
                format!("{} OVER", group(b))
            } else {
                group(b)
            }
        });
        let what = match key {
            "command_max" => format!("slowest command: `{}`", r.command_max_kind),
            "max_irq_off" => format!(
                "longest of {} windows in the scripted run, in {}",
                group(r.script_windows),
                r.irq_off_at
            ),
            _ => sources(key)
                .iter()
                .filter_map(|n| r.regions.get(*n).map(|s| (n, s)))
                .map(|(n, s)| format!("{n}: n {}, median {}", s.n, group(s.median)))
                .collect::<Vec<_>>()
                .join("; "),
        };
        let _ = writeln!(t, "| `{key}` | {} | {budget} | {what} |", group(v));
    }
    // Reported, not gated (no JSON key): extra rows.
    for (name, what) in EXTRA_ROWS {
        if let Some(s) = r.regions.get(name) {
            let _ = writeln!(
                t,
                "| `{name}` | {} | — | {what}: n {}, median {} |",
                group(s.max),
                s.n,
                group(s.median)
            );
        }
    }
    let _ = writeln!(t);
    let _ = writeln!(t, "| region | n | min | median | max |");
    let _ = writeln!(t, "| --- | ---: | ---: | ---: | ---: |");
    for (name, s) in &r.regions {
        let _ = writeln!(
            t,
            "| {name} | {} | {} | {} | {} |",
            s.n,
            group(s.min),
            group(s.median),
            group(s.max)
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::super::trace::{Region, Window};
    use super::*;

    fn layout() -> Layout {
        let mut l = Layout::default();
        for n in [
            "calib_empty",
            "calib_nop100",
            "calib_loop50",
            "calib_irq40",
            "calib_cs40",
            "step_accel",
            "step_cruise",
            "oversample",
            "frame",
            "frame_rls",
            "frame_rls_drift",
            "telemetry_line",
            "cmd_status",
            "cmd_model_commit",
            "step_batch3",
            "frame_chain",
        ] {
            l.name_index(n);
        }
        l
    }

    fn region(l: &Layout, name: &str, insns: u64, irq: u64) -> Region {
        let name = l.names.iter().position(|n| n == name).unwrap();
        Region {
            name,
            insns,
            max_irq_off: irq,
        }
    }

    fn counts(l: &Layout) -> Counts {
        let r = |n, i, q| region(l, n, i, q);
        Counts {
            regions: vec![
                r("calib_empty", 0, 0),
                r("calib_nop100", 100, 0),
                r("calib_loop50", 101, 0),
                r("calib_irq40", 42, 42),
                r("calib_cs40", 41, 40),
                r("step_accel", 10, 5),
                r("step_accel", 30, 5),
                r("step_cruise", 20, 5),
                r("oversample", 7, 3),
                r("frame", 70, 60),
                r("frame_rls", 80, 70),
                r("frame_rls_drift", 90, 85),
                r("telemetry_line", 9, 4),
                r("cmd_status", 11, 3),
                r("cmd_model_commit", 12, 3),
                r("cmd_status", 13, 3),
                r("step_batch3", 40, 5),
                r("frame_chain", 75, 60),
            ],
            total: 1000,
            script_insns: 900,
            script_windows: 12,
            script_max_irq_off: Some(Window {
                len: 85,
                start_pc: 0x0800_1000,
                region: Some(11),
            }),
        }
    }

    #[test]
    fn figures_are_the_maxima_of_their_regions() {
        let l = layout();
        let c = counts(&l);
        assert!(check_calibration(&l, &c).is_ok());
        let r = report(&l, &c).unwrap();
        assert_eq!(
            r.figures,
            Figures {
                step: 30,
                oversample: 7,
                frame: 70,
                frame_rls: 80,
                frame_rls_drift: 90,
                frame_chain: 75,
                telemetry_line: 9,
                command_max: 13,
                max_irq_off: 85,
            }
        );
        assert_eq!(r.command_max_kind, "status");
        assert!(r.irq_off_at.starts_with("frame_rls_drift"));
        assert_eq!(r.regions["step_accel"].median, 30);
        assert_eq!(r.regions["step_accel"].n, 2);
        // The three-step batch is shown, not gated, and not a JSON key.
        let t = table(&r, &BTreeMap::new());
        assert!(t.contains("| `step_batch3` | 40 | — |"), "{t}");
        // The JSON has exactly the keys, in order, numbers only.
        let json = serde_json::to_string(&r.figures).unwrap();
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
        let mut sorted = KEYS.to_vec();
        sorted.sort_unstable();
        assert_eq!(keys, sorted);
        assert!(v.as_object().unwrap().values().all(|x| x.is_u64()));
    }

    #[test]
    fn a_wrong_calibration_count_is_an_error() {
        let l = layout();
        let mut c = counts(&l);
        c.regions[1].insns = 101;
        let e = check_calibration(&l, &c).unwrap_err();
        assert!(e.contains("calib_nop100"), "{e}");
        let mut c = counts(&l);
        c.regions[3].max_irq_off = 41;
        assert!(check_calibration(&l, &c)
            .unwrap_err()
            .contains("calib_irq40"));
        let mut c = counts(&l);
        c.regions.remove(0);
        assert!(check_calibration(&l, &c)
            .unwrap_err()
            .contains("calib_empty"));
    }

    #[test]
    fn a_missing_measurement_is_an_error() {
        let l = layout();
        let mut c = counts(&l);
        c.regions.retain(|r| l.names[r.name] != "frame_rls_drift");
        assert!(report(&l, &c).unwrap_err().contains("frame_rls_drift"));
        let mut c = counts(&l);
        c.script_max_irq_off = None;
        assert!(report(&l, &c).is_err());
    }

    #[test]
    fn budgets_name_each_exceeded_key() {
        let b = parse_budgets("step = 300\nframe = 6000\nmax_irq_off = 2000\n").unwrap();
        let f = Figures {
            step: 1810,
            oversample: 1,
            frame: 6000,
            frame_rls: 1,
            frame_rls_drift: 1,
            frame_chain: 1,
            telemetry_line: 1,
            command_max: 1,
            max_irq_off: 118_000,
        };
        assert_eq!(
            over_budget(&f, &b),
            [
                "step = 1,810 > budget 300",
                "max_irq_off = 118,000 > budget 2,000"
            ]
        );
        assert!(parse_budgets("stepp = 3\n").is_err());
        assert!(parse_budgets("step = -3\n").is_err());
        assert!(parse_budgets("step = \"x\"\n").is_err());
    }

    #[test]
    fn groups_thousands() {
        assert_eq!(group(0), "0");
        assert_eq!(group(999), "999");
        assert_eq!(group(1000), "1,000");
        assert_eq!(group(118_234), "118,234");
        assert_eq!(group(1_234_567), "1,234,567");
    }
}
