//! The chamber law: pressure of one balloon chamber from its volume and flow.
//!
//! The paper's multivariate polynomial (Table II, n = 3, m = 2), rewritten as its Eq. (9):
//!
//! ```text
//! P(v, v̇) = Σ_{i≤3} Σ_{j≤2} α_ij v^i v̇^j = K(v) + C(v, v̇)·v̇
//! K(v)     = Σ_i α_i0 v^i                          (elastic part)
//! C(v, v̇)·v̇ = C₁(v)·v̇ + C₂(v)·v̇²,   C_j(v) = Σ_i α_ij v^i   (flow part)
//! ```
//!
//! with SBA1's coefficients from Table IV ([`model_core::poly::SBA1_RAW`]), evaluated in f64 on raw
//! monomials (v ≤ a few thousand mm³ cubed is far inside f64's range, and evaluation, unlike fitting,
//! does not square the conditioning).
//!
//! # Other designs (SBA2–SBA4)
//! The paper publishes only SBA1's coefficients; for SBA2–SBA4 it gives the envelope (Table V: max
//! volume V_max, max pressure P_max) and the mean stiffness and damping k̄, c̄ (Table VI). The presets
//! here are **derived, not published**: SBA1's law rescaled to each envelope,
//!
//! ```text
//! P_d(v, v̇) = (P_max,d / P_max,1) · K₁(v · V_max,1 / V_max,d) + (c̄_d / c̄_1) · [C₁·v̇](v · V_max,1 / V_max,d, v̇)
//! ```
//!
//! i.e. the volume axis stretched to the design's max volume, the elastic part scaled to its max
//! pressure, and the flow part scaled so the mean damping keeps the proportion of Table VI. The
//! flow axis is not rescaled (same pumps, same 20–100 mm³/s). k̄ of the rescaled law is
//! (P_max,d/P_max,1)(V_max,1/V_max,d) k̄_1, which matches Table VI only roughly (SBA4's published
//! k̄ = 0.0003 is far below the 0.006 the envelope implies).
//!
//! # Beyond the identified flow range
//! The polynomial was identified for |v̇| ≤ 100 mm³/s. Quadratic in v̇, it turns over for fast
//! withdrawal (∂P/∂v̇ < 0 beyond about −380 mm³/s at v = 0), which no tube does and which would
//! make the implicit integration ambiguous. Outside ±[`IDENTIFIED_FLOW_MM3_S`] the flow part is
//! therefore continued linearly with its slope at the boundary (laminar, Hagen–Poiseuille-like),
//! which keeps P continuous and C¹ and leaves every value inside the identified range untouched.

use model_core::poly::SBA1_RAW;
use serde::{Deserialize, Serialize};

/// Largest |v̇| the paper identified the law for, mm³/s.
pub const IDENTIFIED_FLOW_MM3_S: f64 = 100.0;

/// A stacked-balloon-actuator design with a published envelope (paper, Table V).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Design {
    /// Reniform, TPE, 550 mm³, 80 kPa: the benchmark SBA whose coefficients Table IV gives.
    #[default]
    Sba1,
    /// Circular, TPU, 450 mm³, 70 kPa.
    Sba2,
    /// Reniform, TPE, 200 mm³, 35 kPa.
    Sba3,
    /// Circular, TPU, 7000 mm³, 40 kPa.
    Sba4,
}

impl Design {
    /// All designs, in the paper's order.
    pub const ALL: [Design; 4] = [Design::Sba1, Design::Sba2, Design::Sba3, Design::Sba4];

    /// Max volume, mm³ (Table V).
    pub fn max_volume_mm3(self) -> f64 {
        match self {
            Design::Sba1 => 550.0,
            Design::Sba2 => 450.0,
            Design::Sba3 => 200.0,
            Design::Sba4 => 7000.0,
        }
    }

