//! Drawing the monitor's state on any ratatui backend: a status block on top, one pane per
//! chamber (measured pressure against P̂ over the chart window, the residual), and at the bottom
//! the force, the flags and the log pane.

use firmware::telemetry::{Flags, Frame};
use model_core::force::{estimate, DEFAULT_AREAS_MM2};
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style, Stylize};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Axis, Block, Chart, Dataset, GraphType, LegendPosition, Paragraph, Wrap};

use super::state::MonitorState;

/// What the screen says about where the data comes from and goes to.
#[derive(Debug, Clone, Default)]
pub struct View {
    /// The input, as given on the command line.
    pub source: String,
    /// The log being recorded, if any.
    pub recording: Option<String>,
}

const MEASURED: Color = Color::Cyan;
const PREDICTED: Color = Color::Yellow;

/// Draws the whole screen.
pub fn render(frame: &mut ratatui::Frame, state: &MonitorState, view: &View) {
    let [status, chambers, bottom] = Layout::vertical([
        Constraint::Length(4),
        Constraint::Min(8),
        Constraint::Length(9),
    ])
    .areas(frame.area());
    frame.render_widget(status_block(state, view), status);
    let panes = Layout::horizontal([Constraint::Ratio(1, 3); 3]).split(chambers);
    for (ch, area) in panes.iter().enumerate() {
        chamber_pane(frame, state, ch, *area);
    }
    let [force, flags, log] = Layout::horizontal([
        Constraint::Length(30),
        Constraint::Length(34),
        Constraint::Min(20),
    ])
    .areas(bottom);
    frame.render_widget(force_pane(state.last.as_ref()), force);
    frame.render_widget(flags_pane(state), flags);
    frame.render_widget(log_pane(state, log.height.saturating_sub(2)), log);
}

/// Counts: what arrived, at what rate, what is missing and why.
fn status_block<'a>(state: &MonitorState, view: &'a View) -> Paragraph<'a> {
    let c = &state.counts;
    let rate = state
        .received_rate_hz()
        .map_or("–".to_string(), |r| format!("{r:.1}"));
    let seqs = match (state.first_seq, state.last.as_ref()) {
        (Some(a), Some(f)) => format!(" (seq {a}..={})", f.seq),
        _ => String::new(),
    };
    let bad = |n: u64| {
        if n == 0 {
            Style::default().fg(Color::Green)
        } else {
            Style::default().fg(Color::Red).add_modifier(Modifier::BOLD)
        }
    };
    let line1 = Line::from(vec![
        format!("frames {}{seqs} · {rate} frames/s · ", c.frames).into(),
        Span::styled(format!("missing {}", c.missing), bad(c.missing)),
        format!(
            " in {} gaps · board dropped {} lines · ",
            c.gaps, c.board_drops
        )
        .into(),
        Span::styled(
            format!("lost on the way ≥ {}", c.lost_in_transit),
            bad(c.lost_in_transit),
        ),
    ]);
    let line2 = Line::from(vec![
        Span::styled(format!("corrupted {}", c.corrupted), bad(c.corrupted)),
        format!(
            " · rejected {} · events {} · restarts {} · lines {} ({} other)",
            c.rejected, c.events, c.restarts, c.lines, c.other
        )
        .into(),
    ]);
    let state_word = if state.input_ended {
        " input ended ".red()
    } else {
        " live ".green()
    };
    let rec = view
        .recording
        .as_deref()
        .map_or(" not recording ".to_string(), |r| {
            format!(" recording {r} ")
        });
    Paragraph::new(vec![line1, line2]).block(
        Block::bordered()
            .title(Line::from(vec![
                format!(" vfp monitor · {} ·", view.source).bold(),
                state_word,
            ]))
            .title_bottom(Line::from(vec![rec.into(), " q quits ".bold()]).right_aligned()),
    )
}

