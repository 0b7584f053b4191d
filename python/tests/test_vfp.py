"""The Python package against the `vfp` command-line tool on the same logs.

Truth here is the tool's own `--json` output (a separate process, the same library reached
through clap and the CLI's rendering): the package must return the same documents to the last
digit, give the same answers for a table and for the file it came from, and raise ValueError with
the tool's message on bad input.
"""

import math

import numpy as np
import pandas as pd
import pytest

import vfp
from conftest import cli_json, run_cli, strip_timing

QUICK = "data/real/quicklung-c10-r50-pip35-peep5.csv"
BAG = "data/real/bag-lung-pip15-peep5.csv"


def without(doc, *keys):
    return {k: v for k, v in strip_timing(doc).items() if k not in keys}


def test_identify_equals_cli_json():
    py = vfp.identify(QUICK, families=["poly"])
    cli = cli_json("identify", QUICK, "--family", "poly")
    assert strip_timing(py) == strip_timing(cli)
    # The acceptance check, spelled out: the selected model, every float identical.
    assert py["selected"] == cli["selected"]
    assert py["selected"]["family"] == "poly"


@pytest.fixture(scope="module")
def bag_diagnosis():
    """`diagnose` on the bag-lung log with the residuals (one run shared by the tests below)."""
    return vfp.diagnose(BAG, residuals=True)


def test_diagnose_equals_cli_json(bag_diagnosis):
    py, _ = bag_diagnosis
    cli = cli_json("diagnose", BAG)
    assert strip_timing(py) == strip_timing(cli)
    assert py["final"] == cli["final"]
    assert py["final"]["rmse_heldout"] <= py["baseline"]["rmse_heldout"]


def test_diagnose_residuals_are_the_reported_ones(bag_diagnosis):
    """The residual points returned with `residuals=True` are the held-out residuals the
    document's RMSEs were computed from: their RMS is the baseline's and the final model's
    held-out RMSE (an identity, independent of the fitting)."""
    doc, res = bag_diagnosis
    for key, rmse in [("before", doc["baseline"]["rmse_heldout"]), ("after", doc["final"]["rmse_heldout"])]:
        r = res[key]["residual_kpa"]
        assert len(r) == doc["samples"][1] and len(res[key]["time_s"]) == len(r)
        assert math.isclose(float(np.sqrt(np.mean(r**2))), rmse, rel_tol=1e-12)


def test_diagnose_validate_equals_cli_json(tmp_path):
    """`diagnose(validate=)` gives `vfp diagnose --validate`'s document, for a path and a table."""
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    run_cli("simulate", "--preset", "effect:hysteresis", "--cycles", "2", "--seed", "1", "-o", a)
    run_cli("simulate", "--preset", "effect:hysteresis", "--cycles", "2", "--seed", "2", "-o", b)
    py = vfp.diagnose(a, validate=b)
    cli = cli_json("diagnose", a, "--validate", b)
    assert strip_timing(py) == strip_timing(cli)
    v = py["validation"]
    assert v["final_rmse"] < v["baseline_rmse"]
    table = vfp.read_log(b, as_frame=True)
    assert vfp.diagnose(a, validate=table)["validation"]["steps"] == v["steps"]
    with pytest.raises(ValueError, match="missing.csv"):
        vfp.diagnose(a, validate=tmp_path / "missing.csv")


def test_diagnose_options_reach_the_library():
    py = vfp.diagnose(BAG, model=(2, 1), effects=["hysteresis"], alpha=0.01)
    cli = cli_json(
        "diagnose", BAG, "--model", "2,1", "--effect", "hysteresis", "--alpha", "0.01"
    )
    assert strip_timing(py) == strip_timing(cli)
    assert (py["baseline"]["n"], py["baseline"]["m"]) == (2, 1)


def test_export_lines_equal_cli():
    cli = run_cli("export", QUICK, "--format", "lines").stdout.splitlines()
    assert vfp.export(QUICK) == cli
    rust = run_cli("export", QUICK, "--n", "2", "--m", "1", "--format", "rust").stdout
    assert vfp.export(QUICK, n=2, m=1, format="rust") == rust


