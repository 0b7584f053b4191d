//! The design of an augmented model: the data prepared once ([`Prepared`]), each effect with its
//! parameter fixed ([`Effect`]), and the regressor columns ([`build`]) in the order of the module
//! docs: input transforms along the chain, the baseline's columns on the transformed inputs, the
//! effects' added columns, then the output filters on every column.

use super::{cruise_speeds, CountLag, EffectKind};
use crate::residual::basis::PolyBasis;
use crate::residual::inframe::{self, SubMotion};
use crate::residual::lsq;
use crate::residual::signal;
use crate::residual::Series;

/// Scales of one data set, from which search ranges are set (so the library is not tuned to a rig).
#[derive(Clone, Copy, Debug)]
pub struct Scales {
    /// Volume range (mm³).
    pub v_range: f64,
    /// Median sample interval (s).
    pub dt: f64,
    /// Log duration (s).
    pub duration: f64,
    /// `∫ P dt` over the log (kPa·s).
    pub p_integral: f64,
    /// `∫ max(P, 0) dt` over the log (kPa·s): what a one-way leak loses water with.
    pub p_pos_integral: f64,
    /// Range of the measured pressure over the log, max − min (kPa).
    pub p_range: f64,
    /// The period of the log's cycles when they repeat regularly (s; `Series::cycle_s`).
    pub cycle_s: Option<f64>,
    /// The rig the log comes from (`Series::rig`): the effects' names.
    pub rig: crate::residual::Rig,
}

/// One effect with its nonlinear parameter fixed.
#[derive(Clone, Debug)]
pub struct Effect {
    /// Which effect.
    pub kind: EffectKind,
    /// Its nonlinear parameter (width mm³, τ s, delay s, air mm³, rate mm³/s, λ mm³/(kPa·s),
    /// frequency Hz, drift degree), unused for inertance.
    pub theta: f64,
    /// Air compliance and pump ripple: the damping `c = ∂P/∂v̇` per sample, from the model it was
    /// added to.
    pub damping: Option<std::sync::Arc<Vec<f64>>>,
    /// Pump ripple: the stiffness `k = ∂P/∂v` per sample, from the model it was added to.
    pub stiffness: Option<std::sync::Arc<Vec<f64>>>,
    /// Backlash, transport delay, sensor lag and air compliance: the log's samples are instants
    /// (a sampling sensor) rather than means over each frame (an averaging one, the default): the
    /// play operator then acts on the samples themselves, a delayed flow is the volume
    /// interpolant's derivative, and a lag acts on each column's cubic between samples instead of
    /// inside the frames. The search tries both and keeps the better fit.
    pub point_sampled: bool,
    /// Set by the export (`sysid::board::augmented`): the effect in the form the board runs it,
    /// where that differs from the point-sampled one. Backlash: the play operator on the nut's
    /// motion inside each frame rebuilt from that frame alone (`signal::play_frame_linear`).
    pub board_form: bool,
    /// Pump ripple: the volume error `(a, b)` (mm³) already applied exactly as an input
    /// transform, `u = v + a sin φ + b cos φ`; the two columns then fit the remaining correction
    /// to first order (the search iterates this Gauss–Newton step).
    pub ripple_offset: (f64, f64),
    /// Pump ripple: how far the logged volume trails the plunger while it moves, by speed
    /// ([`CountLag`]).
    pub count_lag: CountLag,
    /// Leak: water lost only while the chamber's pressure is above the atmosphere's,
    /// `q = λ max(P, 0)` (a seal that closes under suction), where `false` is a leak at either
    /// sign, `q = λ P` (an open path). The leak's refinement fits both and keeps the better
    /// (`effects::leak`); the board runs the open path ([`Effect::board_form`]).
    pub one_way: bool,
    /// Leak and air compliance: the chamber's pressure they are scheduled on, where the model
    /// reads it through a sensor lag (set by [`build`] from the model's own lags,
    /// [`pressure_schedule`]); `None`: the measured pressure ([`Prepared::p_sched`]).
    pub pressure: Option<std::sync::Arc<Vec<f64>>>,
}

impl Effect {
    /// An effect without auxiliary data.
    pub fn new(kind: EffectKind, theta: f64) -> Self {
        Self {
            kind,
            theta,
            damping: None,
            stiffness: None,
            point_sampled: false,
            board_form: false,
            ripple_offset: (0.0, 0.0),
            count_lag: CountLag::default(),
            one_way: false,
            pressure: None,
        }
    }

    /// The pressure the effect is scheduled on (kPa, per sample): the chamber's where the design
    /// set it ([`Effect::pressure`]), else the measured one.
    pub fn scheduled_pressure<'a>(&'a self, prep: &'a Prepared) -> &'a [f64] {
        self.pressure.as_deref().map_or(&prep.p_sched, |p| p)
    }
}