    /// Max pressure, kPa (Table V).
    pub fn max_pressure_kpa(self) -> f64 {
        match self {
            Design::Sba1 => 80.0,
            Design::Sba2 => 70.0,
            Design::Sba3 => 35.0,
            Design::Sba4 => 40.0,
        }
    }

    /// Mean damping c̄ identified by the paper, kPa·s/mm³ (Table VI).
    pub fn mean_damping(self) -> f64 {
        match self {
            Design::Sba1 => 0.1750,
            Design::Sba2 => 0.2308,
            Design::Sba3 => 0.5345,
            Design::Sba4 => 0.9176,
        }
    }

    /// Lower-case name (`sba1` …), as in scenario files and log metadata.
    pub fn name(self) -> &'static str {
        match self {
            Design::Sba1 => "sba1",
            Design::Sba2 => "sba2",
            Design::Sba3 => "sba3",
            Design::Sba4 => "sba4",
        }
    }

    /// The chamber law of this design (see the module docs for SBA2–SBA4).
    pub fn law(self) -> ChamberLaw {
        let base = Design::Sba1;
        ChamberLaw {
            alpha: SBA1_RAW,
            v_stretch: base.max_volume_mm3() / self.max_volume_mm3(),
            k_gain: self.max_pressure_kpa() / base.max_pressure_kpa(),
            c_gain: self.mean_damping() / base.mean_damping(),
        }
    }
}

/// Pressure, stiffness and damping at one point of the law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LawPoint {
    /// P, kPa.
    pub p: f64,
    /// ∂P/∂v, kPa/mm³.
    pub dp_dv: f64,
    /// ∂P/∂v̇, kPa·s/mm³.
    pub dp_dvdot: f64,
}

/// P(v, v̇) of one chamber: a Table-IV-shaped polynomial, optionally rescaled (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChamberLaw {
    /// Raw α_ij, index i·3 + j (row i: power of v; column j: power of v̇).
    alpha: [f64; 12],
    /// v is evaluated at v · v_stretch.
    v_stretch: f64,
    /// Gain on K.
    k_gain: f64,
    /// Gain on the flow part.
    c_gain: f64,
}

/// Σ_i a[i·3 + j] x^i and its derivative in x, by Horner.
fn column(alpha: &[f64; 12], j: usize, x: f64) -> (f64, f64) {
    let (mut p, mut d) = (0.0, 0.0);
    for i in (0..4).rev() {
        d = d * x + p;
        p = p * x + alpha[i * 3 + j];
    }
    (p, d)
}

impl ChamberLaw {
    /// A law from raw coefficients α_ij (index i·3 + j, kPa, mm³, mm³/s), without rescaling.
    pub fn from_raw(alpha: [f64; 12]) -> Self {
        Self {
            alpha,
            v_stretch: 1.0,
            k_gain: 1.0,
            c_gain: 1.0,
        }
    }

    /// The elastic part K(v), kPa.
    pub fn k(&self, v: f64) -> f64 {
        self.k_gain * column(&self.alpha, 0, v * self.v_stretch).0
    }

