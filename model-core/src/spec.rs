//! One specification per device effect: the single table both ends of the board's seam read.
//!
//! Each kind of [`EffectKind`] has one row ([`EffectKind::spec`], an exhaustive `match` without
//! a wildcard arm): its wire name (the protocol's `model <ch> effect <name> <param>…` and the
//! residual loop's effect of the same name), its stored code in a committed model
//! (`firmware::store`), where it acts in the chain ([`Stage`]), and its parameters in the order
//! the protocol and the store carry them, each with its name, unit and admissible range.
//! [`EffectKind::name`], [`EffectKind::from_name`], [`EffectKind::code`],
//! [`EffectKind::from_code`], [`EffectKind::params`] and the checks of
//! [`Effect::new`](crate::chain::Effect::new) (which the firmware's `model <ch> effect` and its
//! store's decoder call) all read it; the host's export takes the units of what it carries from
//! it.
//!
//! # Stored codes are forever
//! A board keeps its committed models across firmware updates, so the code of a kind never
//! changes and is never reused, not even after a kind is removed (its code then stays
//! reserved). A new kind takes the next free code ([`NEXT_FREE_CODE`]). The codes are not the
//! evaluation order ([`EffectKind::ALL`]): a kind may move in that order without touching what a
//! board has stored. The first nine codes are the ranks the evaluation order had when codes were
//! split from it, so stores written before decode as they were. `stored_effect_codes_never_change`
//! (`model-core/tests/chain.rs`) pins every code and every parameter layout.
//!
//! # Adding a device effect
//! A variant of [`EffectKind`] (its place in the declaration is its place in the evaluation
//! order, [`EffectKind::ALL`]), its row here (the compiler asks for it: the match has no
//! wildcard arm), its evaluation in `chain.rs` (the evaluation's four matches over the kinds
//! have no wildcard arm either, so the compiler names each stage that must say what the new kind
//! does there), and on the host its effect's own file (`sysid::residual::effects`, whose
//! `device_kind` names the variant). The pinned table of `stored_effect_codes_never_change` then
//! fails until the new row is appended to it. CONTRIBUTING.md, "Add a device effect", lists the
//! steps.

use crate::chain::EffectKind;

/// Where an effect acts in the chain's evaluation (module docs of [`crate::chain`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    /// Transforms the volume and flow the polynomial sees (`(v, v̇) → (v′, v̇′)`).
    Input,
    /// Adds a term to the polynomial's pressure.
    Added,
    /// Filters the predicted pressure.
    Output,
}

/// The lower end of a parameter's admissible range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Min {
    /// No lower end (any finite value).
    Any,
    /// The value itself is admissible.
    AtLeast(f32),
    /// Only values above it are admissible.
    Above(f32),
}

/// One parameter of an effect: name, unit and admissible range (every value must be finite).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamSpec {
    /// Its name (snake case, as the host's report calls it).
    pub name: &'static str,
    /// Its unit, in the host's plain-text notation (`mm3`, `kPa*s^2/mm3`).
    pub unit: &'static str,
    /// The lower end of its range.
    pub min: Min,
    /// The largest admissible value (inclusive; `f32::INFINITY` for none).
    pub max: f32,
}

impl ParamSpec {
    /// Whether `x` is finite and in range.
    pub fn admits(&self, x: f32) -> bool {
        let above = match self.min {
            Min::Any => true,
            Min::AtLeast(m) => x >= m,
            Min::Above(m) => x > m,
        };
        x.is_finite() && above && x <= self.max
    }
}

/// One device effect's row of the table (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EffectSpec {
    /// Wire name: the protocol's and the residual loop's.
    pub name: &'static str,
    /// Stored code (module docs: fixed forever, never reused).
    pub code: u8,
    /// Where it acts in the chain.
    pub stage: Stage,
    /// Its parameters, in the order the protocol and the store carry them.
    pub params: &'static [ParamSpec],
}

/// The code the next new kind takes (module docs: codes are never reused).
pub const NEXT_FREE_CODE: u8 = 9;

