//! The effect chain: the effects the host's residual loop (`sysid::residual`) adds to the
//! polynomial, in a causal, `f32`, allocation-free form the board evaluates once per frame.
//!
//! # Where each effect sits
//! A chain holds at most [`MAX_EFFECTS`] effects (one of each kind) and evaluates them around the
//! polynomial in the residual loop's order, whatever order they were added in:
//!
//! ```text
//! (v, v̇) ─ delivery lag ─ transport delay ─ backlash ─ leak ─ air (static) ─▶ (v′, v̇′)
//! P_in = P̂_poly(v′, v̇′) [+ AR terms] + hysteresis(v′) + inertance(v, v̇) + pump ripple(v, v̇)
//! P̂   = sensor lag( air lag( P_in ) )
//! ```
//!
//! `(v, v̇)` is the frame's logged volume (mm³) and flow (mm³/s), `p` its measured (zeroed)
//! pressure (kPa), `Δt` the frame period (s), `x = (v − v_offset)/v_scale` the polynomial's
//! scaled volume. Each effect, its parameters (in the order the protocol and the store carry
//! them) and its state:
//!
//! | effect | parameters | equation per frame k | state |
//! | --- | --- | --- | --- |
//! | `hysteresis` | w mm³ (> 0), H₀ kPa, H₁ kPa | on the chamber's volume v′ (the input transforms' output; v when there are none): `h_k = s + (h_{k−1} − s)·e^{−│v′_k − v′_{k−1}│/w}`, `s = sign(v′_k − v′_{k−1})` (unchanged when v′ is); `P_in += (H₀ + H₁·x′)·h_k`, x′ = (v′ − v_offset)/v_scale | h, v′_{k−1} |
//! | `sensor_lag` | τ s (≥ 0) | `τ Ṗ_m + P_m = P` over the cubic between frames whose slopes are the backward differences `m_k = d_k + ½(d_k − d_{k−1})`, `d_k = (P_k − P_{k−1})/Δt` (a frame mean's slope from the past only; the secant on the second frame, 0 on the first): `P̂_k = a P̂_{k−1} + w₀ P_{k−1} + w₁ P_k + Δt(m₀ m_{k−1} + m₁ m_k)` (weights below) | P̂_{k−1}, P_{k−1}, P_{k−2}, m_{k−1} |
//! | `delivery_lag` | τ s (≥ 0) | two stages of `τ ẏ + y = u` on v and on v̇; each stage: v by the cubic whose slopes are the flows, `y_k = a y_{k−1} + w₀ u_{k−1} + w₁ u_k + Δt(m₀ u̇_{k−1} + m₁ u̇_k)` (weights below), v̇ the same over the cubic whose slopes are the accelerations `ü_k = (−6(u_k − u_{k−1}) + 2Δt u̇_{k−1} + 4Δt u̇_k)/Δt²` (the end slope of the input volume's cubic over the frame: from the past only; 0 on the first frame) | per stage: output v, v̇, input v, v̇ and ü of the last frame |
//! | `transport_delay` | d s (0 ≤ d ≤ [`MAX_DELAY_FRAMES`] − 2 frames) | `(v′, v̇′)` at `t_k − d` on the cubic Hermite through the stored frames (slopes = flows), flow = that cubic's derivative; before the first frame: the first frame | the last [`MAX_DELAY_FRAMES`] frames of its input |
//! | `backlash` | b mm³ (≥ 0) | play operator `z ← clamp(z, x_j − b/2, x_j + b/2)` on the nut's motion inside the frame rebuilt from the frame alone, `x_j = v_k + v̇_k Δt((j + ½)/8 − ½)`, j = 0…7 (the frame's mean volume is a mean over its interval, and the dead band after a reversal lasts a fraction of it); `v′` = the mean of z over the eight, `v̇′ = g·v̇` with g the fraction of them at which the nut pushes the plunger (the clamp moves z in the direction of v̇) | z at the last sub-sample |
//! | `inertance` | L kPa·s²/mm³ | `P_in += L·v̈_k`, `v̈_k = (−6(v_k − v_{k−1}) + 2Δt v̇_{k−1} + 4Δt v̇_k)/Δt²` (the end slope of the last interval's cubic Hermite; 0 on the first frame) | v_{k−1}, v̇_{k−1} |
//! | `pump_ripple` | Λ mm³ (> 0), a mm³, b mm³ | volume error `δ = a sin φ + b cos φ`, `φ = 2π (v mod Λ)/Λ`, `δ̇ = (2π/Λ) v̇ (a cos φ − b sin φ)`; `P_in += k_poly δ + c_poly δ̇` | none |
//! | `air_compliance` | V_a mm³ (≥ 0) | static: `v′ −= V_a·p̃/(P_atm + p̃)`, `p̃ = max(p, −0.9 P_atm)` (Boyle); dynamic: `τ_k P_air' + P_air = P_in` with `τ_k = max(c_mid, 0)·x′(p̃)`, the gas spring `x′(p̃) = V_a·P_atm/(P_atm + p̃)²` and the damping at the flow midway between the pump's and the chamber's, `c_mid = ∂P_poly/∂v̇ (v′, v̇′ − ẋ/2)`, `ẋ = x′(p̃_k)·(p̃_k − p̃_{k−1})/Δt` the flow the pocket takes (the backward difference: 0 on the first frame; exact for a law g quadratic in flow, `g(v̇′ − ẋ) = g(v̇′) − g′(v̇′ − ẋ/2)·ẋ`, as the host's loop); over each frame the mean of its ends' τ, over the cubic with backward-difference slopes as `sensor_lag` (its weights computed per frame in f32) | P_air, P_in, P_in before, its slope, τ and p̃ of the last frame |
//! | `leak` | λ mm³/(kPa·s) (≥ 0) | `I_k = I_{k−1} + ½(p_k + p_{k−1})Δt` (trapezoid, `I_0 = 0`, summed with Kahan's compensation); `v′ −= λ I_k`, `v̇′ −= λ p_k` (the lost volume λI is the state) | I (and its compensation), p_{k−1} |
//!
//! `delivery_lag`'s cubic weights are the exact response of the lag over one frame to a cubic
//! Hermite input, with `r = Δt/τ` and `I_q = ∫₀¹ r e^{−r(1−s)} s^q ds` (`I_0 = 1 − e^{−r}`,
//! `I_q = 1 − (q/r) I_{q−1}`, by its power series when r < ½):
//!
//! ```text
//! a = e^{−r},  w₀ = 2I₃ − 3I₂ + I₀,  w₁ = 3I₂ − 2I₃,  m₀ = I₃ − 2I₂ + I₁,  m₁ = I₃ − I₂,
//! ```
//!
//! computed once in `f64` when the effect is added; the straight-line weights are the same with
//! both slopes equal to the secant, `(1 − a) − (1 − g) = w₀ − (m₀ + m₁)`, `1 − g = w₁ + m₀ + m₁`.
//! A time constant ≤ 10⁻⁹ Δt is no lag at all (output = input).
//!
//! # State and when it resets
//! The chain ([`Chain`]) is configuration: it travels with the model (protocol, flash, CRC). Its
//! state ([`ChainState`]) belongs to the estimator, which resets it ([`ChainState::reset`]) at
//! boot, at `origin` (the volume count restarts: every stored volume would be off) and when a
//! model is installed. The first frame after a reset starts every effect at rest on that frame
//! (lags output their input, h = 0, z = v, I = 0, the delay line holds the frame) and computes the
//! effects' per-frame constants (lag weights, the delay's split) for that frame's Δt, unless
//! [`ChainState::prepare`] computed them already (a state must then only see that chain and Δt). A frame whose
//! evaluation fails (out of the model's range, a non-finite measured pressure where leak or air
//! needs it) leaves the state as it was, as if the frame had not happened.
//!
//! # Effects the board cannot run
//! Effects tied to the log's own clock have no counterpart on the board: `ripple` (a sine in the
//! log's time, whose phase the board does not share), `offset_drift` (Legendre polynomials of the
//! time since the log began) and `volume_drift` (a volume error growing with that time). The
//! board's sensor zero is taken at boot and on `zero`, and its slow drift is followed at rest at
//! the zero's volume (`firmware::rest_zero`), not in the chain.
//!
//! # Stiffness and damping of the whole chain
//! [`ChainEval::k`] and [`ChainEval::c`] are the chain's quasi-static sensitivities `∂P̂/∂v`,
//! `∂P̂/∂v̇` at the frame: every lag and delay passes a slow change unchanged (gain 1), so only
//! the static maps count:
//!
//! ```text
//! k = g·k_poly/(1 + g·k_poly·V_a·P_atm/(P_atm + p̃)²) + k_hyst + k_ripple,   c = g·c_poly + c_ripple,
//! ```
//!
//! with `g` = 1, or with backlash the fraction of the frame in which the nut bears on the plunger
//! (0 in its dead band); the air term is the gas
//! spring in series with the chamber (`dv′/dv` when p is the pressure the model predicts); the
//! leak moves v′ by what the pressure did, not by v, so it leaves k and c alone;
//! `k_hyst = (H₁/v_scale)·h + (H₀ + H₁x)(1 − s h)/w` with `s = sign(v̇)` (the slope of the loop
//! along the direction of motion; at rest only the first term: the switching slope is one-sided
//! there); `k_ripple = k_poly w (a cos φ − b sin φ) − c_poly w² v̇ δ`, `c_ripple = c_poly w (a cos
//! φ − b sin φ)`, `w = 2π/Λ` (first order, the model's curvature left out); inertance acts only on
//! changes of flow and adds nothing. Without effects k and c are the polynomial's own.