/// The chamber's pressure as the model sees it behind its sensor lags: the measured pressure with
/// each lag `τ ẏ + y = P` undone, `P = y + τ ẏ` (ẏ from Akima's slopes of the frame values; on
/// frame means the identity holds of the means too, the mean of a derivative being the
/// derivative of the mean). `None` when the model has no sensor lag, or no effect scheduled on
/// the pressure. An air pocket compresses, and a leak loses water, with the pressure in the
/// chamber, which leads the reading by τ: at 20 ms and the strokes' 50 kPa/s that is 1 kPa, a
/// twentieth of a millimetre of a 20 mm³ pocket's compression but ten times the noise once the
/// stiffness multiplies it.
pub fn pressure_schedule(prep: &Prepared, effects: &[Effect]) -> Option<Vec<f64>> {
    if !effects.iter().any(on_chamber_pressure) {
        return None;
    }
    let mut lags = effects
        .iter()
        .filter_map(|e| e.kind.sensor_lag(e, &prep.scales))
        .peekable();
    lags.peek()?;
    let t = &prep.series.t;
    let mut p = prep.p_sched.clone();
    for tau in lags {
        let slope = signal::akima_slopes(t, &p);
        for (p, s) in p.iter_mut().zip(&slope) {
            *p += tau * s;
        }
    }
    Some(p)
}

/// Whether `e` is scheduled on the chamber's pressure: an effect that reads the pressure, in the
/// loop's form (the board's chain applies its effects to what it reads).
fn on_chamber_pressure(e: &Effect) -> bool {
    e.kind.uses_measured_pressure() && !e.board_form
}

/// `effects` with the chamber's pressure ([`pressure_schedule`]) set on those scheduled on it;
/// borrowed unchanged when there is none. The board's form keeps the measured pressure (the
/// board's chain applies its effects to what it reads).
fn scheduled<'a>(prep: &Prepared, effects: &'a [Effect]) -> std::borrow::Cow<'a, [Effect]> {
    let Some(p) = pressure_schedule(prep, effects) else {
        return std::borrow::Cow::Borrowed(effects);
    };
    let p = std::sync::Arc::new(p);
    std::borrow::Cow::Owned(
        effects
            .iter()
            .map(|e| {
                let mut e = e.clone();
                if on_chamber_pressure(&e) {
                    e.pressure = Some(p.clone());
                }
                e
            })
            .collect(),
    )
}

/// A data set prepared for building designs: the series, the baseline basis, and derived signals.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// The data.
    pub series: Series,
    /// The baseline basis (scaling from the raw inputs).
    pub basis: PolyBasis,
    /// Measured pressure as the scheduling signal of leak and air compliance.
    pub p_sched: Vec<f64>,
    /// `∫ P dt` from the first sample (kPa·s).
    pub p_int: Vec<f64>,
    /// Time mapped onto [−1, 1].
    pub s: Vec<f64>,
    /// Data scales.
    pub scales: Scales,
    /// The flow's parabola edges (`signal::ppm_edges`) from which [`Prepared::subframe`] makes
    /// the logged motion inside each frame as it is read.
    subframe_edges: Vec<(f64, f64)>,
    /// The motion at the same instants as the output lags see it inside the frames
    /// ([`Prepared::sub_motion`]), made on first use and shared by clones.
    sub_motion: std::sync::Arc<std::sync::OnceLock<SubMotion>>,
    /// The last inputs an effect's transform made from the logged motion ([`Prepared::memo_inputs`]).
    input_memo: std::sync::Arc<std::sync::Mutex<Vec<InputMemo>>>,
    /// The last pump ripple columns and inputs made ([`Prepared::memo_ripple`]); a clone starts
    /// with none.
    ripple_memo: RippleMemo,
    /// The speeds the log dwells at ([`cruise_speeds`]), where a pump ripple's count lag is fitted.
    pub cruise_speeds: std::sync::Arc<Vec<f64>>,
    /// Training row indices.
    pub train_rows: Vec<usize>,
    /// The budget of the designs built on these data ([`DesignGate`], [`DESIGN_MEMORY`]).
    pub gate: std::sync::Arc<DesignGate>,
    /// Held-out row indices.
    pub held_rows: Vec<usize>,
}

