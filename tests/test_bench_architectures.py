"""`python -m benchmarks architectures`: every candidate exported, inspected and timed against the full network."""

from __future__ import annotations

import json

import pytest

from benchmarks.cli import main as benchmarks_main

pytestmark = pytest.mark.usefixtures("one_thread")


def test_model_speed_reports_each_cut_against_the_full_network(tmp_path, capsys) -> None:
    out = tmp_path / "speed.json"
    args = ["architectures", "--architectures", "lraspp_mobilenet_v3_large_cut10", "--sizes", "64", "32"]
    assert benchmarks_main([*args, "--runs", "8", "--threads", "1", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    rows = summary["rows"]
    assert set(rows) == {
        "lraspp_mobilenet_v3_large @ 64",
        "lraspp_mobilenet_v3_large @ 32",
        "lraspp_mobilenet_v3_large_cut10 @ 64",
        "lraspp_mobilenet_v3_large_cut10 @ 32",
    }
    full, cut = rows["lraspp_mobilenet_v3_large @ 64"], rows["lraspp_mobilenet_v3_large_cut10 @ 64"]
    assert full["ratio"] == 1.0 and summary["baseline"] == "lraspp_mobilenet_v3_large @ 64"
    assert cut["params"] < full["params"] / 10 and cut["file_mb"] < full["file_mb"] / 5
    assert 0 < cut["conv_gflop"] < full["conv_gflop"] and full["ratio_min"] == 1.0
    assert cut["graph"]["nodes"] < full["graph"]["nodes"] and full["graph"]["Conv+HardSwish"] > 0
    assert all(row["runs"] == 8 and row["median_ms"] > 0 for row in rows.values())
    printed = capsys.readouterr().out
    assert "load average" in printed and "targets: not checked" in printed and "(of min)" in printed


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--architectures", "resnet50"], "--architectures='resnet50': unknown architecture"),
        (["--sizes", "100"], "--sizes 100: must be >= 32 and a multiple of 16"),
    ],
)
def test_model_speed_refuses_bad_options_in_one_line(extra, message, capsys) -> None:
    assert benchmarks_main(["architectures", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
