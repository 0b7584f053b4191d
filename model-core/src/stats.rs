//! Streaming statistics of stiffness and damping (paper, Sec. "Stiffness/Damping Analysis"):
//!
//! ```text
//! k̄ = (1/N) Σ k_i,   c̄ = (1/N) Σ c_i,
//! ```
//!
//! over all samples and separately over inflation (v̇ > +dead band) and deflation (v̇ < −dead band).
//! Means use Welford's update m_N = m_{N−1} + (x_N − m_{N−1}) / N with f64 accumulators: at 25 Hz ×
//! 3 chambers the soft-float cost on the Cortex-M4F is negligible, and an f32 accumulator would
//! lose digits over the 10⁶+ samples of a long session.

use crate::error::ModelError;

/// Running mean and variance of a stream (Welford).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RunningMean {
    n: u64,
    mean: f64,
    m2: f64,
}

impl RunningMean {
    /// An empty accumulator.
    pub const fn new() -> Self {
        RunningMean {
            n: 0,
            mean: 0.0,
            m2: 0.0,
        }
    }

    /// Adds a sample; `NonFinite` (and no change) for NaN/∞.
    pub fn push(&mut self, x: f32) -> Result<(), ModelError> {
        if !x.is_finite() {
            return Err(ModelError::NonFinite);
        }
        let x = x as f64;
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
        Ok(())
    }

    /// Number of samples.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// The mean, or `None` before the first sample.
    pub fn mean(&self) -> Option<f32> {
        (self.n > 0).then_some(self.mean as f32)
    }

    /// The sample variance (N − 1 denominator), or `None` with fewer than two samples.
    pub fn variance(&self) -> Option<f32> {
        (self.n > 1).then(|| (self.m2 / (self.n - 1) as f64) as f32)
    }

    /// Forgets all samples.
    pub fn reset(&mut self) {
        *self = RunningMean::new();
    }
}

/// Phase of a sample by the sign of the flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// v̇ > +dead band.
    Inflating,
    /// v̇ < −dead band.
    Deflating,
    /// |v̇| ≤ dead band.
    Holding,
}

/// Running means of k and c, overall and split by inflation / deflation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KcStats {
    deadband: f32,
    /// k over all samples.
    pub k_all: RunningMean,
    /// c over all samples.
    pub c_all: RunningMean,
    /// k while inflating.
    pub k_inflate: RunningMean,
    /// c while inflating.
    pub c_inflate: RunningMean,
    /// k while deflating.
    pub k_deflate: RunningMean,
    /// c while deflating.
    pub c_deflate: RunningMean,
}

impl KcStats {
    /// Statistics with a flow dead band (mm³/s, finite and ≥ 0, else `BadParameter`).
    pub fn new(deadband_mm3_s: f32) -> Result<Self, ModelError> {
        if !(deadband_mm3_s.is_finite() && deadband_mm3_s >= 0.0) {
            return Err(ModelError::BadParameter);
        }
        Ok(KcStats {
            deadband: deadband_mm3_s,
            k_all: RunningMean::new(),
            c_all: RunningMean::new(),
            k_inflate: RunningMean::new(),
            c_inflate: RunningMean::new(),
            k_deflate: RunningMean::new(),
            c_deflate: RunningMean::new(),
        })
    }

    /// The flow dead band, mm³/s.
    pub fn deadband(&self) -> f32 {
        self.deadband
    }

    /// The phase of a flow value under this dead band.
    pub fn phase(&self, vdot: f32) -> Phase {
        if vdot > self.deadband {
            Phase::Inflating
        } else if vdot < -self.deadband {
            Phase::Deflating
        } else {
            Phase::Holding
        }
    }

    /// Adds one (k, c) sample taken at flow `vdot`; `NonFinite` (and no change) if any is NaN/∞.
    pub fn push(&mut self, k: f32, c: f32, vdot: f32) -> Result<Phase, ModelError> {
        if !(k.is_finite() && c.is_finite() && vdot.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        self.k_all.push(k)?;
        self.c_all.push(c)?;
        let phase = self.phase(vdot);
        match phase {
            Phase::Inflating => {
                self.k_inflate.push(k)?;
                self.c_inflate.push(c)?;
            }
            Phase::Deflating => {
                self.k_deflate.push(k)?;
                self.c_deflate.push(c)?;
            }
            Phase::Holding => {}
        }
        Ok(phase)
    }

    /// Forgets all samples, keeping the dead band.
    pub fn reset(&mut self) {
        for m in [
            &mut self.k_all,
            &mut self.c_all,
            &mut self.k_inflate,
            &mut self.c_inflate,
            &mut self.k_deflate,
            &mut self.c_deflate,
        ] {
            m.reset();
        }
    }
}
