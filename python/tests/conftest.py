"""Shared helpers: the repository root and the `vfp` command-line tool to compare against.

The tool is `$VFP_BIN` when set, else the workspace's dev build (`target/debug/vfp`, built by
`cargo test` / `.ci/run` before this suite), else `cargo run -p vfp`. It runs in the repository
root, and the Python calls name logs by the same relative paths, so the documents' `file`/`log`
fields agree too.
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _vfp_command():
    env = os.environ.get("VFP_BIN")
    if env:
        return [env]
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    built = target / "debug" / "vfp"
    if built.exists():
        return [str(built)]
    if shutil.which("cargo") is None:
        pytest.skip("no vfp binary and no cargo to build one")
    return ["cargo", "run", "--locked", "-q", "-p", "vfp", "--bin", "vfp", "--"]


def run_cli(*args, ok=True):
    """Runs `vfp ARGS` in the repository root; returns the completed process."""
    out = subprocess.run(
        _vfp_command() + [str(a) for a in args],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if ok:
        assert out.returncode == 0, f"vfp {' '.join(map(str, args))} failed:\n{out.stderr}"
    return out


def cli_json(*args):
    return json.loads(run_cli(*args, "--json").stdout)


@pytest.fixture(autouse=True)
def in_root(monkeypatch):
    """Every test runs in the repository root (relative log paths as the tool sees them)."""
    monkeypatch.chdir(ROOT)


def strip_timing(v):
    """The document without `timing_s` members (wall-clock seconds) at any depth."""
    if isinstance(v, dict):
        return {k: strip_timing(x) for k, x in v.items() if k != "timing_s"}
    if isinstance(v, list):
        return [strip_timing(x) for x in v]
    return v