    /// P(v, v̇) with its partial derivatives (module docs; linear beyond the identified flow range).
    pub fn eval(&self, v: f64, vdot: f64) -> LawPoint {
        let s = self.v_stretch;
        let x = v * s;
        let (k, dk) = column(&self.alpha, 0, x);
        let (c1, dc1) = column(&self.alpha, 1, x);
        let (c2, dc2) = column(&self.alpha, 2, x);
        // Flow part g(q) = c1 q + c2 q², continued linearly outside ±q_lim.
        let q_lim = IDENTIFIED_FLOW_MM3_S;
        let q = vdot.clamp(-q_lim, q_lim);
        let excess = vdot - q;
        let g = c1 * q + c2 * q * q;
        let dg_dq = c1 + 2.0 * c2 * q;
        let dg_dx = dc1 * q + dc2 * q * q;
        let d2g_dqdx = dc1 + 2.0 * dc2 * q;
        let flow = g + dg_dq * excess;
        let dflow_dx = dg_dx + d2g_dqdx * excess;
        LawPoint {
            p: self.k_gain * k + self.c_gain * flow,
            dp_dv: (self.k_gain * dk + self.c_gain * dflow_dx) * s,
            dp_dvdot: self.c_gain * dg_dq,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Table IV by hand at one point: v = 550, v̇ = 100 (all 12 terms written out).
    #[test]
    fn sba1_matches_table_iv_by_hand() {
        let (v, q): (f64, f64) = (550.0, 100.0);
        let terms = [
            (0.0, 0, 0),
            (1.7660e-1, 0, 1),
            (2.3010e-4, 0, 2),
            (1.2695e-2, 1, 0),
            (-1.3896e-4, 1, 1),
            (-3.0150e-6, 1, 2),
            (-8.0664e-5, 2, 0),
            (6.6527e-7, 2, 1),
            (1.3800e-8, 2, 2),
            (4.1269e-7, 3, 0),
            (-7.3542e-10, 3, 1),
            (-1.3773e-11, 3, 2),
        ];
        let expect: f64 = terms
            .iter()
            .map(|&(a, i, j)| a * v.powi(i) * q.powi(j))
            .sum();
        let got = Design::Sba1.law().eval(v, q).p;
        assert!((got - expect).abs() < 1e-9, "{got} vs {expect}");
        // And the envelope: about 74 kPa at full volume and full flow, below Table V's 80 kPa.
        assert!(got > 60.0 && got < 80.0, "{got}");
    }

    #[test]
    fn partials_match_finite_differences() {
        for d in Design::ALL {
            let law = d.law();
            let vmax = d.max_volume_mm3();
            for &(fv, q) in &[
                (0.1, 20.0),
                (0.5, -60.0),
                (0.9, 100.0),
                (0.7, -150.0),
                (0.3, 140.0),
            ] {
                let v = fv * vmax;
                let p = law.eval(v, q);
                let (hv, hq) = (1e-4 * vmax, 1e-4);
                let dv = (law.eval(v + hv, q).p - law.eval(v - hv, q).p) / (2.0 * hv);
                let dq = (law.eval(v, q + hq).p - law.eval(v, q - hq).p) / (2.0 * hq);
                assert!(
                    (p.dp_dv - dv).abs() < 1e-6 * (1.0 + dv.abs()),
                    "{d:?} {v} {q}"
                );
                assert!(
                    (p.dp_dvdot - dq).abs() < 1e-6 * (1.0 + dq.abs()),
                    "{d:?} {v} {q}"
                );
            }
        }
    }

    /// The implicit integrator relies on P rising with v̇ everywhere it can go.
    #[test]
    fn damping_is_positive_over_the_envelope_and_beyond() {
        for d in Design::ALL {
            let law = d.law();
            for iv in 0..=50 {
                let v = d.max_volume_mm3() * (iv as f64 / 50.0);
                for iq in -40..=40 {
                    let q = iq as f64 * 10.0;
                    assert!(law.eval(v, q).dp_dvdot > 0.0, "{d:?} v={v} q={q}");
                }
            }
        }
    }

    #[test]
    fn rescaled_designs_follow_their_envelope() {
        let base = Design::Sba1.law();
        for d in Design::ALL {
            let law = d.law();
            // Same normalised volume, elastic part in proportion to max pressure.
            let ratio = law.k(d.max_volume_mm3()) / base.k(550.0);
            assert!((ratio - d.max_pressure_kpa() / 80.0).abs() < 1e-12, "{d:?}");
            // Flow part in proportion to c̄ (Table VI).
            let flow = |l: &ChamberLaw, v: f64| l.eval(v, 50.0).p - l.k(v);
            let r = flow(&law, 0.5 * d.max_volume_mm3()) / flow(&base, 275.0);
            assert!((r - d.mean_damping() / 0.175).abs() < 1e-12, "{d:?}");
        }
    }
}