use crate::error::{finite, ModelError};
use crate::poly::{ArHistory, PolyModel};

/// Most effects in one chamber's chain.
pub const MAX_EFFECTS: usize = 4;
/// Frames the transport delay keeps (the current one included): a delay of at most
/// `MAX_DELAY_FRAMES − 2` frame periods (1.52 s at 25 Hz).
pub const MAX_DELAY_FRAMES: usize = 40;
/// Longest transport delay a chain accepts, s (the residual loop searches up to 1.5 s); at frame
/// rates above 25.3 Hz the delay line is shorter than that and such a chain's frames fail with
/// `BadParameter`.
pub const MAX_DELAY_S: f32 = 1.5;
/// Most parameters of one effect.
pub const MAX_EFFECT_PARAMS: usize = 3;
/// Atmospheric pressure, kPa (the air pocket's isothermal reference).
pub const P_ATM_KPA: f32 = 101.325;

/// Declares [`EffectKind`] and [`EffectKind::ALL`] from one list, so that a new kind is in the
/// evaluation order by construction (the list's order is that order).
macro_rules! effect_kinds {
    ($(#[$m:meta])* pub enum EffectKind { $($(#[$vm:meta])* $v:ident,)+ }) => {
        $(#[$m])*
        pub enum EffectKind {
            $($(#[$vm])* $v,)+
        }

        impl EffectKind {
            /// Every kind, in the order they are evaluated (inputs, added terms, output
            /// filters): the order of the enum's declaration.
            pub const ALL: [EffectKind; [$(EffectKind::$v),+].len()] = [$(EffectKind::$v),+];
        }
    };
}

effect_kinds! {
    /// The effects the board can run, in their evaluation order; each has one row in the table
    /// of [`crate::spec`] (wire name, stored code, parameters with units and bounds, stage).
    #[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
    pub enum EffectKind {
        /// Volume and flow through a critically damped (two-stage) lag.
        DeliveryLag,
        /// Volume and flow delayed by a fixed time.
        TransportDelay,
        /// Play between lead-screw nut and plunger.
        Backlash,
        /// Volume lost at a rate proportional to pressure.
        Leak,
        /// Trapped air (Boyle's law) with its pressure-scheduled lag.
        AirCompliance,
        /// Rate-independent direction memory (Duhem hysteron) times a gap linear in volume.
        Hysteresis,
        /// Fluid inertance of the line, `L·v̈`.
        Inertance,
        /// Lead-screw pitch error, periodic in volume.
        PumpRipple,
        /// First-order lag of the pressure sensor.
        SensorLag,
    }
}

impl EffectKind {
    /// Position in [`ALL`](Self::ALL): the evaluation order. Not stored anywhere: a kind may
    /// move in the order without changing what a board has kept (that is [`code`](Self::code)).
    pub fn rank(self) -> u8 {
        Self::ALL.iter().position(|&k| k == self).unwrap_or(0) as u8
    }
}

/// One effect with checked parameters (module table; unused trailing parameters are 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Effect {
    kind: EffectKind,
    params: [f32; MAX_EFFECT_PARAMS],
}

impl Effect {
    /// A checked effect against its row of the table ([`EffectKind::spec`]): `BadLength`
    /// unless `params` has [`EffectKind::params`] values, `NonFinite` for NaN/∞,
    /// `BadParameter` for a value outside its range (a width or period ≤ 0; a negative time
    /// constant, delay, play, air volume or leak conductance; a delay over [`MAX_DELAY_S`]).
    pub fn new(kind: EffectKind, params: &[f32]) -> Result<Self, ModelError> {
        let spec = kind.spec();
        if params.len() != spec.params.len() {
            return Err(ModelError::BadLength);
        }
        if params.iter().any(|p| !p.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        if !spec.params.iter().zip(params).all(|(s, &x)| s.admits(x)) {
            return Err(ModelError::BadParameter);
        }
        let mut p = [0.0; MAX_EFFECT_PARAMS];
        p[..params.len()].copy_from_slice(params);
        Ok(Effect { kind, params: p })
    }

    /// Its kind.
    pub fn kind(&self) -> EffectKind {
        self.kind
    }

    /// Its parameters ([`EffectKind::params`] of them).
    pub fn params(&self) -> &[f32] {
        &self.params[..self.kind.params()]
    }
}

/// Per-frame constants of an effect, derived once from its parameters and the frame period.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
struct Derived {
    /// Lags: `a` in slot 0, the cubic weights `w₀, w₁, Δt·m₀, Δt·m₁` in slots 1–4 (delivery and
    /// sensor lag). Delay: the Hermite weights.
    w: [f32; 8],
    /// Transport delay: whole frames back to the interval's later end.
    n: u8,
}

/// Weights of the exact response of `τ ẏ + y = u` over one frame to a cubic Hermite input
/// (module docs): `[a, w₀, w₁, m₀, m₁]` in `f64`; no lag (`[0, 0, 1, 0, 0]`) when τ ≤ 10⁻⁹ Δt.
fn lag_weights(dt: f64, tau: f64) -> [f64; 5] {
    if tau <= 1e-9 * dt {
        return [0.0, 0.0, 1.0, 0.0, 0.0];
    }
    let r = dt / tau;
    let mut i = [0.0f64; 4];
    if r >= 0.5 {
        i[0] = -libm::expm1(-r);
        for q in 1..4 {
            i[q] = 1.0 - (q as f64 / r) * i[q - 1];
        }
    } else {
        // I_q = r Σ_j (−r)^j q!/(q + j + 1)!: alternating, terms shrink at least ×4 per step.
        for (q, iq) in i.iter_mut().enumerate() {
            let mut term = r / (q as f64 + 1.0);
            let mut sum = 0.0;
            for j in 0..40 {
                sum += term;
                if libm::fabs(term) <= 1e-17 * libm::fabs(sum) {
                    break;
                }
                term *= -r / (q as f64 + j as f64 + 2.0);
            }
            *iq = sum;
        }
    }
    [
        libm::exp(-r),
        2.0 * i[3] - 3.0 * i[2] + i[0],
        3.0 * i[2] - 2.0 * i[3],
        i[3] - 2.0 * i[2] + i[1],
        i[3] - i[2],
    ]
}

/// Sub-samples of a frame at which backlash runs its play operator.
pub const PLAY_SUBSAMPLES: usize = 8;

/// What the play operator made of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlayFrame {
    /// The plunger at the frame's last sub-sample (the state).
    pub z: f32,
    /// The plunger's mean over the frame.
    pub v: f32,
    /// Fraction of the sub-samples at which the nut bears on the plunger.
    pub engaged: f32,
}

/// Backlash on one frame: the nut's motion inside the frame is rebuilt from the frame's own
/// mean volume `v` and flow `f` alone (causal), `x_j = v + f·Δt·((j + ½)/8 − ½)` at
/// [`PLAY_SUBSAMPLES`] instants centred on the frame, the play operator
/// `z ← clamp(z, x_j − h, x_j + h)` runs over them from the last frame's `z` (from `x₀` on the
/// first frame), and the plunger's mean and the engaged fraction (the sub-samples at which the
/// clamp moves z along the flow's direction: the nut pushes the plunger) come out. `h = 0` is no play (the frame passes unchanged).
/// The host's form of the board's backlash (`sysid`'s `play_frame_linear`) calls this same
/// function, so that the two decide each sub-sample's engagement alike: in f64 a nut that
/// reaches the band's edge within f32's resolution of a sub-sample would engage there, and
/// the board's would not. Inlined as it was when private: made public without it, the firmware's
/// `frame` rose 3,948 → 4,199 instructions and `frame_chain` 6,549 → 6,818 (`cargo fw-bench`).
#[inline]
pub fn play_frame(z: f32, primed: bool, v: f32, f: f32, dt: f32, h: f32) -> PlayFrame {
    if h == 0.0 {
        return PlayFrame {
            z: v,
            v,
            engaged: 1.0,
        };
    }
    let n = PLAY_SUBSAMPLES as f32;
    let x = |j: usize| v + f * dt * ((j as f32 + 0.5) / n - 0.5);
    let mut z = if primed { z } else { x(0) };
    let (mut sum, mut engaged) = (0.0f32, 0u32);
    for j in 0..PLAY_SUBSAMPLES {
        let xj = x(j);
        let before = z;
        z = z.clamp(xj - h, xj + h);
        // The nut bears on the plunger when it pushes it along its own motion (an exact
        // comparison: no tolerance window where f32 and f64 could decide differently).
        if (z - before) * f > 0.0 {
            engaged += 1;
        }
        sum += z;
    }
    PlayFrame {
        z,
        v: sum / n,
        engaged: engaged as f32 / n,
    }
}

/// The transport delay's split `d = (n + 1 − s)·Δt` and the cubic Hermite weights at `s` of the
/// interval from frame `k − n − 1` to `k − n`: value `[h00, h10·Δt, h01, h11·Δt]`, flow
/// `[6(s² − s)/Δt, 3s² − 4s + 1, 6(s − s²)/Δt, 3s² − 2s]` on `(v_j, v̇_j, v_{j+1}, v̇_{j+1})`.
fn delay_weights(dt: f32, d: f32) -> Derived {
    let frames = (d as f64) / (dt as f64);
    let whole = libm::floor(frames);
    let (n, s) = if frames - whole < 1e-6 {
        // On a frame: the later end itself (s = 1).
        (whole as u8, 1.0f64)
    } else {
        (whole as u8, 1.0 - (frames - whole))
    };
    let h = dt as f64;
    let (s2, s3) = (s * s, s * s * s);
    let w = [
        2.0 * s3 - 3.0 * s2 + 1.0,
        (s3 - 2.0 * s2 + s) * h,
        -2.0 * s3 + 3.0 * s2,
        (s3 - s2) * h,
        6.0 * (s2 - s) / h,
        3.0 * s2 - 4.0 * s + 1.0,
        6.0 * (s - s2) / h,
        3.0 * s2 - 2.0 * s,
    ];
    Derived {
        w: w.map(|x| x as f32),
        n,
    }
}

impl Derived {
    fn of(e: &Effect, dt: f32) -> Self {
        let (dtf, p0) = (dt as f64, e.params[0] as f64);
        let mut w = [0.0f32; 8];
        match e.kind {
            EffectKind::SensorLag => {
                // The cubic whose slopes are the backward three-point differences.
                let [a, w0, w1, m0, m1] = lag_weights(dtf, p0);
                w = [a, w0, w1, m0 * dtf, m1 * dtf, 0.0, 0.0, 0.0].map(|x| x as f32);
            }
            EffectKind::DeliveryLag => {
                let [a, w0, w1, m0, m1] = lag_weights(dtf, p0);
                w = [a, w0, w1, m0 * dtf, m1 * dtf, 0.0, 0.0, 0.0].map(|x| x as f32);
            }
            EffectKind::TransportDelay => return delay_weights(dt, e.params[0]),
            // No per-frame constants.
            EffectKind::Hysteresis
            | EffectKind::Backlash
            | EffectKind::Inertance
            | EffectKind::PumpRipple
            | EffectKind::AirCompliance
            | EffectKind::Leak => {}
        }
        Derived { w, n: 0 }
    }
}

/// A chamber's effect chain (configuration, see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chain {
    len: u8,
    effects: [Effect; MAX_EFFECTS],
}

/// Inputs of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ChainInput {
    /// Volume, mm³.
    pub v: f32,
    /// Flow, mm³/s.
    pub vdot: f32,
    /// Measured (zeroed) pressure, kPa; only leak and air compliance read it.
    pub p: f32,
    /// Frame period Δt, s (> 0; the same for every frame between two resets).
    pub dt: f32,
}

/// What the chain predicts for one frame.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ChainEval {
    /// P̂ of the whole chain, kPa.
    pub p: f32,
    /// Quasi-static stiffness ∂P̂/∂v of the chain, kPa/mm³ (module docs).
    pub k: f32,
    /// Quasi-static damping ∂P̂/∂v̇ of the chain, kPa·s/mm³ (module docs).
    pub c: f32,
    /// The polynomial's own prediction at the transformed inputs, kPa.
    pub p_poly: f32,
    /// The volume the polynomial saw, v′ (mm³).
    pub v_in: f32,
    /// The flow the polynomial saw, v̇′ (mm³/s).
    pub vdot_in: f32,
}

