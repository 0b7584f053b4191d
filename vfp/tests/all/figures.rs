//! `--plot-format png` writes real PNG files (signature, header chunk, the canvas' size), the
//! SVGs of a long log stay under 1 MB (scatter plots are decimated), and both formats write the
//! same set of figures.

use crate::common;

use std::path::{Path, PathBuf};

fn scratch(name: &str) -> PathBuf {
    common::scratch("fig", name)
}

/// Runs `vfp identify LOG --family poly --plots DIR --plot-format FORMAT`; the files written.
fn identify_plots(log: &str, dir: &Path, format: &str) -> Vec<PathBuf> {
    common::ok(
        common::vfp()
            .args(["identify", log, "--family", "poly", "--plots"])
            .arg(dir)
            .args(["--plot-format", format]),
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("plots dir")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    files
}

fn stems(files: &[PathBuf]) -> Vec<String> {
    files
        .iter()
        .map(|f| f.file_stem().unwrap().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn png_figures_are_valid_pngs() {
    let dir = scratch("png");
    let files = identify_plots("data/real/bag-lung-pip15-peep5.csv", &dir, "png");
    assert_eq!(
        stems(&files),
        [
            "ch0-error-histogram",
            "ch0-poly-rmse-aicc",
            "ch0-residual-vs-volume",
            "ch0-vp"
        ]
    );
    for f in &files {
        let bytes = std::fs::read(f).expect("readable");
        assert_eq!(f.extension().unwrap(), "png");
        assert_eq!(
            &bytes[..8],
            b"\x89PNG\r\n\x1a\n",
            "{}: PNG signature",
            f.display()
        );
        assert_eq!(
            &bytes[12..16],
            b"IHDR",
            "{}: header chunk first",
            f.display()
        );
        let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().unwrap());
        let size = (be(16), be(20));
        let want = if f.to_string_lossy().contains("rmse-aicc") {
            // 30 px per model so each upright label fits: the 49 shapes of the polynomial sweep.
            (120 + 30 * 49, 640)
        } else {
            (900, 600)
        };
        assert_eq!(size, want, "{}", f.display());
        assert_eq!(
            &bytes[bytes.len() - 8..bytes.len() - 4],
            b"IEND",
            "{}: complete",
            f.display()
        );
        assert!(
            bytes.len() > 10_000 && bytes.len() < 1_000_000,
            "{}: {} B",
            f.display(),
            bytes.len()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn svg_figures_of_a_long_log_stay_small() {
    // 23,000 samples: every one drawn would be some 4 MB of SVG for the V-P figure.
    let dir = scratch("svg");
    let files = identify_plots("data/real/test-lung-pip15-peep5.csv", &dir, "svg");
    assert_eq!(files.len(), 4, "{files:?}");
    for f in &files {
        let len = std::fs::metadata(f).expect("written").len();
        assert!(len < 1_000_000, "{}: {len} B", f.display());
        let text = std::fs::read_to_string(f).expect("UTF-8");
        assert!(
            text.starts_with("<svg") && text.trim_end().ends_with("</svg>"),
            "{}",
            f.display()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
