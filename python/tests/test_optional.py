"""The core package needs numpy only: pandas and matplotlib are extras (`vfp[pandas]`,
`vfp[plot]`), and a function that needs a missing one says which extra to install."""

import subprocess
import sys

import pytest

import vfp
from conftest import ROOT

LOG = "data/real/bag-lung-pip15-peep5.csv"


def test_the_package_imports_without_pandas_or_matplotlib():
    # A fresh interpreter in which importing either fails, as in a venv without them.
    code = (
        "import sys\n"
        "sys.modules['pandas'] = None\n"
        "sys.modules['matplotlib'] = None\n"
        "import vfp\n"
        f"table = vfp.read_log({LOG!r})\n"
        "assert 'pressure_kpa' in table, sorted(table)\n"
        "print('ok')\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_a_missing_pandas_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError) as err:
        vfp.read_log(LOG, as_frame=True)
    message = str(err.value)
    assert "as_frame=True needs pandas" in message
    assert "pip install 'vfp[pandas]'" in message
    assert "./python[pandas]" in message