/// The chain's state (module docs: what resets it and when).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChainState {
    primed: bool,
    /// `derived` holds the constants for this state's chain (set by [`ChainState::prepare`]).
    prepared: bool,
    /// Per-frame constants of each effect for the frame period, computed on the first frame.
    derived: [Derived; MAX_EFFECTS],
    slot: [[f32; 8]; MAX_EFFECTS],
    ring: [(f32, f32); MAX_DELAY_FRAMES],
    head: u8,
    held: u8,
}

impl Default for Chain {
    fn default() -> Self {
        Self::new()
    }
}

impl Default for ChainState {
    fn default() -> Self {
        Self::new()
    }
}

impl ChainState {
    /// At rest: the next frame starts every effect.
    pub const fn new() -> Self {
        ChainState {
            primed: false,
            prepared: false,
            derived: [Derived { w: [0.0; 8], n: 0 }; MAX_EFFECTS],
            slot: [[0.0; 8]; MAX_EFFECTS],
            ring: [(0.0, 0.0); MAX_DELAY_FRAMES],
            head: 0,
            held: 0,
        }
    }

    /// Forget everything (boot, `origin`, model load).
    pub fn reset(&mut self) {
        *self = ChainState::new();
    }

    /// Computes `chain`'s per-frame constants for frames `dt` apart now, so that the first frame
    /// after a reset costs no more than the others (the board calls it where it resets, outside
    /// the frame). Errors as [`Chain::eval`] for a bad `dt`; the state stays unprepared then.
    pub fn prepare(&mut self, chain: &Chain, dt: f32) -> Result<(), ModelError> {
        self.derived = chain.derive(dt)?;
        self.prepared = true;
        Ok(())
    }