def test_replay_equals_cli(tmp_path):
    """`replay` with `export`'s lines gives `vfp replay --json`'s summary, and its frames are the
    CSV of `vfp replay -o` (the board's f32 values, widened exactly)."""
    log = tmp_path / "paper.csv"
    run_cli("simulate", "--preset", "paper", "--cycles", "2", "-o", log)
    lines = vfp.export(log)
    model = tmp_path / "model.txt"
    model.write_text("\n".join(lines) + "\n")
    summary, frames = vfp.replay(lines, log, frames=True)
    assert summary == cli_json("replay", model, log)
    assert vfp.replay(model, log) == summary
    out = tmp_path / "replay.csv"
    run_cli("replay", model, log, "-o", out)
    csv = pd.read_csv(out)
    np.testing.assert_array_equal(frames["time_s"], csv["time_s"].to_numpy())
    # The CSV holds each f32 in its shortest round-trip form: equal as f32.
    for col in ["p_0", "p_hat_0", "residual_0", "k_0", "c_0", "force_n"]:
        got, want = frames[col].astype(np.float32), csv[col].to_numpy().astype(np.float32)
        np.testing.assert_array_equal(got, want, err_msg=col)
    # Identities: the residual is P - P̂ in f32, and without a sensor lag the load is the residual;
    # the summary's RMSE is the frames' own.
    r = (frames["p_0"].astype(np.float32) - frames["p_hat_0"].astype(np.float32)).astype(np.float64)
    np.testing.assert_array_equal(frames["residual_0"], r)
    np.testing.assert_array_equal(frames["load_0"], frames["residual_0"])
    ok = np.isfinite(frames["p_hat_0"])
    rmse = float(np.sqrt(np.mean((frames["p_0"][ok] - frames["p_hat_0"][ok]) ** 2)))
    assert math.isclose(rmse, summary["chambers"][0]["p_hat_rmse_kpa"], rel_tol=1e-9)
    # A ventilator's scales are beyond the board's commands: the replay refuses, naming them.
    with pytest.raises(ValueError, match=r"model lines:2: the firmware would refuse it \(out-of-range \d+\)"):
        vfp.replay(vfp.export(BAG), BAG)


def test_frame_and_dict_agree_with_path():
    frame = vfp.read_log(QUICK, as_frame=True)
    table = vfp.read_log(QUICK)
    from_path = vfp.identify(QUICK, families=["poly"])
    for log, name in [(frame, "DataFrame"), (table, "dict")]:
        doc = vfp.identify(log, families=["poly"])
        assert doc["file"] == name
        assert without(doc, "file") == without(from_path, "file")
    d = vfp.diagnose(frame)
    assert without(d, "log") == without(vfp.diagnose(QUICK), "log")