/// An effect's name and parameter (its bits), and the volume and flow it made.
type InputMemo = ((&'static str, u64), std::sync::Arc<(Vec<f64>, Vec<f64>)>);

/// Inputs [`Prepared::memo_inputs`] keeps (each two numbers per sample).
const INPUT_MEMOS: usize = 2;

/// One pair of series [`Prepared::memo_ripple`] made: its key (the parameters' bits), the
/// per-sample data it was made from (held, so that the identity of each stays unique while the
/// entry lives), the inputs it was made from (compared bit for bit), and the pair.
struct RippleEntry {
    key: Vec<u64>,
    pins: Vec<std::sync::Arc<Vec<f64>>>,
    from: Option<(Vec<f64>, Vec<f64>)>,
    made: std::sync::Arc<(Vec<f64>, Vec<f64>)>,
}

/// Pairs [`Prepared::memo_ripple`] keeps (each two numbers per sample, four with the inputs).
const RIPPLE_MEMOS: usize = 3;

/// The memo of [`Prepared::memo_ripple`], its own per [`Prepared`] (a clone starts empty).
#[derive(Default)]
struct RippleMemo(std::sync::Mutex<Vec<RippleEntry>>);

impl Clone for RippleMemo {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl std::fmt::Debug for RippleMemo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("RippleMemo")
    }
}

/// Whether two series are the same bit for bit.
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

impl Prepared {
    /// The logged motion rebuilt at `signal::SUB_SAMPLES` instants per frame (position, flow;
    /// `signal::FrameMotion`), made a frame at a time as it is read: held whole, it would be
    /// 16 numbers per sample for the whole run (34 MB on a 3-hour log).
    pub fn subframe(&self) -> signal::FrameMotion<'_> {
        let se = &self.series;
        signal::FrameMotion::new(&se.t, &se.v, &se.vdot, &self.subframe_edges)
    }

    /// `self` with the motion inside its frames given: `f` the flow at each frame's instants
    /// ([`inframe::frame_instants`], frame k's at `k·S ..`), for a motion known exactly (an
    /// experiment's plan, `residual::decide`) instead of rebuilt from the frame means. Ignored
    /// when the motion was already made or `f` has not S numbers per frame.
    pub fn with_sub_flows(self, f: Vec<f64>) -> Self {
        if f.len() == self.series.len() * crate::residual::signal::SUB_SAMPLES {
            let _ = self.sub_motion.set(SubMotion { f });
        }
        self
    }

    /// The logged motion rebuilt at the instants each frame averages, with the fewest corners of
    /// flow (`inframe::sparse_motion`), where the output lags run ([`super::lag_in_frames`]).
    pub fn sub_motion(&self) -> &SubMotion {
        self.sub_motion.get_or_init(|| {
            let se = &self.series;
            inframe::sparse_motion(&se.vdot)
        })
    }

    /// The volume and flow effect `name` at parameter `theta` makes from the logged motion:
    /// `make()` the first time, after that (while it is among the last [`INPUT_MEMOS`]) the same
    /// numbers again. A search over another effect's parameter rebuilds the design many times
    /// with this one unchanged, and the lags inside the frames cost many times a design column.
    pub fn memo_inputs(
        &self,
        name: &'static str,
        theta: f64,
        make: impl FnOnce() -> (Vec<f64>, Vec<f64>),
    ) -> std::sync::Arc<(Vec<f64>, Vec<f64>)> {
        let key = (name, theta.to_bits());
        let lock = |m: &std::sync::Mutex<Vec<InputMemo>>| {
            m.lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .clone()
        };
        if let Some((_, found)) = lock(&self.input_memo).into_iter().find(|(k, _)| *k == key) {
            return found;
        }
        let made = std::sync::Arc::new(make());
        let mut memo = self
            .input_memo
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        memo.retain(|(k, _)| *k != key);
        memo.insert(0, (key, made.clone()));
        memo.truncate(INPUT_MEMOS);
        made
    }

    /// A pump ripple's pair of series (its two columns, or the volume and flow its transform
    /// makes) for parameters `key` (their bits), per-sample data `pins` (by identity) and inputs
    /// `from` (by value): `make()` the first time, after that (while it is among the last
    /// [`RIPPLE_MEMOS`]) the same numbers again. Each makes a sine and a cosine at every instant
    /// inside every frame; once a ripple is in the model, every design built for the other
    /// effects' searches and re-tunes makes them again with the ripple unchanged.
    pub fn memo_ripple(
        &self,
        key: Vec<u64>,
        pins: &[&std::sync::Arc<Vec<f64>>],
        from: Option<(&[f64], &[f64])>,
        make: impl FnOnce() -> (Vec<f64>, Vec<f64>),
    ) -> std::sync::Arc<(Vec<f64>, Vec<f64>)> {
        let lock = || {
            self.ripple_memo
                .0
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        let matches = |e: &RippleEntry| {
            e.key == key
                && e.pins.len() == pins.len()
                && e.pins
                    .iter()
                    .zip(pins)
                    .all(|(a, b)| std::sync::Arc::ptr_eq(a, b))
                && match (&e.from, from) {
                    (None, None) => true,
                    (Some((v, f)), Some((v2, f2))) => same_bits(v, v2) && same_bits(f, f2),
                    _ => false,
                }
        };
        if let Some(e) = lock().iter().find(|e| matches(e)) {
            return e.made.clone();
        }
        let made = std::sync::Arc::new(make());
        let mut memo = lock();
        memo.retain(|e| !matches(e));
        memo.insert(
            0,
            RippleEntry {
                key,
                pins: pins.iter().map(|&p| p.clone()).collect(),
                from: from.map(|(v, f)| (v.to_vec(), f.to_vec())),
                made: made.clone(),
            },
        );
        memo.truncate(RIPPLE_MEMOS);
        made
    }

    /// Baseline columns on the raw inputs. Computed afresh each time (products of Chebyshev
    /// values, as cheap as copying them): a cached copy would hold another (n+1)(m+1) numbers per
    /// sample for the whole run.
    fn raw_columns(&self) -> Vec<Vec<f64>> {
        self.basis.columns(&self.series.v, &self.series.vdot)
    }
}

impl Prepared {
    /// Prepares a series for a baseline `basis` (usually [`PolyBasis::for_data`] on the series).
    pub fn new(series: Series, basis: PolyBasis) -> Self {
        // Unsmoothed: noise enters δ and τ only through factors ≪ 1 (V_a/P_atm·σ), while smoothing
        // would blur the pressure jumps at reversals where the air pocket matters most.
        let p_sched = series.p.clone();
        let p_int = signal::cumulative_integral(&series.t, &p_sched);
        let t0 = series.t[0];
        let duration = series.t[series.t.len() - 1] - t0;
        let s = series
            .t
            .iter()
            .map(|&t| 2.0 * (t - t0) / duration - 1.0)
            .collect();
        let mut dts: Vec<f64> = series.t.windows(2).map(|w| w[1] - w[0]).collect();
        dts.sort_by(f64::total_cmp);
        let dt = dts[dts.len() / 2];
        let v_range = 2.0 * basis.scaling.v_scale;
        let p_integral = *p_int.last().unwrap_or(&0.0);
        let p_pos: Vec<f64> = p_sched.iter().map(|&p| p.max(0.0)).collect();
        let p_pos_integral = signal::cumulative_integral(&series.t, &p_pos)
            .last()
            .copied()
            .unwrap_or(0.0);
        let (p_lo, p_hi) = series
            .p
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        let train_rows = (0..series.len()).filter(|&k| series.train[k]).collect();
        let held_rows = (0..series.len()).filter(|&k| !series.train[k]).collect();
        let subframe_edges = signal::ppm_edges(&series.vdot);
        Self {
            subframe_edges,
            sub_motion: Default::default(),
            input_memo: Default::default(),
            ripple_memo: Default::default(),
            cruise_speeds: std::sync::Arc::new(cruise_speeds(&series.vdot)),
            basis,
            p_sched,
            p_int,
            s,
            scales: Scales {
                v_range,
                dt,
                duration,
                p_integral,
                p_pos_integral,
                p_range: p_hi - p_lo,
                cycle_s: series.cycle_s,
                rig: series.rig,
            },
            train_rows,
            held_rows,
            series,
            gate: DesignGate::new(DESIGN_MEMORY),
        }
    }
}

/// How much memory the full designs of one diagnosis may hold at once (bytes): a 64-column
/// design of a 3-hour log (270,000 samples) is 138 MB, and the candidate searches run on several
/// threads. Below this, the threads build designs freely; above it, one waits for another's
/// design to be dropped ([`DesignGate`]).
pub const DESIGN_MEMORY: usize = 192 << 20;

/// A budget on the memory held by full designs ([`build`]), shared by the threads of one
/// diagnosis: a build takes a [`Permit`] for its size, and waits while the others' permits
/// and its own would exceed the budget. A thread that already holds a permit never waits (it
/// would wait on itself), nor does a request when nothing is held (a design larger than the
/// whole budget still runs, alone). Only the scheduling changes, never a result.
#[derive(Debug)]
pub struct DesignGate {
    budget: usize,
    held: std::sync::Mutex<usize>,
    freed: std::sync::Condvar,
}

thread_local! {
    /// Permits held by this thread (of any gate).
    static HELD_HERE: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

impl DesignGate {
    /// A gate with `budget` bytes.
    pub fn new(budget: usize) -> std::sync::Arc<Self> {
        std::sync::Arc::new(Self {
            budget,
            held: std::sync::Mutex::new(0),
            freed: std::sync::Condvar::new(),
        })
    }

    /// A permit for `bytes`, once the budget allows (see the type's docs).
    fn acquire(self: &std::sync::Arc<Self>, bytes: usize) -> Permit {
        let mut held = self.held.lock().unwrap_or_else(|e| e.into_inner());
        if HELD_HERE.get() == 0 {
            while *held > 0 && *held + bytes > self.budget {
                held = self.freed.wait(held).unwrap_or_else(|e| e.into_inner());
            }
        }
        *held += bytes;
        HELD_HERE.set(HELD_HERE.get() + 1);
        Permit {
            gate: self.clone(),
            bytes,
        }
    }
}

/// A share of a [`DesignGate`]'s budget, given back when dropped.
#[derive(Debug)]
pub struct Permit {
    gate: std::sync::Arc<DesignGate>,
    bytes: usize,
}

/// A copy of the columns takes its own share.
impl Clone for Permit {
    fn clone(&self) -> Self {
        self.gate.acquire(self.bytes)
    }
}

impl Drop for Permit {
    fn drop(&mut self) {
        let mut held = self.gate.held.lock().unwrap_or_else(|e| e.into_inner());
        *held -= self.bytes;
        HELD_HERE.set(HELD_HERE.get().saturating_sub(1));
        self.gate.freed.notify_all();
    }
}

/// Regressor columns of an augmented model, with labels and owners.
#[derive(Clone, Debug)]
pub struct Design {
    /// Columns over every sample (train and held-out).
    pub cols: Vec<Vec<f64>>,
    /// What each column is.
    pub labels: Vec<String>,
    /// Index into the effect list of the effect a column belongs to; `None` for the baseline.
    pub owner: Vec<Option<usize>>,
    /// The share of [`Prepared::gate`] the columns hold.
    permit: Option<Permit>,
}

impl Design {
    /// Drops the columns (and gives their memory back to the gate), keeping labels and owners.
    pub fn release(&mut self) {
        self.cols = Vec::new();
        self.permit = None;
    }
}

/// Builds the design of the baseline augmented with `effects` (see the module docs for the order:
/// input transforms, baseline columns, added columns, output filters).
pub fn build(prep: &Prepared, effects: &[Effect]) -> Design {
    filtered(prep, effects).0
}

/// The design of `effects` (scheduled), its output filters applied, and the moved inputs.
fn filtered(prep: &Prepared, effects: &[Effect]) -> (Design, Option<Moved>) {
    let effects = &*scheduled(prep, effects);
    let (mut design, inputs) = unfiltered(prep, effects);
    output_filters(
        prep,
        effects,
        inputs.as_ref(),
        prep.basis.len(),
        &mut design.cols,
    );
    (design, inputs)
}

/// A model's design with its output filters applied, held through a search of a candidate that
/// only adds columns ([`sse_adding_columns`]).
pub struct FilteredBase {
    design: Design,
    inputs: Option<Moved>,
}

/// Most bytes a [`FilteredBase`] may take (a search holds it beside the designs it builds).
const FILTERED_BASE_BYTES: usize = 64 << 20;

/// The design of `effects` with its output filters applied, for [`sse_adding_columns`]; `None`
/// when no effect filters the output (the searches then take the moments' route,
/// [`sse_structured`]) or the design would take more than [`FILTERED_BASE_BYTES`].
pub fn filtered_base(prep: &Prepared, effects: &[Effect]) -> Option<FilteredBase> {
    if !effects.iter().any(|e| e.kind.filter_stage().is_some()) {
        return None;
    }
    let width = prep.basis.len() + 2 * effects.len();
    if width * prep.series.len() * 8 > FILTERED_BASE_BYTES {
        return None;
    }
    let (design, inputs) = filtered(prep, effects);
    Some(FilteredBase { design, inputs })
}

/// `lsq::sse_fast` of [`build`]'s design of `effects` (`base`'s effects, as [`filtered_base`] was
/// given them, and one more, last)
/// where the last one only adds columns: it neither filters the output, nor moves the inputs,
/// nor reads the pressure, nor lags the sensor, so the design is `base`'s columns as they are
/// followed by its own columns through the same output filters. Every column runs through the
/// filters on its own (`lag_in_frames::apply`, `signal::LagStream`), so those are the same
/// numbers, to the bit: only the new columns are filtered per trial, not the whole design. `None`
/// when the last effect does not qualify.
pub fn sse_adding_columns(prep: &Prepared, base: &FilteredBase, effects: &[Effect]) -> Option<f64> {
    let e = effects.last()?;
    let k = &e.kind;
    if k.filter_stage().is_some()
        || k.transforms_inputs(e)
        || k.uses_measured_pressure()
        || k.sensor_lag(e, &prep.scales).is_some()
    {
        return None;
    }
    let effects = &*scheduled(prep, effects);
    let e = effects.last()?;
    let v = base
        .inputs
        .as_ref()
        .map_or(&prep.series.v[..], |(v, _)| &v[..]);
    let mut extra: Vec<Vec<f64>> = e
        .kind
        .columns(e, prep, v)
        .into_iter()
        .map(|c| c.values)
        .collect();
    let y = &prep.series.p;
    if extra.iter().any(|c| c.len() != y.len()) {
        return None;
    }
    output_filters(prep, effects, base.inputs.as_ref(), 0, &mut extra);
    Some(lsq::sse_fast_parts(
        &base.design.cols,
        &extra,
        y,
        &prep.train_rows,
    ))
}

/// Volume and flow after the input transforms (`transformed_inputs`).
type Moved = (Vec<f64>, Vec<f64>);

/// [`build`] up to the output filters (of `effects` as [`scheduled`]), with the transformed
/// inputs when a transform moved them.
fn unfiltered(prep: &Prepared, effects: &[Effect]) -> (Design, Option<Moved>) {
    // The size before it is built: the baseline's columns plus (at most, for every effect here)
    // two added ones.
    let width = prep.basis.len() + 2 * effects.len();
    let permit = Some(prep.gate.acquire(width * prep.series.len() * 8));
    let inputs = transforms_inputs(effects).then(|| transformed_inputs(prep, effects));
    let mut cols = match &inputs {
        Some((v, f)) => prep.basis.columns(v, f),
        None => prep.raw_columns(),
    };
    let mut labels: Vec<String> = (0..cols.len()).map(|i| prep.basis.label(i)).collect();
    let mut owner: Vec<Option<usize>> = vec![None; cols.len()];
    added_columns(
        prep,
        effects,
        inputs.as_ref().map(|(v, _)| v.as_slice()),
        &mut cols,
        &mut labels,
        &mut owner,
    );
    let design = Design {
        cols,
        labels,
        owner,
        permit,
    };
    (design, inputs)
}

/// Training SSE (`lsq::sse_fast`'s) of the baseline augmented with `effects` when their only
/// output filter is one cubic lag between samples ([`super::EffectModel::output_lag`]: a sensor
/// lag or an air pocket taken on instants, or in the board's form): the unfiltered design is
/// built and the lag streamed into the Gram sum a block of rows at a time
/// (`lsq::sse_fast_streamed`), so the lagged design is never written back nor copied whole. The
/// same lag on the same columns and the same Gram sum: the same SSE, to the bit, as
/// `lsq::sse_fast` of [`build`]'s design. `None` for any other design.
pub fn sse_lagged(prep: &Prepared, effects: &[Effect]) -> Option<f64> {
    let mut filters = effects.iter().filter(|e| e.kind.filter_stage().is_some());
    let (Some(_), None) = (filters.next(), filters.next()) else {
        return None;
    };
    let effects = &*scheduled(prep, effects);
    let e = effects.iter().find(|e| e.kind.filter_stage().is_some())?;
    if super::lag_in_frames::lag_time_constants(prep, &[e]).is_some() {
        return None;
    }
    let (coeffs, slopes) = e.kind.output_lag(e, prep)?;
    let (design, _) = unfiltered(prep, effects);
    let cols = &design.cols;
    let t = &prep.series.t;
    if cols.is_empty() || cols.iter().any(|c| c.len() != t.len()) || coeffs.len() != t.len() {
        return None;
    }
    let mut stream = signal::LagStream::new(t, &coeffs, slopes, cols);
    Some(lsq::sse_fast_streamed(
        cols.len(),
        &prep.series.p,
        &prep.train_rows,
        |hi, out| stream.advance(cols, hi, out),
    ))
}

/// Whether any effect transforms the baseline's inputs.
fn transforms_inputs(effects: &[Effect]) -> bool {
    effects.iter().any(|e| e.kind.transforms_inputs(e))
}

/// Training SSE of the baseline augmented with `effects`, for the parameter searches, without
/// building the design: the baseline block's Gram matrix from Chebyshev moments
/// (`lsq::sse_fast_poly`). `None` when an output filter (sensor lag, air compliance) makes the
/// filtered baseline columns no longer products of Chebyshev polynomials; then the caller builds
/// the design.
pub fn sse_structured(prep: &Prepared, effects: &[Effect]) -> Option<f64> {
    if effects.iter().any(|e| e.kind.filter_stage().is_some()) {
        return None;
    }
    let effects = &*scheduled(prep, effects);
    let se = &prep.series;
    let rows = &prep.train_rows;
    let gather = |x: &[f64]| -> Vec<f64> { rows.iter().map(|&r| x[r]).collect() };
    let moved = transforms_inputs(effects).then(|| transformed_inputs(prep, effects));
    let (v, f) = match &moved {
        Some((v, f)) => (gather(v), gather(f)),
        None => (gather(&se.v), gather(&se.vdot)),
    };
    // The span of T_i(x)T_j(y), i ≤ n, j ≤ m, is every polynomial of degree ≤ (n, m) in (v, v̇)
    // whatever the affine scaling, and so is the SSE; scaling onto the transformed inputs' own
    // range keeps the Gram matrix well conditioned when a transform (leak, drift) moves them
    // outside the baseline's [−1, 1].
    let b = &PolyBasis::for_data(&v, &f, prep.basis.n, prep.basis.m).ok()?;
    let (mut extra, mut labels, mut owner) = (Vec::new(), Vec::new(), Vec::new());
    added_columns(
        prep,
        effects,
        moved.as_ref().map(|(v, _)| v.as_slice()),
        &mut extra,
        &mut labels,
        &mut owner,
    );
    let extra: Vec<Vec<f64>> = extra.iter().map(|c| gather(c)).collect();
    let y = gather(&se.p);
    let mean = y.iter().sum::<f64>() / y.len().max(1) as f64;
    let yc: Vec<f64> = y.iter().map(|p| p - mean).collect();
    let factors = |r: std::ops::Range<usize>| b.factors(&v[r.clone()], &f[r], 2 * b.n, 2 * b.m);
    Some(lsq::sse_fast_poly(factors, b.n, b.m, &extra, &yc))
}

/// The volume and flow an input transform acts on, as the transforms before it left them.
#[derive(Clone, Debug)]
pub struct Inputs {
    /// Volume (mm³) over every sample.
    pub v: Vec<f64>,
    /// Flow (mm³/s) over every sample.
    pub f: Vec<f64>,
    /// True while `v`, `f` are still the logged ones, so the motion inside each frame is
    /// [`Prepared::subframe`].
    pub raw: bool,
}

/// Volume and flow after the input transforms, applied in the order of their
/// [`super::EffectModel::input_stage`] (ties in the order of `effects`).
fn transformed_inputs(prep: &Prepared, effects: &[Effect]) -> (Vec<f64>, Vec<f64>) {
    let mut chain: Vec<&Effect> = effects
        .iter()
        .filter(|e| e.kind.input_stage().is_some())
        .collect();
    chain.sort_by_key(|e| e.kind.input_stage());
    let mut inputs = Inputs {
        v: prep.series.v.clone(),
        f: prep.series.vdot.clone(),
        raw: true,
    };
    for e in chain {
        if e.kind.transforms_inputs(e) {
            e.kind.transform_inputs(e, prep, &mut inputs);
            inputs.raw = false;
        }
    }
    (inputs.v, inputs.f)
}

/// Appends the effects' added columns (in the order of `effects`).
fn added_columns(
    prep: &Prepared,
    effects: &[Effect],
    moved: Option<&[f64]>,
    cols: &mut Vec<Vec<f64>>,
    labels: &mut Vec<String>,
    owner: &mut Vec<Option<usize>>,
) {
    for (idx, e) in effects.iter().enumerate() {
        let v = moved.unwrap_or(&prep.series.v);
        for c in e.kind.columns(e, prep, v) {
            cols.push(c.values);
            labels.push(c.label);
            owner.push(Some(idx));
        }
    }
}

/// Applies the output filters in the order of their [`super::EffectModel::filter_stage`]: when
/// they are all lags in the loop's frame-mean form, inside the frames ([`super::lag_in_frames`];
/// `inputs` the transformed volume and flow the baseline's columns were evaluated on, if any;
/// the first `nb` of `cols` the baseline's, the others added columns);
/// otherwise (a filter in the board's form) each by its own [`super::EffectModel::filter`].
fn output_filters(
    prep: &Prepared,
    effects: &[Effect],
    inputs: Option<&(Vec<f64>, Vec<f64>)>,
    nb: usize,
    cols: &mut [Vec<f64>],
) {
    let mut filters: Vec<&Effect> = effects
        .iter()
        .filter(|e| e.kind.filter_stage().is_some())
        .collect();
    if filters.is_empty() {
        return;
    }
    filters.sort_by_key(|e| e.kind.filter_stage());
    if let Some(taus) = super::lag_in_frames::lag_time_constants(prep, &filters) {
        super::lag_in_frames::apply(prep, inputs, nb, &taus, cols);
        return;
    }
    for e in filters {
        e.kind.filter(e, prep, cols);
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Hysteresis, Leak, OffsetDrift, Ripple, SensorLag, VolumeDrift};
    use super::*;

    /// `len` frames at 25 Hz of two incommensurate tones, so (v, v̇) fills an area (one tone traces
    /// an ellipse, on which the tensor basis is rank-deficient), prepared for a (3, 2) baseline.
    fn two_tones(len: usize) -> Prepared {
        let (t, v, f) = crate::test_motion::two_tones(len);
        let p: Vec<f64> = (0..len)
            .map(|k| 2.0 + 0.01 * v[k] + 0.002 * f[k] + 0.05 * (1.7 * t[k]).sin())
            .collect();
        let train: Vec<bool> = (0..len).map(|k| (k / 300) % 5 != 4).collect();
        let series = Series::new(t, v, f, p, train).unwrap();
        let basis = PolyBasis::for_data(&series.v, &series.vdot, 3, 2).unwrap();
        Prepared::new(series, basis)
    }

    /// A reading that lags a known chamber pressure `x = 20 + 10 sin ωt` through `τ ẏ + y = x`
    /// (its steady state in closed form): behind the model's sensor lag, the air pocket is
    /// scheduled on `x` itself; without a sensor lag, or without an effect scheduled on the
    /// pressure, there is nothing to undo.
    #[test]
    fn the_schedule_undoes_the_sensor_lag_to_the_chamber_pressure() {
        let (tau, w) = (0.02, std::f64::consts::TAU * 0.5);
        let mut prep = two_tones(1500);
        let t = prep.series.t.clone();
        let x: Vec<f64> = t.iter().map(|&t| 20.0 + 10.0 * (w * t).sin()).collect();
        let gain = 10.0 / (1.0 + (w * tau).powi(2)).sqrt();
        prep.p_sched = t
            .iter()
            .map(|&t| 20.0 + gain * (w * t - (w * tau).atan()).sin())
            .collect();
        let air = Effect::new(EffectKind(&super::super::AirCompliance), 20.0);
        let lag = Effect::new(EffectKind(&SensorLag), tau);
        let worst = |p: &[f64]| {
            (2..p.len() - 2)
                .map(|k| (p[k] - x[k]).abs())
                .fold(0.0, f64::max)
        };
        // The reading itself is off by up to ωτ·10 ≈ 0.63 kPa.
        assert!(worst(&prep.p_sched) > 0.6);
        let sched = pressure_schedule(&prep, &[air.clone(), lag.clone()]).expect("a sensor lag");
        assert!(worst(&sched) < 0.005, "{}", worst(&sched));
        assert!(pressure_schedule(&prep, std::slice::from_ref(&air)).is_none());
        assert!(pressure_schedule(&prep, std::slice::from_ref(&lag)).is_none());
        // The design's copy of the air pocket carries it; the caller's effects are untouched.
        let both = [air, lag];
        let set = scheduled(&prep, &both);
        assert_eq!(set[0].scheduled_pressure(&prep), &sched[..]);
        assert!(set[1].pressure.is_none() && both[0].pressure.is_none());
    }

    #[test]
    fn the_gate_keeps_other_threads_within_the_budget_and_never_blocks_a_holder() {
        let gate = DesignGate::new(100);
        // One request above the whole budget runs when nothing is held; a thread holding a
        // permit gets another at once (it would otherwise wait on itself).
        let big = gate.acquire(150);
        let more = gate.acquire(70);
        assert_eq!(*gate.held.lock().unwrap(), 220);
        drop((big, more));
        assert_eq!(*gate.held.lock().unwrap(), 0);
        // Four threads each taking 60 of 100, 200 times: never two at once.
        let most = std::sync::Mutex::new(0usize);
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for _ in 0..200 {
                        let p = gate.acquire(60);
                        let now = *gate.held.lock().unwrap();
                        let mut m = most.lock().unwrap();
                        *m = (*m).max(now);
                        drop(m);
                        std::thread::yield_now();
                        drop(p);
                    }
                });
            }
        });
        assert_eq!(*most.lock().unwrap(), 60);
        assert_eq!(*gate.held.lock().unwrap(), 0);
    }

    #[test]
    fn structured_sse_equals_qr_fit_of_the_built_design() {
        // Identity: the moment route (rescaled onto the transformed inputs' own range) and the QR
        // fit of the explicitly built design minimise the same SSE — here with a leak large enough
        // to carry the volume far outside the baseline's [−1, 1], plus added columns.
        let prep = two_tones(3000);
        let lam = 2.0 * prep.scales.v_range / prep.scales.p_integral;
        for effects in [
            vec![Effect::new(EffectKind(&Leak), lam)],
            vec![
                Effect::new(EffectKind(&Hysteresis), 20.0),
                Effect::new(EffectKind(&Ripple), 0.27),
                Effect::new(EffectKind(&VolumeDrift), 3.0),
            ],
            vec![Effect::new(EffectKind(&OffsetDrift), 2.0)],
        ] {
            let d = build(&prep, &effects);
            let qr = lsq::fit(&d.cols, &prep.series.p, &prep.train_rows)
                .expect("full rank")
                .sse;
            let fast = sse_structured(&prep, &effects).unwrap();
            assert!((fast - qr).abs() < 1e-8 * qr, "{effects:?}: {fast} vs {qr}");
        }
        assert!(sse_structured(&prep, &[Effect::new(EffectKind(&SensorLag), 0.1)]).is_none());
    }

    #[test]
    fn the_streamed_lag_gives_the_built_designs_sse_to_the_bit() {
        // The searches' streamed route (the lag run block by block into the Gram sum) and the
        // built design (lagged in place, then summed) are the same arithmetic: equal bits, for
        // a lag on instants (Akima's slopes and the board's backward ones), alone and with
        // added columns and an input transform before it; with no such filter there is no
        // streamed route.
        let prep = two_tones(9000);
        let lam = 0.5 * prep.scales.v_range / prep.scales.p_integral;
        let lag = |point: bool, board: bool| Effect {
            point_sampled: point,
            board_form: board,
            ..Effect::new(EffectKind(&SensorLag), 0.15)
        };
        for (point, board) in [(true, false), (true, true)] {
            for mut effects in [
                vec![],
                vec![
                    Effect::new(EffectKind(&Hysteresis), 20.0),
                    Effect::new(EffectKind(&Leak), lam),
                ],
            ] {
                effects.push(lag(point, board));
                let d = build(&prep, &effects);
                let built = lsq::sse_fast(&d.cols, &prep.series.p, &prep.train_rows);
                let streamed = sse_lagged(&prep, &effects).expect("one lag between samples");
                assert_eq!(streamed.to_bits(), built.to_bits(), "{effects:?}");
            }
        }
        // On frame means the lag runs inside the frames: not streamed.
        assert!(sse_lagged(&prep, &[lag(false, false)]).is_none());
        assert!(sse_lagged(&prep, &[lag(false, true)]).is_none());
        assert!(sse_lagged(&prep, &[Effect::new(EffectKind(&Hysteresis), 20.0)]).is_none());
    }

    #[test]
    fn adding_columns_behind_the_filters_gives_the_built_designs_sse_to_the_bit() {
        // Every column runs through the output filters on its own, so the model's filtered design
        // with the candidate's columns filtered apart is the built design, column for column:
        // equal bits, behind a sensor lag inside the frames, on instants, and behind a sensor lag
        // and a leak-moved volume; a candidate that moves the inputs has no such route.
        let prep = two_tones(6000);
        let lam = 0.5 * prep.scales.v_range / prep.scales.p_integral;
        let lag = |point: bool| Effect {
            point_sampled: point,
            ..Effect::new(EffectKind(&SensorLag), 0.15)
        };
        for cur in [
            vec![lag(false)],
            vec![lag(true)],
            vec![Effect::new(EffectKind(&Leak), lam), lag(false)],
        ] {
            let base = filtered_base(&prep, &cur).expect("a filtered model");
            for cand in [
                Effect::new(EffectKind(&Hysteresis), 20.0),
                Effect::new(EffectKind(&Ripple), 0.27),
            ] {
                let effects = super::super::super::search::with(&cur, cand);
                let d = build(&prep, &effects);
                let built = lsq::sse_fast(&d.cols, &prep.series.p, &prep.train_rows);
                let apart = sse_adding_columns(&prep, &base, &effects).expect("adds columns only");
                assert_eq!(apart.to_bits(), built.to_bits(), "{effects:?}");
            }
            let moved =
                super::super::super::search::with(&cur, Effect::new(EffectKind(&VolumeDrift), 3.0));
            assert!(sse_adding_columns(&prep, &base, &moved).is_none());
        }
        assert!(filtered_base(&prep, &[Effect::new(EffectKind(&Hysteresis), 20.0)]).is_none());
    }

    #[test]
    fn a_lag_inside_the_frames_shorter_than_anything_is_the_design_itself() {
        // Identity: each column is rebuilt inside the frames with its frame means kept, so a lag
        // of 1 ns leaves the design (baseline and added columns) as built without it.
        let prep = two_tones(1500);
        let hyst = Effect::new(EffectKind(&Hysteresis), 20.0);
        let plain = build(&prep, std::slice::from_ref(&hyst));
        let lagged = build(&prep, &[hyst, Effect::new(EffectKind(&SensorLag), 1e-9)]);
        for (a, b) in plain.cols.iter().zip(&lagged.cols) {
            let scale = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() <= 1e-6 * scale, "{x} vs {y}");
            }
        }
    }
}
