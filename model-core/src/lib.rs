//! Volume-flow-pressure model math shared by the device and the host tools.
//!
//! `no_std`, no allocation, no `unsafe`. All public numbers are f32 in the paper's units (kPa, mm³,
//! mm³/s, N) except where a person reads or writes raw polynomial coefficients (f64, see
//! [`poly::PolyModel::from_raw`]).
//!
//! - [`poly`]: polynomial / poly-AR model P̂(v, v̇), stiffness k = ∂P/∂v, damping c = ∂P/∂v̇, the
//!   C·v̇ + K split, regressors, and the paper's SBA1 model.
//! - [`chain`]: the effect chain (hysteresis, lags, delay, backlash, inertance, pump ripple, air,
//!   leak) evaluated around the polynomial once per frame.
//! - [`spec`]: one row per device effect (wire name, stored code, parameters, units, bounds,
//!   stage), the table the chain, the protocol, the store and the host's export read.
//! - [`exp`]: the physics-inspired exponential model.
//! - [`rls`]: online identification (U-D factored recursive least squares with forgetting).
//! - [`force`]: external force from pressure residuals.
//! - [`flags`]: the fault and warning bits every telemetry frame carries.
//! - [`stats`]: running means of k and c, split by inflation and deflation.
//!
//! ```
//! use model_core::force::{self, DEFAULT_AREAS_MM2};
//! use model_core::poly;
//! use model_core::rls::Rls;
//!
//! // The paper's SBA1 model (Table IV): pressure, stiffness and damping at 300 mm³, +50 mm³/s.
//! let model = poly::sba1();
//! let e = model.eval(300.0, 50.0)?;
//! assert!(e.p > 0.0 && e.k > 0.0 && e.c > 0.0);
//! // Eq. (9): P = C(v, v̇)·v̇ + K(v).
//! let (c, k) = model.split(300.0, 50.0)?;
//! assert!((c * 50.0 + k - e.p).abs() < 1e-4);
//!
//! // Force from the residuals of three chambers.
//! let f = force::estimate([e.p + 1.0 - e.p, 0.5, 0.0], DEFAULT_AREAS_MM2)?;
//! assert!((f.total_n - 0.033).abs() < 1e-6);
//!
//! // Online identification: start from the offline model, update with a measurement.
//! let mut rls = Rls::<12>::new(0.995, 1.0)?;
//! rls.set_coeffs(model.scaled().try_into().unwrap())?;
//! let mut phi = [0.0f32; 12];
//! model.regressors(300.0, 50.0, &mut phi)?;
//! let prior_residual = rls.update(&phi, e.p + 0.2)?;
//! assert!((prior_residual - 0.2).abs() < 1e-4);
//! # Ok::<(), model_core::ModelError>(())
//! ```
//!
//! Equation and table numbers refer to the paper this crate implements: S.-Y. Lee, L. Zamora
//! Yañez, J. Rogatinsky, V. T. Vo, T. Shingade and T. Ranzani, *Simplifying Data-Driven Modeling
//! of the Volume-Flow-Pressure Relationship in Hydraulic Soft Robotic Actuators* (IEEE), counting
//! its numbered equations in order.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Index loops mirror the subscripts of the documented equations.
#![allow(clippy::needless_range_loop)]

pub mod chain;
mod error;
pub mod exp;
pub mod flags;
pub mod force;
pub mod poly;
pub mod rls;
pub mod spec;
pub mod stats;

pub use error::ModelError;
