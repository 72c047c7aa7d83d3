"""Shared checks for the sweep tests (parameter sweeps and families of worlds)."""

from __future__ import annotations

from pathlib import Path

from segmin.app.cli import main

# A run that costs little: 1 m, 64 x 64 frames.
TINY = ["run.length_m=1.0", "perception.width=64", "perception.height=64", "run.time_limit_s=12"]


def assert_refused_before_any_run(spec: str, out: Path, capsys, words: list[str]) -> None:
    """`segmin robustness SPEC` exits 2 with one line naming the spec file and every word, and
    writes nothing."""
    assert main(["robustness", spec, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert spec in err, err
    for word in words:
        assert word in err, (word, err)
    assert not out.exists()  # nothing written, no run started