/// One chamber: its numbers in the title lines, P and P̂ over the window below.
fn chamber_pane(frame: &mut ratatui::Frame, state: &MonitorState, ch: usize, area: Rect) {
    let block = Block::bordered().title(format!(" chamber {ch} "));
    let inner = block.inner(area);
    frame.render_widget(block, area);
    let [text, chart] = Layout::vertical([Constraint::Length(2), Constraint::Min(3)]).areas(inner);
    let lines = match &state.last {
        Some(f) => {
            let c = &f.chambers[ch];
            vec![
                Line::from(vec![
                    Span::styled(format!("P {:.3}", c.p), MEASURED),
                    "  ".into(),
                    Span::styled(format!("P̂ {:.3}", c.p_hat), PREDICTED),
                    " kPa".into(),
                ]),
                Line::from(format!("r {:+.3} kPa  v {:.1} mm³", c.residual, c.v)),
            ]
        }
        None => vec![Line::from("waiting for frames…")],
    };
    frame.render_widget(Paragraph::new(lines), text);
    let measured: Vec<(f64, f64)> = state
        .window()
        .map(|p| (p.t_s, f64::from(p.p[ch])))
        .collect();
    let predicted: Vec<(f64, f64)> = state
        .window()
        .map(|p| (p.t_s, f64::from(p.p_hat[ch])))
        .collect();
    frame.render_widget(pressure_chart(&measured, &predicted, state.window_s), chart);
}

/// P (measured) and P̂ against board time over the last `window_s` seconds.
fn pressure_chart<'a>(
    measured: &'a [(f64, f64)],
    predicted: &'a [(f64, f64)],
    window_s: f64,
) -> Chart<'a> {
    let t_end = measured.last().map_or(window_s, |p| p.0);
    let (lo, hi) = measured
        .iter()
        .chain(predicted)
        .map(|p| p.1)
        .filter(|y| y.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
            (a.min(y), b.max(y))
        });
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (0.0, 1.0) };
    let pad = ((hi - lo) * 0.05).max(0.05);
    let (lo, hi) = (lo - pad, hi + pad);
    let dataset = |name: &'a str, data: &'a [(f64, f64)], color| {
        Dataset::default()
            .name(name)
            .marker(Marker::Braille)
            .graph_type(GraphType::Line)
            .style(Style::default().fg(color))
            .data(data)
    };
    Chart::new(vec![
        dataset("P", measured, MEASURED),
        dataset("P̂", predicted, PREDICTED),
    ])
    // Pressure rises to the right as the syringes fill: the legend goes top left.
    .legend_position(Some(LegendPosition::TopLeft))
    .x_axis(
        Axis::default()
            .bounds([t_end - window_s, t_end])
            .labels([format!("-{window_s:.0} s"), "now".to_string()]),
    )
    .y_axis(
        Axis::default()
            .bounds([lo, hi])
            .labels([format!("{lo:.1}"), format!("{hi:.1}")]),
    )
}

/// The force: the board's magnitude, its direction and each chamber's share.
fn force_pane(last: Option<&Frame>) -> Paragraph<'static> {
    let block = Block::bordered().title(" force ");
    let Some(f) = last else {
        return Paragraph::new("–").block(block);
    };
    let mut lines = vec![Line::from(vec![
        "|F| ".into(),
        format!("{:.1} mN", f.force_n * 1e3).bold(),
    ])];
    // The paper's F = |Σ rᵢ·Aᵢ|; the sign of the sum tells pushing in from pulling out.
    match estimate(f.chambers.map(|c| c.residual), DEFAULT_AREAS_MM2) {
        Ok(e) => {
            let s = e.signed_total_n();
            let dir = if s >= 0.0 {
                "pushing in"
            } else {
                "pulling out"
            };
            let s = s * 1e3;
            lines.push(Line::from(format!("{dir} (Σ rᵢAᵢ {s:+.1} mN)")));
            let scale = e.per_chamber_n.iter().fold(0.0f32, |m, x| m.max(x.abs()));
            for (ch, fi) in e.per_chamber_n.iter().enumerate() {
                let bar = bar(*fi, scale);
                lines.push(Line::from(format!("F{ch} {:+6.1} mN {bar}", fi * 1e3)));
            }
        }
        Err(_) => lines.push(Line::from("direction: residual not finite".red())),
    }
    Paragraph::new(lines).block(block)
}