    /// Whether a frame has been evaluated since the last reset.
    pub fn primed(&self) -> bool {
        self.primed
    }

    /// The stored frame `back` frames before the newest (0 = newest, `back` < held).
    fn ring_get(&self, back: usize) -> (f32, f32) {
        self.ring[(self.head as usize + MAX_DELAY_FRAMES - back) % MAX_DELAY_FRAMES]
    }

    fn ring_push(&mut self, x: (f32, f32)) {
        self.head = ((self.head as usize + 1) % MAX_DELAY_FRAMES) as u8;
        self.ring[self.head as usize] = x;
        self.held = (self.held + 1).min(MAX_DELAY_FRAMES as u8);
    }
}

/// The sensor lag's step (module table): the lag of the cubic through the last two inputs whose
/// slopes are the backward differences `m_k = d_k + ½(d_k − d_{k−1})`, `d_k = (x_k − x_{k−1})/Δt`
/// (the secant while only one earlier input is known, 0 on the first frame: at rest). State:
/// `[y, x_{k−1}, x_{k−2}, m_{k−1}, inputs seen (0, 1, 2)]`.
fn sensor_lag(w: &[f32; 8], s: &mut [f32; 8], primed: bool, dt: f32, x: f32) -> f32 {
    if !primed {
        *s = [x, x, x, 0.0, 1.0, 0.0, 0.0, 0.0];
        return x;
    }
    let d = (x - s[1]) / dt;
    let m = if s[4] >= 2.0 {
        d + 0.5 * (d - (s[1] - s[2]) / dt)
    } else {
        d
    };
    let y = lag_step(w, s[0], s[1], x, s[3], m);
    // Slots 5 and 6 belong to `Chain::load_pressure`.
    *s = [y, x, s[1], m, 2.0, s[5], s[6], 0.0];
    y
}

