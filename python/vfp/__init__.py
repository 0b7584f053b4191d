"""Volume-flow-pressure identification and analyses of soft-actuator logs.

The ``vfp`` package is the Rust ``sysid`` library behind the ``vfp`` command-line tool, called
directly: every function returns the very document the matching command prints with ``--json``
(``identify`` is ``vfp identify --json``, ``diagnose`` is ``vfp diagnose --json``, ...), parsed
into Python dicts, lists, floats and ints, with the same numbers to the last digit.

A *log* is any of

* a path (``str`` or ``os.PathLike``) of a CSV log in the format of ``docs/log-format.md``;
* a pandas ``DataFrame`` or a ``dict`` of 1-D arrays, one column per entry, under the log
  format's column names: ``time_s`` (s), ``chamber`` (0..=2, optional), ``volume_mm3`` (mm³),
  ``flow_mm3_s`` (mm³/s, optional), ``pressure_kpa`` (kPa), ``force_n`` (N, optional); other
  columns are kept as extra columns (the firmware's ``flags``, say). NaN in an optional column
  means "not recorded", as an empty cell does in a file.

``columns=`` maps a lab's own names and units exactly as the command's ``--columns`` does, e.g.
``"time=t,volume=V_ml:mL,pressure=P_cmH2O:cmH2O"`` (see ``sysid/src/columns.rs``); it applies to
files and tables alike. A table goes through the file reader itself (it is written as the text of
a log and read back, numbers in shortest round-trip form, so no digit changes): the checks and
messages are the file reader's, the table's name (``"DataFrame"`` or ``"dict"``) stands for the
file, and row ``k`` (counted from 0) is reported as line ``k + 2`` (the header is line 1).

Bad input raises ``ValueError`` with the command's message (file, line, column). The
interpreter lock is released while the library works, and no progress is printed.
"""

from __future__ import annotations

import importlib
import json
import os
from collections.abc import Mapping
from types import SimpleNamespace
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native

__all__ = ["read_log", "identify", "diagnose", "simulate", "export", "force", "replay"]

Log = Union[str, "os.PathLike[str]", Mapping, Any]


def _data(
    columns: Optional[str] = None,
    chamber_base: int = 0,
    holdout_every: int = 5,
    derive_flow: bool = False,
    diff_half_width: int = 2,
    deadband: Optional[float] = None,
) -> SimpleNamespace:
    if holdout_every < 0 or diff_half_width < 0 or chamber_base < 0:
        raise ValueError("holdout_every, diff_half_width and chamber_base must be >= 0")
    return SimpleNamespace(
        columns=columns,
        chamber_base=chamber_base,
        holdout_every=holdout_every,
        derive_flow=derive_flow,
        diff_half_width=diff_half_width,
        deadband=deadband,
    )


def _cells(a: np.ndarray) -> List[str]:
    out = []
    for x in a.tolist():
        if x is None or (isinstance(x, float) and x != x):
            out.append("")
        else:
            out.append(str(x))
    return out


def _source(log: Log) -> Any:
    """A path as it is, a table as (name, [(column, float64 bytes | text cells)])."""
    if isinstance(log, (str, os.PathLike)):
        return os.fspath(log)
    if hasattr(log, "columns") and hasattr(log, "to_numpy") and not isinstance(log, Mapping):
        name = "DataFrame"
        items = [(str(c), log[c].to_numpy()) for c in log.columns]
    elif isinstance(log, Mapping):
        name = "dict"
        items = [(str(k), np.asarray(v)) for k, v in log.items()]
    else:
        raise TypeError(
            f"a log is a path, a pandas DataFrame or a dict of arrays, not {type(log).__name__}"
        )
    table = []
    for col, a in items:
        if a.ndim != 1:
            raise ValueError(f"{name}: column `{col}` is not one-dimensional (shape {a.shape})")
        if a.dtype.kind in "biuf":
            table.append((col, np.ascontiguousarray(a, dtype=np.float64).tobytes()))
        else:
            table.append((col, _cells(a)))
    return (name, table)


def _column(name: str, numbers: Optional[bytes], text: Optional[List[str]]) -> np.ndarray:
    if numbers is not None:
        return np.frombuffer(numbers, dtype=np.float64).copy()
    for dtype in (np.int64, np.float64):
        try:
            return np.array(text, dtype=dtype)
        except ValueError:
            pass
    return np.array(text, dtype=object)