def test_read_log_columns_and_units(tmp_path):
    """A lab's own names and units: the table read with `columns=` is the tool's file read with
    `--columns`, and its values are the format's units (mL → mm³ × 1000, cmH2O → kPa ×
    0.0980665)."""
    base = vfp.read_log(QUICK)
    lab = pd.DataFrame(
        {
            "t": base["time_s"],
            "V_ml": base["volume_mm3"] / 1000.0,
            "Q_ml_s": base["flow_mm3_s"] / 1000.0,
            "P_cmH2O": base["pressure_kpa"] / 0.0980665,
        }
    )
    spec = "time=t,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O"
    back = vfp.read_log(lab, columns=spec)
    np.testing.assert_allclose(back["volume_mm3"], base["volume_mm3"], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(back["pressure_kpa"], base["pressure_kpa"], rtol=1e-12, atol=1e-12)
    path = tmp_path / "lab.csv"
    lab.to_csv(path, index=False)  # shortest round-trip floats: the file holds the same numbers
    py = vfp.identify(lab, families=["poly"], columns=spec)
    cli = cli_json("identify", path, "--family", "poly", "--columns", spec)
    assert without(py, "file") == without(cli, "file")


def test_simulate_equals_cli_log(tmp_path):
    out = tmp_path / "sim.csv"
    run_cli("simulate", "--cycles", "1", "--flows", "50", "--seed", "7", "--out", out)
    cli = vfp.read_log(out)
    py = vfp.simulate(cycles=1, flows=[50], seed=7)
    assert list(py) == list(cli)
    for k in cli:
        if cli[k].dtype == object:
            assert list(py[k]) == list(cli[k])
        else:
            np.testing.assert_array_equal(py[k], cli[k])
    # The simulated protocol is what was asked for: one inflation-deflation cycle at 50 mm3/s.
    flow = py["flow_mm3_s"][py["chamber"] == 0]
    assert math.isclose(np.nanmax(flow), 50.0, rel_tol=0.2)


def test_force_equals_cli_json(tmp_path):
    ident, test = tmp_path / "ident.csv", tmp_path / "push.csv"
    run_cli("simulate", "--cycles", "1", "--seed", "3", "--out", ident)
    run_cli("simulate", "--preset", "force", "--force-seconds", "4", "--seed", "4", "--out", test)
    cli = cli_json("force", "--ident", ident, "--test", test)
    assert vfp.force(str(ident), str(test)) == cli
    cli = cli_json("force", "--ident", ident, "--test", test, "--augmented")
    assert vfp.force(str(ident), str(test), augmented=True) == cli


def cli_error(*args):
    out = run_cli(*args, ok=False)
    assert out.returncode != 0
    msg = out.stderr.strip()
    assert msg.startswith("vfp: "), msg
    return msg[len("vfp: "):]


def test_bad_file_raises_the_cli_message(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,volume_mm3,pressure_kpa\n0,0,1\n0.04,1,1.2\n0.08,2,abc\n")
    want = cli_error("identify", bad, "--family", "poly")
    assert want == f'{bad}:4: column `pressure_kpa`: cannot parse as a number: "abc"'
    with pytest.raises(ValueError) as e:
        vfp.identify(str(bad), families=["poly"])
    assert str(e.value) == want
    with pytest.raises(ValueError) as e:
        vfp.read_log(str(bad))
    assert str(e.value) == want


def test_bad_table_names_row_and_column(tmp_path):
    """A table's bad cell: the message the tool gives for the same table written as a file,
    with the table's name for the file (row k is line k + 2)."""
    frame = pd.DataFrame(
        {"time_s": [0.0, 0.04, 0.08], "volume_mm3": [0.0, 1.0, 2.0], "pressure_kpa": [1, np.inf, 2]}
    )
    path = tmp_path / "inf.csv"
    frame.to_csv(path, index=False)
    want = cli_error("diagnose", path)
    assert want == f'{path}:3: column `pressure_kpa`: not a finite number: "inf"'
    with pytest.raises(ValueError) as e:
        vfp.diagnose(frame)
    assert str(e.value) == want.replace(str(path), "DataFrame")
    # Time going backwards in a dict of arrays.
    table = {"time_s": np.array([0.0, 0.1, 0.05]), "volume_mm3": np.zeros(3), "pressure_kpa": np.ones(3)}
    with pytest.raises(ValueError, match=r"^dict:4: column `time_s`: 0.05 s is not after"):
        vfp.read_log(table)


def test_bad_options_raise_value_error():
    with pytest.raises(ValueError, match="--columns: item 1 `volume=V:gallon`"):
        vfp.read_log(QUICK, columns="volume=V:gallon")
    with pytest.raises(ValueError, match="missing column `V`"):
        vfp.identify(QUICK, families=["poly"], columns="volume=V")
    with pytest.raises(ValueError, match="family `polynomial`: one of exp, nn, poly, poly-ar"):
        vfp.identify(QUICK, families=["polynomial"])
    with pytest.raises(ValueError, match=r"--chamber 5: chambers are 0, 1 and 2"):
        vfp.identify(QUICK, chamber=5)
    with pytest.raises(ValueError, match="no samples for chamber 1"):
        vfp.diagnose(QUICK, chamber=1)
    with pytest.raises(ValueError, match="--alpha must lie in"):
        vfp.diagnose(QUICK, alpha=2.0)
    with pytest.raises(ValueError, match="unknown preset"):
        vfp.simulate("nonsense")
    with pytest.raises(ValueError, match="No such file"):
        vfp.read_log("data/real/does-not-exist.csv")
    with pytest.raises(TypeError):
        vfp.identify(42)