impl Chain {
    /// An empty chain.
    pub const fn new() -> Self {
        Chain {
            len: 0,
            effects: [Effect {
                kind: EffectKind::Hysteresis,
                params: [1.0, 0.0, 0.0],
            }; MAX_EFFECTS],
        }
    }

    /// The effects, in evaluation order.
    pub fn effects(&self) -> &[Effect] {
        &self.effects[..self.len as usize]
    }

    /// Number of effects.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    /// True without effects (then [`eval`](Self::eval) is the bare polynomial).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Adds an effect in its place in the evaluation order: `BadLength` when the chain is full,
    /// `BadParameter` when it already has one of that kind (its parameters were checked by
    /// [`Effect::new`], a transport delay's against [`MAX_DELAY_S`] among them).
    pub fn push(&mut self, e: Effect) -> Result<(), ModelError> {
        let len = self.len as usize;
        if self.effects().iter().any(|x| x.kind == e.kind) {
            return Err(ModelError::BadParameter);
        }
        if len == MAX_EFFECTS {
            return Err(ModelError::BadLength);
        }
        let at = self
            .effects()
            .iter()
            .position(|x| x.kind.rank() > e.kind.rank())
            .unwrap_or(len);
        for i in (at..len).rev() {
            self.effects[i + 1] = self.effects[i];
        }
        self.effects[at] = e;
        self.len += 1;
        Ok(())
    }