const fn param(name: &'static str, unit: &'static str, min: Min, max: f32) -> ParamSpec {
    ParamSpec {
        name,
        unit,
        min,
        max,
    }
}

const INF: f32 = f32::INFINITY;

static DELIVERY_LAG: EffectSpec = EffectSpec {
    name: "delivery_lag",
    code: 0,
    stage: Stage::Input,
    params: &[param("time_constant", "s", Min::AtLeast(0.0), INF)],
};

static TRANSPORT_DELAY: EffectSpec = EffectSpec {
    name: "transport_delay",
    code: 1,
    stage: Stage::Input,
    params: &[param(
        "delay",
        "s",
        Min::AtLeast(0.0),
        crate::chain::MAX_DELAY_S,
    )],
};

static BACKLASH: EffectSpec = EffectSpec {
    name: "backlash",
    code: 2,
    stage: Stage::Input,
    params: &[param("play", "mm3", Min::AtLeast(0.0), INF)],
};

static LEAK: EffectSpec = EffectSpec {
    name: "leak",
    code: 3,
    stage: Stage::Input,
    params: &[param("conductance", "mm3/(kPa*s)", Min::AtLeast(0.0), INF)],
};

static AIR_COMPLIANCE: EffectSpec = EffectSpec {
    name: "air_compliance",
    code: 4,
    stage: Stage::Input,
    params: &[param("air_volume", "mm3", Min::AtLeast(0.0), INF)],
};

static HYSTERESIS: EffectSpec = EffectSpec {
    name: "hysteresis",
    code: 5,
    stage: Stage::Added,
    params: &[
        param("width", "mm3", Min::Above(0.0), INF),
        param("gap_h0", "kPa", Min::Any, INF),
        param("gap_h1", "kPa", Min::Any, INF),
    ],
};

static INERTANCE: EffectSpec = EffectSpec {
    name: "inertance",
    code: 6,
    stage: Stage::Added,
    params: &[param("inertance", "kPa*s^2/mm3", Min::Any, INF)],
};

static PUMP_RIPPLE: EffectSpec = EffectSpec {
    name: "pump_ripple",
    code: 7,
    stage: Stage::Added,
    params: &[
        param("period", "mm3", Min::Above(0.0), INF),
        param("sin_amplitude", "mm3", Min::Any, INF),
        param("cos_amplitude", "mm3", Min::Any, INF),
    ],
};

static SENSOR_LAG: EffectSpec = EffectSpec {
    name: "sensor_lag",
    code: 8,
    stage: Stage::Output,
    params: &[param("time_constant", "s", Min::AtLeast(0.0), INF)],
};

impl EffectKind {
    /// The kind's row of the table (module docs).
    pub fn spec(self) -> &'static EffectSpec {
        match self {
            EffectKind::DeliveryLag => &DELIVERY_LAG,
            EffectKind::TransportDelay => &TRANSPORT_DELAY,
            EffectKind::Backlash => &BACKLASH,
            EffectKind::Leak => &LEAK,
            EffectKind::AirCompliance => &AIR_COMPLIANCE,
            EffectKind::Hysteresis => &HYSTERESIS,
            EffectKind::Inertance => &INERTANCE,
            EffectKind::PumpRipple => &PUMP_RIPPLE,
            EffectKind::SensorLag => &SENSOR_LAG,
        }
    }

    /// The wire name (the residual loop's name of the effect, used by the protocol).
    pub fn name(self) -> &'static str {
        self.spec().name
    }

    /// The kind called `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The kind's code in a stored or transmitted model (`firmware::store`'s serialised chain):
    /// fixed forever and never reused (module docs).
    pub fn code(self) -> u8 {
        self.spec().code
    }

    /// The kind stored as `code` ([`code`](Self::code)); `None` for a code no kind has.
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.code() == code)
    }

    /// Number of parameters.
    pub fn params(self) -> usize {
        self.spec().params.len()
    }

    /// Where it acts in the chain.
    pub fn stage(self) -> Stage {
        self.spec().stage
    }
}
