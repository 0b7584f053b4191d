//! The V–P figure of a simulated protocol run, in the style of the paper's Fig. 1c: per flow
//! rate, the range of measured pressure over all cycles (shaded) and its mean (line), inflation
//! and deflation, from the firmware's own telemetry (chamber 0).
//!
//! ```sh
//! cargo run --release -p host-sim --example vp_figure -- [--cycles 20] [--flows 20,40,60,80,100] \
//!     [--out docs/guide/src/img/sim-vp-protocol.png] [--font /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf]
//! ```
use std::collections::BTreeMap;
use std::error::Error;

use host_sim::{simulate, PlantConfig, Protocol, Scenario};
use plotters::prelude::*;
use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
use plotters::style::{register_font, FontStyle};

const BIN_MM3: f64 = 10.0;

fn arg(args: &[String], key: &str) -> Option<String> {
    args.iter()
        .position(|a| a == key)
        .and_then(|i| args.get(i + 1).cloned())
}

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().collect();
    let cycles: u16 = arg(&args, "--cycles").map_or(Ok(20), |s| s.parse())?;
    let flows: Vec<f64> = match arg(&args, "--flows") {
        Some(s) => s
            .split(',')
            .map(|x| x.trim().parse())
            .collect::<Result<_, _>>()?,
        None => vec![20.0, 40.0, 60.0, 80.0, 100.0],
    };
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
    let out = arg(&args, "--out")
        .unwrap_or_else(|| format!("{root}/docs/guide/src/img/sim-vp-protocol.png"));
    let font = arg(&args, "--font")
        .unwrap_or_else(|| "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf".into());
    let bytes =
        std::fs::read(&font).map_err(|e| format!("font {font}: {e} (pass --font <ttf>)"))?;
    register_font(
        "sans-serif",
        FontStyle::Normal,
        Box::leak(bytes.into_boxed_slice()),
    )
    .map_err(|_| format!("font {font}: not a TrueType/OpenType font"))?;

    let protocol = Protocol {
        cycles,
        flows: flows.clone(),
        ..Protocol::paper()
    };
    let sc = Scenario::protocol("figure", PlantConfig::default(), &protocol);
    let run = simulate(&sc)?;
    if let Some(e) = run.first_event("fault") {
        return Err(format!("the firmware faulted during the run: {e:?}").into());
    }

    // Legs: runs of frames moving in one direction; a leg's rate is its peak |v̇|.
    // (rate index, inflating) -> volume bin -> pressures
    let mut bins: BTreeMap<(usize, bool), BTreeMap<i64, Vec<f64>>> = BTreeMap::new();
    let mut leg: Vec<(f64, f64)> = Vec::new();
    let mut leg_sign = 0.0f32;
    let mut leg_peak = 0.0f32;
    let mut flush = |leg: &mut Vec<(f64, f64)>, sign: f32, peak: f32| {
        if leg.is_empty() || sign == 0.0 {
            leg.clear();
            return;
        }
        let idx = (0..flows.len())
            .min_by(|&a, &b| {
                (flows[a] - peak as f64)
                    .abs()
                    .total_cmp(&(flows[b] - peak as f64).abs())
            })
            .unwrap_or(0);
        for &(v, p) in leg.iter() {
            let b = (v / BIN_MM3).floor() as i64;
            bins.entry((idx, sign > 0.0))
                .or_default()
                .entry(b)
                .or_default()
                .push(p);
        }
        leg.clear();
    };
    for f in &run.frames {
        let c = &f.chambers[0];
        let s = c.vdot.signum() * (c.vdot != 0.0) as i32 as f32;
        if s != leg_sign {
            flush(&mut leg, leg_sign, leg_peak);
            leg_sign = s;
            leg_peak = 0.0;
        }
        if s != 0.0 {
            leg.push((c.v as f64, c.p as f64));
            leg_peak = leg_peak.max(c.vdot.abs());
        }
    }
    flush(&mut leg, leg_sign, leg_peak);

    let (p_min, p_max) = bins
        .values()
        .flat_map(|m| m.values().flatten())
        .fold((0.0f64, 0.0f64), |(a, b), &p| (a.min(p), b.max(p)));
    let area = BitMapBackend::new(&out, (1000, 720)).into_drawing_area();
    area.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&area)
        .caption(
            format!(
                "Simulated SBA1, paper protocol: {} cycles per rate (firmware telemetry, chamber 0)",
                cycles
            ),
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0f64..560.0, (p_min - 2.0).floor()..(p_max + 2.0).ceil())?;
    chart
        .configure_mesh()
        .x_desc("volume v (mm³)")
        .y_desc("pressure P (kPa)")
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    for ((idx, inflating), m) in &bins {
        // Flow rate is ordered, so a sequential map (viridis, stopping short of its pale yellow end).
        let shade = 0.85 * *idx as f64 / (flows.len().max(2) - 1) as f64;
        let color: RGBColor = ViridisRGB.get_color(shade);
        let stats: Vec<(f64, f64, f64, f64)> = m
            .iter()
            .filter(|(_, ps)| !ps.is_empty())
            .map(|(b, ps)| {
                let v = (*b as f64 + 0.5) * BIN_MM3;
                let lo = ps.iter().cloned().fold(f64::INFINITY, f64::min);
                let hi = ps.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                let mean = ps.iter().sum::<f64>() / ps.len() as f64;
                (v, lo, hi, mean)
            })
            .collect();
        let mut band: Vec<(f64, f64)> = stats.iter().map(|s| (s.0, s.2)).collect();
        band.extend(stats.iter().rev().map(|s| (s.0, s.1)));
        chart.draw_series(std::iter::once(Polygon::new(
            band,
            color.mix(0.18).filled(),
        )))?;
        let line = chart.draw_series(LineSeries::new(
            stats.iter().map(|s| (s.0, s.3)),
            color.stroke_width(2),
        ))?;
        if *inflating {
            line.label(format!("flow {} mm³/s", flows[*idx]))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3))
                });
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", 16))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .draw()?;
    area.present()?;
    println!(
        "wrote {out}: {} frames, {:.0} s of rig time",
        run.frames.len(),
        run.stats.end_us as f64 * 1e-6
    );
    Ok(())
}