    /// Removes every effect.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Evaluates one frame (module docs), advancing `state` only when it succeeds. `hist` is the
    /// polynomial's AR history of previous *transformed* inputs ([`ChainEval::v_in`]).
    ///
    /// Errors: the polynomial's (`NonFinite`, `OutOfRange`, `ShortHistory`) at the transformed
    /// inputs; `NonFinite` when leak or air compliance meets a non-finite measured pressure;
    /// `BadParameter` for a frame period that is not finite and > 0 or too short for the delay.
    ///
    /// The state belongs to this chain: reset it whenever the chain changes.
    pub fn eval(
        &self,
        model: &PolyModel,
        hist: &ArHistory,
        state: &mut ChainState,
        inp: ChainInput,
    ) -> Result<ChainEval, ModelError> {
        if self.len == 0 {
            // No effects: the bare polynomial (nothing to remember).
            let e = if model.shape().p == 0 {
                model.eval(inp.v, inp.vdot)?
            } else {
                model.eval_ar(inp.v, inp.vdot, hist)?
            };
            return Ok(ChainEval {
                p: e.p,
                k: e.k,
                c: e.c,
                p_poly: e.p,
                v_in: inp.v,
                vdot_in: inp.vdot,
            });
        }
        // A frame's own motion must be finite even where the output only reads earlier frames
        // (a transport delay): a non-finite one is an error, not a frame that happened.
        if !(inp.v.is_finite() && inp.vdot.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        if !state.primed && !state.prepared {
            state.derived = self.derive(inp.dt)?;
        }
        let mut slot = state.slot;
        let primed = state.primed;
        let (v_in, f_in, gain) = self.inputs(state, &mut slot, inp)?;
        // The air pocket (its pressure checked finite by `inputs`): the gas spring
        // x'(p̃) = V_a·P_atm/(P_atm + p̃)² and the flow it takes, ẋ = x'(p̃)·Ṗ, Ṗ the backward
        // difference of p̃ over the frame (0 on the first frame).
        let air = self.position(EffectKind::AirCompliance).map(|i| {
            let pt = inp.p.max(-0.9 * P_ATM_KPA);
            let spring =
                self.effects[i].params[0] * P_ATM_KPA / ((P_ATM_KPA + pt) * (P_ATM_KPA + pt));
            let pdot = if primed {
                (pt - slot[i][6]) / inp.dt
            } else {
                0.0
            };
            (i, pt, spring, spring * pdot)
        });
        // The polynomial at the chamber's inputs and, for the air lag, its damping at the flow
        // midway between the pump's and the chamber's, `v̇′ − ẋ/2`.
        let (e, c_air) = match air {
            Some((.., xdot)) => {
                let (mut e, c_mid) = model.eval_damping_at(v_in, f_in, 0.5 * xdot)?;
                if model.shape().p != 0 {
                    e.p = finite(e.p + model.ar_sum(hist)?)?;
                }
                (e, c_mid)
            }
            None if model.shape().p == 0 => (model.eval(v_in, f_in)?, 0.0),
            None => (model.eval_ar(v_in, f_in, hist)?, 0.0),
        };
        let (mut p, mut k, c) = self.added(&mut slot, primed, inp, model, e, (v_in, f_in, gain));
        let mut k_air = 0.0f32;
        // The output filters, after every added term, in the chain's order: air's lag, then
        // the sensor's.
        for (i, eff) in self.effects().iter().enumerate() {
            match eff.kind {
                EffectKind::AirCompliance => {
                    if let Some((_, pt, spring, _)) = air {
                        k_air = spring;
                        let tau = c_air.max(0.0) * spring;
                        p = self.air_lag(&mut slot[i], primed, inp.dt, tau, p, pt);
                    }
                }
                EffectKind::SensorLag => {
                    p = sensor_lag(&state.derived[i].w, &mut slot[i], primed, inp.dt, p);
                }
                // No output filter.
                EffectKind::DeliveryLag
                | EffectKind::TransportDelay
                | EffectKind::Backlash
                | EffectKind::Leak
                | EffectKind::Hysteresis
                | EffectKind::Inertance
                | EffectKind::PumpRipple => {}
            }
        }
        if k_air != 0.0 {
            // The gas spring in series with the chamber's own stiffness.
            let kc = gain * e.k;
            k += kc / (1.0 + kc * k_air) - kc;
        }
        let out = ChainEval {
            p: finite(p)?,
            k: finite(k)?,
            c: finite(c)?,
            p_poly: e.p,
            v_in,
            vdot_in: f_in,
        };
        state.slot = slot;
        state.primed = true;
        if let Some(i) = self.position(EffectKind::TransportDelay) {
            state.ring_push((slot[i][0], slot[i][1]));
        }
        Ok(out)
    }

    /// The added terms (hysteresis, inertance, pump ripple) on the polynomial's `e`:
    /// `(P_in, k, c)` before the output filters. `(v′, v̇′, gain)`: the transformed inputs and
    /// `∂v′/∂v`; the hysteron switches on the chamber's volume v′.
    fn added(
        &self,
        slot: &mut [[f32; 8]; MAX_EFFECTS],
        primed: bool,
        inp: ChainInput,
        model: &PolyModel,
        e: crate::poly::Eval,
        (v_in, f_in, gain): (f32, f32, f32),
    ) -> (f32, f32, f32) {
        let (mut p, mut k, mut c) = (e.p, gain * e.k, gain * e.c);
        let chamber = ChainInput {
            v: v_in,
            vdot: f_in,
            ..inp
        };
        for (i, eff) in self.effects().iter().enumerate() {
            let s = &mut slot[i];
            let [p0, p1, p2] = eff.params;
            match eff.kind {
                EffectKind::Hysteresis => {
                    let (dp, dk) = hysteresis(s, primed, chamber, (p0, p1, p2), model);
                    p += dp;
                    k += gain * dk;
                }
                EffectKind::Inertance => {
                    let dt = inp.dt;
                    let acc = if primed {
                        end_accel(dt, s[0], s[1], inp.v, inp.vdot)
                    } else {
                        0.0
                    };
                    (s[0], s[1]) = (inp.v, inp.vdot);
                    p += p0 * acc;
                }
                EffectKind::PumpRipple => {
                    let (dp, dk, dc) = ripple(inp, (p0, p1, p2), e.k, e.c);
                    p += dp;
                    k += dk;
                    c += dc;
                }
                // Input transforms and output filters: no added term.
                EffectKind::DeliveryLag
                | EffectKind::TransportDelay
                | EffectKind::Backlash
                | EffectKind::Leak
                | EffectKind::AirCompliance
                | EffectKind::SensorLag => {}
            }
        }
        (p, k, c)
    }

    /// Every effect's per-frame constants for frames `dt` apart.
    fn derive(&self, dt: f32) -> Result<[Derived; MAX_EFFECTS], ModelError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(ModelError::BadParameter);
        }
        let mut d = [Derived::default(); MAX_EFFECTS];
        for (i, e) in self.effects().iter().enumerate() {
            if e.kind == EffectKind::TransportDelay
                && e.params[0] as f64 > (MAX_DELAY_FRAMES - 2) as f64 * dt as f64
            {
                return Err(ModelError::BadParameter);
            }
            d[i] = Derived::of(e, dt);
        }
        Ok(d)
    }

    /// The pressure of an external load on the chamber from this frame's residual
    /// `r = P − P̂` (kPa). The load's pressure reaches the sensor through the same lag as the
    /// chamber's own, so with a `sensor_lag` of τ the residual is the load's pressure lagged,
    /// and undoing the lag to first order gives
    ///
    /// ```text
    /// load_k = r_k + τ·(r_k − r_{k−1})/Δt
    /// ```
    ///
    /// (r alone on the first frame after a reset or after a frame without a residual). The
    /// difference multiplies the residual's noise by about √(1 + 2(τ/Δt)²): 3.7 at τ = 0.1 s and
    /// 25 Hz, the price of a force that is not late. Without a sensor lag: r. A non-finite r gives
    /// NaN, and the next frame starts over. Call it once per frame, after [`Chain::eval`], with
    /// the same state (slots 5 and 6 of the sensor lag's).
    pub fn load_pressure(&self, state: &mut ChainState, residual: f32, dt: f32) -> f32 {
        let Some(i) = self.position(EffectKind::SensorLag) else {
            return residual;
        };
        let tau = self.effects()[i].params[0];
        let s = &mut state.slot[i];
        if !residual.is_finite() {
            s[6] = 0.0;
            return f32::NAN;
        }
        let load = if s[6] > 0.0 {
            residual + tau * (residual - s[5]) / dt
        } else {
            residual
        };
        (s[5], s[6]) = (residual, 1.0);
        load
    }

    fn position(&self, kind: EffectKind) -> Option<usize> {
        self.effects().iter().position(|e| e.kind == kind)
    }

    /// The input transforms in order: `(v′, v̇′, g)`, g = 0 in backlash's dead band, else 1.
    fn inputs(
        &self,
        state: &ChainState,
        slot: &mut [[f32; 8]; MAX_EFFECTS],
        inp: ChainInput,
    ) -> Result<(f32, f32, f32), ModelError> {
        let (mut v, mut f, mut gain) = (inp.v, inp.vdot, 1.0f32);
        let primed = state.primed;
        for (i, eff) in self.effects().iter().enumerate() {
            let s = &mut slot[i];
            let p0 = eff.params[0];
            match eff.kind {
                EffectKind::DeliveryLag => {
                    (v, f) = delivery(&state.derived[i].w, s, primed, inp.dt, v, f)
                }
                EffectKind::TransportDelay => {
                    // The delay line stores what enters the delay (after a delivery lag).
                    (s[0], s[1]) = (v, f);
                    (v, f) = self.delayed(i, state, v, f);
                }
                EffectKind::Backlash => {
                    let out = play_frame(s[0], primed, v, f, inp.dt, 0.5 * p0);
                    (s[0], v, f, gain) = (out.z, out.v, f * out.engaged, gain * out.engaged);
                }
                EffectKind::Leak => {
                    let p = finite(inp.p)?;
                    let integral = if primed {
                        kahan_add(s, 0.5 * (p + s[1]) * inp.dt)
                    } else {
                        (s[0], s[2]) = (0.0, 0.0);
                        0.0
                    };
                    s[1] = p;
                    v -= p0 * integral;
                    f -= p0 * p;
                }
                EffectKind::AirCompliance => {
                    let pt = finite(inp.p)?.max(-0.9 * P_ATM_KPA);
                    v -= p0 * pt / (P_ATM_KPA + pt);
                }
                // Added terms and output filters: no input transform.
                EffectKind::Hysteresis
                | EffectKind::Inertance
                | EffectKind::PumpRipple
                | EffectKind::SensorLag => {}
            }
        }
        Ok((v, f, gain))
    }

    /// Transport delay on the stored frames (the current one not yet pushed): the interval from
    /// frame k − n − 1 to k − n, or the first frame since the reset when that interval starts
    /// before it.
    fn delayed(&self, i: usize, state: &ChainState, v: f32, f: f32) -> (f32, f32) {
        let d = &state.derived[i];
        let n = d.n as usize;
        let held = state.held as usize;
        if n + 1 > held {
            return if held == 0 {
                (v, f)
            } else {
                state.ring_get(held - 1)
            };
        }
        let later = if n == 0 {
            (v, f)
        } else {
            state.ring_get(n - 1)
        };
        let earlier = state.ring_get(n);
        let w = &d.w;
        // In difference form (h00 = 1 − h01, and the flow's volume weights are ∓ the same): the
        // volumes' difference is exact in f32 where the two weighted volumes, each of the size of
        // the stroke, would round to about 10⁻⁴ of a small model's range.
        let dv = later.0 - earlier.0;
        (
            earlier.0 + w[2] * dv + w[1] * earlier.1 + w[3] * later.1,
            w[6] * dv + w[5] * earlier.1 + w[7] * later.1,
        )
    }

    /// Air compliance's output lag, time constant τ(p) averaged over the frame's ends, over the
    /// cubic with backward-difference slopes (as `sensor_lag`), its weights computed per frame
    /// ([`lag_weights_f32`]). Slots: 0 output, 1 input, 2 τ of the last frame, 3 the input
    /// before, 4 its slope, 5 inputs seen (1, 2), 6 the frame's clamped measured pressure `pt`
    /// (the next frame's backward difference Ṗ), 7 unused.
    fn air_lag(&self, s: &mut [f32; 8], primed: bool, dt: f32, tau: f32, x: f32, pt: f32) -> f32 {
        if !primed {
            *s = [x, x, tau, x, 0.0, 1.0, pt, 0.0];
            return x;
        }
        let d = (x - s[1]) / dt;
        let m = if s[5] >= 2.0 {
            d + 0.5 * (d - (s[1] - s[3]) / dt)
        } else {
            d
        };
        let [a, w0, w1, m0, m1] = lag_weights_f32(dt, 0.5 * (tau + s[2]));
        let y = a * s[0] + w0 * s[1] + w1 * x + dt * (m0 * s[4] + m1 * m);
        *s = [y, x, tau, s[1], m, 2.0, pt, 0.0];
        y
    }
}

