//! `vfp stiffness LOG`: pointwise stiffness and damping of the identified polynomial (paper
//! §IV-A, eq. 13, Fig. 7c–d); the method is [`sysid::diag::stiffness`].

use crate::opts::{LogInput, OutputOpts};
use crate::plots::diag::{self as plot, Curve, Mark};
use crate::units::DisplayUnits;
use crate::Error;
use std::path::PathBuf;
use sysid::diag::stiffness::{stiffness, ChamberStiffness, StiffnessReport};
use sysid::diag::Shape;

/// Polynomial shape of the §IV analyses (`--n`, `--m`).
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct ShapeOpts {
    /// Highest power of volume v in the polynomial.
    #[arg(long, default_value_t = 3)]
    pub n: usize,
    /// Highest power of flow v̇ in the polynomial.
    #[arg(long, default_value_t = 2)]
    pub m: usize,
}

impl Default for ShapeOpts {
    fn default() -> Self {
        Self { n: 3, m: 2 }
    }
}

impl ShapeOpts {
    /// The shape, checked (1..=7 each).
    pub fn shape(&self) -> Result<Shape, Error> {
        let s = Shape {
            n: self.n,
            m: self.m,
        };
        s.validate()?;
        Ok(s)
    }
}

/// `vfp stiffness`: stiffness and damping of one log.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The log, `--chamber` (default: every chamber) and the data options; `--deadband` also
    /// separates inflation (v̇ > band) and deflation (v̇ < −band) from rest in the means.
    #[command(flatten)]
    pub input: LogInput,
    #[command(flatten)]
    pub shape: ShapeOpts,
    #[command(flatten)]
    pub out: OutputOpts,
}

/// Runs `vfp stiffness`.
pub fn run(args: &Args) -> Result<(), Error> {
    let shape = args.shape.shape()?;
    let data = args.input.load()?;
    let (report, res) = stiffness(&data, shape)?;
    let u = args.out.display_units(&args.input.data);
    args.out.emit(
        &report,
        |r| human(r, &u),
        |dir, format| plot_distributions(dir, format, &data.label(), &res, &u),
    )
}

fn opt(x: Option<f64>, u: &DisplayUnits) -> String {
    x.map(|x| format!("{:>12.5}", u.k(x)))
        .unwrap_or_else(|| format!("{:>12}", "-"))
}

/// The human report, its numbers in `u`.
pub fn human(r: &StiffnessReport, u: &DisplayUnits) -> String {
    let (kh, ch) = (
        format!("k ({})", u.stiffness()),
        format!("c ({})", u.damping()),
    );
    let mut s = format!(
        "Stiffness k = dP/dv and damping c = dP/dvdot of the fitted polynomial (n = {}, m = {}) \
         at every sample of {}\n",
        r.shape.n, r.shape.m, r.log
    );
    if r.flow_derived {
        s += "(flow derived from volume and time: the log has no flow_mm3_s column)\n";
    }
    for c in &r.chambers {
        s += &format!(
            "\nchamber {}: {} samples, fit RMSE {:.4} {}\n  {:<10} {:>12} {:>12} {:>8}\n",
            c.chamber,
            c.samples,
            u.p(c.fit_rmse_kpa),
            u.pressure(),
            "phase",
            kh,
            ch,
            "samples"
        );
        s += &format!(
            "  {:<10} {:>12.5} {:>12.5} {:>8}\n",
            "all",
            u.k(c.k_mean),
            u.k(c.c_mean),
            c.samples
        );
        for (name, m) in [("inflation", &c.inflation), ("deflation", &c.deflation)] {
            s += &format!(
                "  {:<10} {} {} {:>8}\n",
                name,
                opt(m.k_mean, u),
                opt(m.c_mean, u),
                m.samples
            );
        }
        s += &format!(
            "  ({} samples with |vdot| <= {} {} count as rest: in 'all' only)\n",
            c.rest_samples,
            u.q(c.deadband_mm3_s),
            u.flow()
        );
    }
    s
}

/// Fig. 7d-style distributions of kᵢ and cᵢ per chamber; returns the file written.
fn plot_distributions(
    dir: &std::path::Path,
    format: crate::figure::PlotFormat,
    label: &str,
    res: &[ChamberStiffness],
    u: &DisplayUnits,
) -> Result<PathBuf, Error> {
    let path = plot::target(dir, &format.file("diag-stiffness"))?;
    let root = plot::canvas(&path, (1100, 420), format);
    let (left, right) = root.split_horizontally(550);
    let conv = |x: &[f64]| x.iter().map(|&x| u.k(x)).collect::<Vec<f64>>();
    let (kv, cv): (Vec<Vec<f64>>, Vec<Vec<f64>>) = res
        .iter()
        .map(|r| (conv(&r.pointwise.k), conv(&r.pointwise.c)))
        .unzip();
    let ks: Vec<&[f64]> = kv.iter().map(Vec::as_slice).collect();
    let cs: Vec<&[f64]> = cv.iter().map(Vec::as_slice).collect();
    let (klo, khi) = plot::quantile_range(&ks, 0.005, 0.995);
    let (clo, chi) = plot::quantile_range(&cs, 0.005, 0.995);
    let curves = |sets: &[&[f64]], lo, hi| -> Vec<Curve> {
        sets.iter()
            .zip(res)
            .enumerate()
            .map(|(i, (s, r))| {
                Curve::new(
                    format!("chamber {}", r.summary.chamber),
                    plot::density_outline(s, lo, hi, 60),
                    plot::color(i),
                    Mark::Line,
                )
            })
            .collect()
    };
    plot::panel(
        &left,
        &path,
        &format!("{label}: pointwise stiffness k"),
        &format!("k = dP/dv ({})", u.stiffness()),
        "density",
        &curves(&ks, klo, khi),
    )?;
    plot::panel(
        &right,
        &path,
        &format!("{label}: pointwise damping c"),
        &format!("c = dP/dvdot ({})", u.damping()),
        "density",
        &curves(&cs, clo, chi),
    )?;
    plot::finish(root, &path)?;
    Ok(path.clone())
}