/// A bar of up to 8 cells for `x` relative to `scale` (the largest share), with its sign.
fn bar(x: f32, scale: f32) -> String {
    let n = if scale > 0.0 {
        ((x.abs() / scale).min(1.0) * 8.0).round() as usize
    } else {
        0
    };
    let fill = "█".repeat(n);
    if x < 0.0 {
        format!("-{fill}")
    } else {
        format!("+{fill}")
    }
}

/// The names of per-channel flags, their base bit and whether they are latched faults.
const CHANNEL_FLAGS: [(&str, u32, bool); 8] = [
    ("over-pressure", Flags::OVER_PRESSURE, true),
    ("volume-limit", Flags::VOLUME_LIMIT, true),
    ("sensor-rail", Flags::SENSOR_RAIL, true),
    ("sensor-jump", Flags::SENSOR_JUMP, true),
    ("model-range", Flags::MODEL_RANGE, false),
    ("drift", Flags::DRIFT, false),
    ("rls", Flags::RLS_ACTIVE, false),
    ("origin-needed", Flags::ORIGIN_NEEDED, false),
];
/// Board-wide flags.
const BOARD_FLAGS: [(&str, u32, bool); 5] = [
    ("stopped", Flags::STOPPED, false),
    ("fault-reset", Flags::FAULT_RESET, true),
    ("not-zeroed", Flags::NOT_ZEROED, false),
    ("model-unsaved", Flags::MODEL_UNSAVED, false),
    ("store-failed", Flags::STORE_FAILED, false),
];

/// The set flags by name (`over-pressure 1` for channel 1), faults first.
pub fn flag_names(flags: Flags) -> Vec<(String, bool)> {
    let mut out = Vec::new();
    for (name, bit, fault) in BOARD_FLAGS {
        if flags.has(bit) {
            out.push((name.to_string(), fault));
        }
    }
    for (name, base, fault) in CHANNEL_FLAGS {
        for ch in 0..3 {
            if flags.has(Flags::channel(base, ch)) {
                out.push((format!("{name} {ch}"), fault));
            }
        }
    }
    out.sort_by_key(|f| !f.1);
    out
}

/// Flags of the latest frame: faults in red, warnings in yellow.
fn flags_pane(state: &MonitorState) -> Paragraph<'static> {
    let flags = state.last.map_or(Flags(0), |f| f.flags);
    let names = flag_names(flags);
    let mut lines = vec![if flags.is_fault() {
        Line::from(format!("FAULT (flags {:#x})", flags.0).red().bold())
    } else {
        Line::from(format!("no fault (flags {:#x})", flags.0).green())
    }];
    lines.extend(names.into_iter().map(|(n, fault)| match fault {
        true => Line::from(n.red()),
        false => Line::from(n.yellow()),
    }));
    let faults = state.counts.fault_events;
    Paragraph::new(lines)
        .wrap(Wrap { trim: true })
        .block(Block::bordered().title(format!(" flags · {faults} fault events ")))
}

/// The last `rows` lines of other output, events and problems.
fn log_pane(state: &MonitorState, rows: u16) -> Paragraph<'static> {
    let lines = state.log_lines();
    let skip = lines.len().saturating_sub(usize::from(rows));
    let lines: Vec<Line> = lines
        .skip(skip)
        .map(|l| Line::from(l.to_string()))
        .collect();
    Paragraph::new(lines).block(Block::bordered().title(" log "))
}

/// The buffer's text, one line per row, trailing spaces removed (tests, the README's picture).
pub fn buffer_text(buf: &Buffer) -> String {
    let width = usize::from(buf.area.width);
    let mut out = String::new();
    for row in buf.content().chunks(width.max(1)) {
        let line: String = row.iter().map(|c| c.symbol()).collect();
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}