/// [`lag_weights`] in `f32`, for a time constant that changes every frame (air compliance):
/// `I_q` by its power series while r < 2 (at most 24 terms, each at most half the last), by the
/// recurrence above (whose error grows by at most q/r ≤ 1.5 per step).
fn lag_weights_f32(dt: f32, tau: f32) -> [f32; 5] {
    if tau <= 1e-9 * dt {
        return [0.0, 0.0, 1.0, 0.0, 0.0];
    }
    let r = dt / tau;
    let mut i = [0.0f32; 4];
    if r >= 2.0 {
        i[0] = -libm::expm1f(-r);
        for q in 1..4 {
            i[q] = 1.0 - (q as f32 / r) * i[q - 1];
        }
    } else {
        for (q, iq) in i.iter_mut().enumerate() {
            let mut term = r / (q as f32 + 1.0);
            let mut sum = 0.0f32;
            for j in 0..24 {
                sum += term;
                if libm::fabsf(term) <= 1e-8 * libm::fabsf(sum) {
                    break;
                }
                term *= -r / (q as f32 + j as f32 + 2.0);
            }
            *iq = sum;
        }
    }
    [
        libm::expf(-r),
        2.0 * i[3] - 3.0 * i[2] + i[0],
        3.0 * i[2] - 2.0 * i[3],
        i[3] - 2.0 * i[2] + i[1],
        i[3] - i[2],
    ]
}

/// One step of a first-order lag over the cubic between frames, with the weights `[a, w₀, w₁,
/// Δt·m₀, Δt·m₁]` of [`lag_weights`] in `w[..5]`: `y = a y₀ + w₀ x₀ + w₁ x₁ + Δt(m₀ ẋ₀ + m₁ ẋ₁)`.
#[inline]
fn lag_step(w: &[f32; 8], y0: f32, x0: f32, x1: f32, d0: f32, d1: f32) -> f32 {
    w[0] * y0 + w[1] * x0 + w[2] * x1 + w[3] * d0 + w[4] * d1
}

/// The acceleration at the end of a frame interval: the end slope of the cubic Hermite through
/// `(v₀, v̇₀)` and `(v₁, v̇₁)` over `dt`, `(−6(v₁ − v₀) + 2Δt v̇₀ + 4Δt v̇₁)/Δt²`.
fn end_accel(dt: f32, v0: f32, f0: f32, v1: f32, f1: f32) -> f32 {
    (-6.0 * (v1 - v0) + 2.0 * dt * f0 + 4.0 * dt * f1) / (dt * dt)
}