def _optional(module: str, extra: str, what: str) -> Any:
    """Imports an optional dependency, or raises an ImportError that says how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise ImportError(
            f"{what} needs {module}, which is not installed: pip install 'vfp[{extra}]' "
            f"(from a clone of the repository: pip install './python[{extra}]')"
        ) from err


def _table(out: Tuple[list, List[str]], as_frame: bool) -> Any:
    columns, comments = out
    table = {name: _column(name, nums, text) for name, nums, text in columns}
    if not as_frame:
        return table
    pd = _optional("pandas", "pandas", "as_frame=True")

    frame = pd.DataFrame(table)
    frame.attrs["comments"] = comments
    return frame


def read_log(
    path: Log,
    columns: Optional[str] = None,
    as_frame: bool = False,
    chamber_base: int = 0,
) -> Any:
    """Read a log into its columns, in the log format's names and units.

    Returns a dict of 1-D numpy arrays: ``time_s`` (s), ``chamber`` (0..=2, as float),
    ``volume_mm3`` (mm³), ``flow_mm3_s`` (mm³/s; present when the log has flow, NaN where a row
    has none), ``pressure_kpa`` (kPa), ``force_n`` (N; when recorded), then the extra columns
    (integers, floats or text). With ``as_frame=True`` a pandas DataFrame (its
    ``attrs["comments"]`` holds the ``#`` comment lines). ``columns=`` and ``chamber_base=`` are
    the command's ``--columns`` and ``--chamber-base``.
    """
    data = _data(columns, chamber_base)
    return _table(_native.read_log(_source(path), data), as_frame)


def identify(
    log: Log,
    families: Optional[Sequence[str]] = None,
    holdout_every: int = 5,
    chamber: Optional[int] = None,
    *,
    columns: Optional[str] = None,
    chamber_base: int = 0,
    derive_flow: bool = False,
    diff_half_width: int = 2,
    deadband: Optional[float] = None,
    weights: Tuple[float, float, float] = (0.0, 0.0, 1.0),
    max_n: int = 7,
    max_m: int = 7,
    prune: int = 3,
) -> Dict[str, Any]:
    """Identify volume-flow-pressure models (the paper's Tables I, II and IV): ``vfp identify --json``.

    ``families``: any of ``"exp"``, ``"nn"``, ``"poly"``, ``"poly-ar"`` (default: all).
    ``holdout_every``: one cycle in every K held out (0: none). ``chamber``: 0..=2 (default:
    every chamber in the log). ``weights``: w1, w2, w3 of the joint cost
    J = w1·RMSE + w2·(1 − R²adj) + w3·AICc (eq. 8). ``max_n``, ``max_m``: highest powers of v and
    v̇ in the polynomial sweep (1..=7). ``prune``: least significant terms tried in Table IV.

    Returns the command's document: ``file``, ``weights``, ``selected`` (the first chamber's
    lowest-cost model: ``family``, shape, ``nu`` parameters, ``rmse`` in kPa, ``r2_adj``,
    ``aicc``, ``bic``, held-out scores), ``models`` (every fitted model, tagged with its chamber),
    ``timing_s`` (wall seconds per family, the only numbers that differ between runs) and
    ``chambers`` (per-chamber reports).
    """
    w = tuple(float(x) for x in weights)
    if len(w) != 3 or not all(np.isfinite(x) and x >= 0 for x in w):
        raise ValueError(f"weights {weights!r}: expected 3 finite numbers >= 0")
    if not (1 <= max_n <= 7 and 1 <= max_m <= 7):
        raise ValueError(f"max_n {max_n} max_m {max_m}: degrees must be 1..=7")
    if isinstance(families, str):
        families = [families]
    data = _data(columns, chamber_base, holdout_every, derive_flow, diff_half_width, deadband)
    text = _native.identify(
        _source(log),
        data,
        chamber,
        None if families is None else list(families),
        w,
        max_n,
        max_m,
        prune,
    )
    return json.loads(text)


def diagnose(
    log: Log,
    chamber: Optional[int] = None,
    model: Optional[Tuple[int, int]] = None,
    alpha: float = 1e-3,
    min_gain: float = 0.01,
    effects: Optional[Sequence[str]] = None,
    validate: Optional[Log] = None,
    *,
    holdout_every: int = 5,
    columns: Optional[str] = None,
    chamber_base: int = 0,
    derive_flow: bool = False,
    diff_half_width: int = 2,
    deadband: Optional[float] = None,
    residuals: bool = False,
) -> Any:
    """Trace a model's residual to physical effects it lacks: ``vfp diagnose --json``.

    Runs on one chamber (``chamber``, default the lowest in the log). ``model``: the baseline
    polynomial's (n, m), default the shape the polynomial sweep selects by training AICc.
    ``alpha``: level of the nested F-test. ``min_gain``: smallest relative held-out RMSE gain for
    an effect to be kept. ``effects``: restrict the candidates (names as the command's
    ``--effect``, e.g. ``"hysteresis"``, ``"sensor-lag"``). ``holdout_every`` must be at least 2.

    Returns the command's document: ``baseline`` (``n``, ``m``, ``nu``, ``rmse_train`` and
    ``rmse_heldout`` in kPa), ``effects`` (kept effects in order, with their parameters and
    units), ``final`` (the final model's RMSEs in kPa), ``remaining``, ``before`` / ``after``
    (held-out residual summaries), ``log``, ``chamber``, ``split``. ``validate``: another log of
    the same rig (path, DataFrame or dict, read with the same options): the document then has
    ``validation`` (``vfp diagnose --validate``): the models fitted on ``log`` evaluated on every
    row of the other, nothing refitted (``baseline_rmse``, ``final_rmse``, ``steps`` per kept
    effect, in kPa; ``clock_bound``: effects evaluated on the other log's own clock).

    With ``residuals=True`` returns ``(document, residuals)``: ``residuals["before"]`` (the
    baseline) and ``residuals["after"]`` (the final model) each hold the held-out samples'
    ``time_s`` (s), ``volume_mm3`` (mm³), ``flow_mm3_s`` (mm³/s) and ``residual_kpa`` (measured
    − predicted pressure, kPa) as numpy arrays: what the command's ``--plots`` figures show.
    """
    if not (0.0 < alpha < 1.0):
        raise ValueError(f"invalid option: --alpha must lie in (0, 1), got {alpha}")
    if not (0.0 <= min_gain < 1.0):
        raise ValueError(f"invalid option: --min-gain must lie in [0, 1), got {min_gain}")
    if holdout_every < 2:
        raise ValueError("invalid option: --holdout-every must be at least 2")
    if model is not None:
        n, m = model
        if not (1 <= n <= 7 and 1 <= m <= 7):
            raise ValueError(f"model {model!r}: expects (N, M) with 1 <= N, M <= 7")
        model = (int(n), int(m))
    if isinstance(effects, str):
        effects = [effects]
    data = _data(columns, chamber_base, holdout_every, derive_flow, diff_half_width, deadband)
    text, before, after = _native.diagnose(
        _source(log),
        data,
        chamber,
        model,
        float(alpha),
        float(min_gain),
        None if effects is None else list(effects),
        None if validate is None else _source(validate),
    )
    doc = json.loads(text)
    if not residuals:
        return doc

    def points(raw: bytes) -> Dict[str, np.ndarray]:
        a = np.frombuffer(raw, dtype=np.float64).reshape(-1, 4)
        names = ("time_s", "volume_mm3", "flow_mm3_s", "residual_kpa")
        return {k: a[:, i].copy() for i, k in enumerate(names)}

    return doc, {"before": points(before), "after": points(after)}


def simulate(
    preset: str = "paper",
    cycles: Optional[int] = None,
    seed: Optional[int] = None,
    flows: Optional[Sequence[float]] = None,
    as_frame: bool = False,
) -> Any:
    """Run the firmware's own tasks against the simulated rig: the log ``vfp simulate`` writes.

    ``preset``: ``"paper"`` (the paper's protocol on SBA1), ``"air:MM3"`` (an air pocket of MM3
    mm³ in every syringe), ``"design:sba1"`` .. ``"design:sba4"``, ``"effect:NAME"`` (one plant
    effect), ``"force"`` (1 Hz pushes at 500 mm³, with truth). ``cycles``: cycles per flow rate.
    ``flows``: flow rates in mm³/s. ``seed``: the sensor noise's seed (the same seed gives the
    same log). Returns the log as :func:`read_log` does (the simulator's truth in extra columns:
    ``force_n`` in N, true volume, flow and pressure).
    """
    if cycles is not None and not (0 <= cycles <= 65535):
        raise ValueError(f"cycles {cycles}: 1..=65535")
    out = _native.simulate(
        preset,
        cycles,
        None if flows is None else [float(f) for f in flows],
        seed,
    )
    return _table(out, as_frame)


def export(
    log: Log,
    n: Optional[int] = None,
    m: Optional[int] = None,
    p: int = 0,
    chamber: Optional[int] = None,
    all_samples: bool = False,
    format: str = "lines",
    *,
    holdout_every: int = 5,
    columns: Optional[str] = None,
    chamber_base: int = 0,
    derive_flow: bool = False,
    diff_half_width: int = 2,
    deadband: Optional[float] = None,
) -> Union[List[str], str]:
    """Identify each chamber's polynomial (or poly-AR) model in the device's form: ``vfp export``.

    ``n``, ``m``: highest powers of v (mm³) and v̇ (mm³/s), both or neither (default: the AICc
    selection among shapes the device's f32 arithmetic evaluates faithfully). ``p``: AR order
    0..=5. ``all_samples``: fit on all samples instead of the training cycles. ``format``:
    ``"lines"`` gives the serial command lines (``--format lines``), ``"rust"`` the Rust
    constants (``--format rust``), as lists of lines / one string, f32 warnings included as
    ``//`` comments like the command's. The command's ``--augmented`` is not offered here yet.
    """
    if format not in ("lines", "rust"):
        raise ValueError(f"format {format!r}: 'lines' or 'rust'")
    data = _data(columns, chamber_base, holdout_every, derive_flow, diff_half_width, deadband)
    out = _native.export(_source(log), data, chamber, (n, m), p, all_samples)
    lines: List[str] = []
    rust = ""
    for ch, warning, cmd, consts in out:
        if warning is not None:
            lines.append(f"// chamber {ch}: {warning}")
            rust += f"// {warning}\n"
        lines.extend(cmd)
        rust += consts
    return lines if format == "lines" else rust


def force(
    ident: Log,
    test: Log,
    augmented: bool = False,
    *,
    n: int = 3,
    m: int = 2,
    area: Union[float, Sequence[float]] = 22.0,
    smooth: int = 1,
    holdout_every: int = 5,
    columns: Optional[str] = None,
    chamber_base: int = 0,
    derive_flow: bool = False,
    diff_half_width: int = 2,
    deadband: Optional[float] = None,
) -> Dict[str, Any]:
    """External force from pressure residuals (paper §IV-C, Fig. 8): ``vfp force --json``.

    One polynomial (``n``, ``m``) per chamber is identified on the force-free log ``ident``;
    on ``test`` the measured minus predicted pressure (kPa) times the effective area (mm², one
    for all chambers or one per chamber) is summed over chambers: the force in N.
    ``smooth``: centred moving average over this many samples. Returns the command's report
    (forces in N, pressures in kPa). ``augmented=True``: ``vfp force --augmented --json``, the
    models the board would run (per chamber the residual loop on ``ident`` with baseline
    (``n``, ``m``), built as ``vfp export --augmented`` builds them, ``test`` replayed through the
    firmware's estimator); the report adds ``augmented`` (effects per chamber) and
    ``no_estimate``.
    """
    if augmented and holdout_every < 2:
        raise ValueError(
            f"invalid option: --holdout-every {holdout_every}: --augmented compares models on held-out cycles (2 or more)"
        )
    areas = [float(area)] if np.isscalar(area) else [float(a) for a in area]
    if len(areas) not in (1, 3) or not all(np.isfinite(a) and a > 0 for a in areas):
        raise ValueError(
            f"invalid option: --area {areas}: give one positive area in mm2 for all chambers or three (a,b,c)"
        )
    if smooth < 1:
        raise ValueError("invalid option: --smooth 0: the window is at least 1 sample")
    data = _data(columns, chamber_base, holdout_every, derive_flow, diff_half_width, deadband)
    text = _native.force(_source(ident), _source(test), data, (n, m), areas, smooth, augmented)
    return json.loads(text)


def replay(
    model: Union[str, "os.PathLike[str]", Sequence[str]],
    log: Log,
    *,
    frames: bool = False,
    as_frame: bool = False,
    holdout_every: int = 5,
    columns: Optional[str] = None,
    chamber_base: int = 0,
    derive_flow: bool = False,
    diff_half_width: int = 2,
    deadband: Optional[float] = None,
) -> Any:
    """What the board would have estimated on a log: ``vfp replay MODEL LOG --json``.

    ``model``: the lines ``export()`` returns (a list of ``str``) or the path of a file of
    ``vfp export`` output. The log's frames go through the firmware's own estimator (the code the
    board runs, its f32 arithmetic, the effect chain included). Returns the command's summary:
    per chamber the P̂ RMSE against the measured pressure (kPa), over all frames and the held-out
    cycles, and the force error against ``force_n`` (N) when the log has one.

    With ``frames=True`` returns ``(summary, frames)``: ``frames`` a dict of numpy arrays (a
    pandas DataFrame with ``as_frame=True``) with ``time_s`` (s), per chamber ``p_i``,
    ``p_hat_i``, ``residual_i``, ``load_i`` (kPa; the residual with the chain's sensor lag
    undone, what the force is made of), ``k_i`` (kPa/mm³), ``c_i`` (kPa·s/mm³), then ``force_n``
    and ``force_ref_n`` (N; NaN where the log has none).
    """
    if isinstance(model, (str, os.PathLike)):
        name = os.fspath(model)
        with open(name, encoding="utf-8") as f:
            text = f.read()
    else:
        name = "model lines"
        text = "\n".join(model)
    data = _data(columns, chamber_base, holdout_every, derive_flow, diff_half_width, deadband)
    summary, cols = _native.replay(text, name, _source(log), data)
    doc = json.loads(summary)
    if not frames:
        return doc
    return doc, _table((cols, []), as_frame)
