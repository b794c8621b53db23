"""The trials report without matplotlib (the `trials` extra): report.html keeps its tables and says what draws the
figures, and `trials run` / `trials report` print one line naming `pip install 'viva-sitl[trials]'`. A real one-trial
run of the CLI over the synthetic field, in a Python where importing matplotlib fails as if it were not installed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from viva_sitl.evaluation.report import FIGURES_HINT, figures_missing_note

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "configs" / "trials" / "synthetic_emergency.toml"
NOTE = "note: report.html has no figures: they need matplotlib (pip install 'viva-sitl[trials]')"
# sys.modules[name] = None makes `import name` raise ImportError, as an absent package does
WITHOUT_MATPLOTLIB = (
    "import sys; sys.modules['matplotlib'] = None; from viva_sitl.cli import main; raise SystemExit(main())"
)


def _cli_without_matplotlib(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", WITHOUT_MATPLOTLIB, *args], cwd=REPO, capture_output=True,
                          text=True, timeout=180)  # fmt: skip


def test_report_without_matplotlib_names_the_trials_extra(tmp_path: Path) -> None:
    assert FIGURES_HINT == "pip install 'viva-sitl[trials]'"
    out = tmp_path / "run"
    r = _cli_without_matplotlib("trials", "run", str(SPEC), "--pilot", "descend", "--n", "1", "--jobs", "1",
                                "-o", str(out), "--no-progress")  # fmt: skip
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert [ln.strip() for ln in lines].count(NOTE) == 1, r.stdout
    assert "Traceback" not in r.stderr, r.stderr
    page = (out / "report.html").read_text()
    assert f"figures need matplotlib: <code>{FIGURES_HINT}</code>" in page
    assert "<img" not in page and "id='scores'" in page and "id='worst'" in page  # tables kept, no figures

    r = _cli_without_matplotlib("trials", "report", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == NOTE, r.stdout


def test_no_note_when_matplotlib_is_installed() -> None:
    pytest.importorskip("matplotlib")
    assert figures_missing_note() is None