/// Delivery lag: two stages, each lagging v over the cubic whose slopes are the flows, and v̇
/// over the cubic whose slopes are the accelerations at the frames, each the end slope of the
/// stage input's volume cubic over the last frame ([`end_accel`]; causal).
/// Slots: 0, 1 stage-one output v, v̇; 2, 3 stage-two output; 4, 5 the raw input last frame;
/// 6, 7 each stage's input acceleration last frame.
fn delivery(w: &[f32; 8], s: &mut [f32; 8], primed: bool, dt: f32, v: f32, f: f32) -> (f32, f32) {
    if !primed {
        *s = [v, f, v, f, v, f, 0.0, 0.0];
        return (v, f);
    }
    let (mut xv, mut xf) = (v, f);
    let (mut pv, mut pf) = (s[4], s[5]);
    (s[4], s[5]) = (v, f);
    for st in 0..2 {
        let (yv, yf) = (s[2 * st], s[2 * st + 1]);
        let acc = end_accel(dt, pv, pf, xv, xf);
        let before = s[6 + st];
        s[6 + st] = acc;
        let nv = lag_step(w, yv, pv, xv, pf, xf);
        let nf = lag_step(w, yf, pf, xf, before, acc);
        // The next stage's previous input is this stage's previous output.
        (pv, pf) = (yv, yf);
        (s[2 * st], s[2 * st + 1]) = (nv, nf);
        (xv, xf) = (nv, nf);
    }
    (xv, xf)
}

/// Adds `x` to the running sum in slot 0 with Kahan's compensation in slot 2 (the leak's
/// integral grows for as long as the chamber is pressurised; a plain `f32` sum would lose the
/// small increments to rounding), returning the new sum.
fn kahan_add(s: &mut [f32; 8], x: f32) -> f32 {
    let y = x - s[2];
    let t = s[0] + y;
    s[2] = (t - s[0]) - y;
    s[0] = t;
    t
}

/// Hysteresis: `(ΔP, Δk)`; slots 0 h, 1 last volume.
fn hysteresis(
    s: &mut [f32; 8],
    primed: bool,
    inp: ChainInput,
    (w, h0, h1): (f32, f32, f32),
    model: &PolyModel,
) -> (f32, f32) {
    let (mut h, prev) = if primed { (s[0], s[1]) } else { (0.0, inp.v) };
    let dv = inp.v - prev;
    if dv != 0.0 {
        let sg = if dv > 0.0 { 1.0 } else { -1.0 };
        h = sg + (h - sg) * libm::expf(-libm::fabsf(dv) / w);
    }
    (s[0], s[1]) = (h, inp.v);
    let sc = model.scaling();
    let x = (inp.v - sc.v_offset) / sc.v_scale;
    let gap = h0 + h1 * x;
    let dir = if inp.vdot > 0.0 {
        1.0
    } else if inp.vdot < 0.0 {
        -1.0
    } else {
        0.0
    };
    let slope = if dir == 0.0 {
        0.0
    } else {
        gap * (1.0 - dir * h) / w
    };
    (gap * h, h1 / sc.v_scale * h + slope)
}

/// Pump ripple: `(ΔP, Δk, Δc)` from the polynomial's stiffness `k` and damping `c`.
fn ripple(inp: ChainInput, (lambda, a, b): (f32, f32, f32), k: f32, c: f32) -> (f32, f32, f32) {
    let w = core::f32::consts::TAU / lambda;
    let phase = w * libm::fmodf(inp.v, lambda);
    let (sin, cos) = (libm::sinf(phase), libm::cosf(phase));
    let delta = a * sin + b * cos;
    let dd = w * (a * cos - b * sin);
    (
        k * delta + c * inp.vdot * dd,
        k * dd - c * w * w * inp.vdot * delta,
        c * dd,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lag_weights_identities() {
        for (dt, tau) in [
            (0.04, 0.0801),
            (0.04, 0.08),
            (0.04, 0.3),
            (0.04, 0.005),
            (0.04, 5.0),
        ] {
            let [a, w0, w1, m0, m1] = lag_weights(dt, tau);
            let r = dt / tau;
            assert!((a - (-r).exp()).abs() < 1e-15);
            // A constant input passes unchanged: a + w₀ + w₁ = 1 (the Hermite basis sums to 1).
            assert!((a + w0 + w1 - 1.0).abs() < 1e-12, "{r}");
            // Secant slopes give the straight line's closed form: g − a and 1 − g.
            let g = (tau / dt) * (1.0 - a);
            assert!((w0 - (m0 + m1) - (g - a)).abs() < 1e-12, "{r}");
            assert!((w1 + (m0 + m1) - (1.0 - g)).abs() < 1e-12, "{r}");
        }
        // The f32 weights the air lag computes per frame are the f64 ones to f32 precision.
        for tau in [0.002, 0.01, 0.02, 0.05, 0.3, 5.0, 100.0] {
            let x = lag_weights(0.04, tau);
            let y = lag_weights_f32(0.04, tau as f32);
            for (a, b) in x.iter().zip(&y) {
                assert!(
                    (a - *b as f64).abs() <= 2e-6 * x[0].max(x[2]),
                    "{tau}: {x:?} {y:?}"
                );
            }
        }
        // Series (r < ½) and recurrence (r ≥ ½) agree at the switch.
        let (x, y) = (lag_weights(0.04, 0.04 / 0.4999999), lag_weights(0.04, 0.08));
        for q in 0..5 {
            assert!((x[q] - y[q]).abs() < 1e-6, "{q}");
        }
        assert_eq!(lag_weights(0.04, 0.0), [0.0, 0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn delay_on_a_frame_is_that_frame() {
        // d = 3Δt: the later end is frame k − 3 itself (value weight 1, flow weight 1).
        let d = delay_weights(0.04, 0.12);
        assert_eq!(d.n, 3);
        assert!((d.w[2] - 1.0).abs() < 1e-6 && d.w[0].abs() < 1e-6 && d.w[7] > 0.999);
    }
}
