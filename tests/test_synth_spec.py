"""World specs: shipped YAMLs validate, bad specs fail with a message naming the field."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from synth_helpers import tiny, write_spec

from segmin.common.config import ConfigError
from segmin.data.synth.spec import TEST_FIELDS, load_world_spec, spec_from_dict

WORLDS = Path(__file__).resolve().parents[1] / "configs" / "worlds"


def test_shipped_worlds_validate_and_cover_the_test_fields():
    names = sorted(p.stem for p in WORLDS.glob("*.yaml"))
    assert set(TEST_FIELDS) <= set(names)
    families = {}
    for name in names:
        spec = load_world_spec(name)
        assert spec.name == name
        assert spec.rows.length >= 22.0, f"{name}: rows too short for a 20 m drive plus margin"
        families.setdefault(spec.family, []).append(spec)
    # Training worlds exist for both crop families and never reuse a test field's seed.
    test_seeds = {load_world_spec(n).seed for n in TEST_FIELDS}
    train = [load_world_spec(n) for n in names if n.startswith("train_")]
    assert {s.family for s in train} == {"vineyards", "trees"}
    assert not test_seeds & {s.seed for s in train}
    assert len({s.domain for s in train}) == len(train)


def test_paper_geometry_of_the_test_fields():
    expect = {  # Table 1: row distance, plant distance, height
        "straight_vineyard": (1.8, 1.3, 2.0),
        "curved_vineyard": (1.8, 1.3, 2.0),
        "pergola_vineyard": (6.0, 1.5, 2.9),
        "pear_field": (2.0, 1.0, 2.9),
        "high_trees": (7.0, 5.0, 12.5),
    }
    for name, (rows, plants, height) in expect.items():
        spec = load_world_spec(name)
        assert spec.rows.spacing == rows and spec.plants.spacing == plants
        assert spec.plants.height[0] - 0.25 <= height <= spec.plants.height[1] + 0.25
        assert spec.terrain.roughness > 0, f"{name}: terrain must be uneven"
    assert load_world_spec("curved_vineyard").rows.curve_radius != 0
    assert load_world_spec("pergola_vineyard").structures.pergola
    assert load_world_spec("pergola_vineyard").structures.free_band_offset != 0  # asymmetric
    assert load_world_spec("pear_field").plants.low_branches[1] > 0


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"rows": {"spacing": -1.0}}, "rows.spacing"),
        ({"plants": {"spacing": 0.0}}, "plants.spacing"),
        ({"rows": {"spacing": 0.05}}, "rows.spacing"),  # trunks of neighbouring rows would touch
        ({"rows": {"curve_radius": 1.5}}, "rows.curve_radius"),  # inner rows would cross
        ({"plants": {"height": [2.0, 1.0]}}, "plants.height"),
        ({"rows": {"polyline": [[0, 0], [3, 0], [3, 3], [10, 3]]}}, "rows.polyline"),  # sharp turn
        ({"rows": {"colour": 3}}, "colour"),  # unknown key
        ({"terrain": {"roughness": -0.1}}, "terrain.roughness"),
        ({"family": "cereals"}, "family"),
        ({"structures": {"pergola": True, "free_band_width": 1.9}}, "free_band_width"),
    ],
)
def test_invalid_specs_name_the_field(changes, field):
    with pytest.raises(ConfigError) as info:
        spec_from_dict(tiny(**changes))
    assert field in str(info.value)


def test_missing_field_and_unknown_world(tmp_path):
    raw = tiny()
    del raw["seed"]
    with pytest.raises(ConfigError, match="seed"):
        load_world_spec(write_spec(tmp_path / "w.yaml", raw))
    with pytest.raises(ConfigError, match="not found"):
        load_world_spec("no_such_world")


def test_overrides_and_default_domain(tmp_path):
    spec = load_world_spec(write_spec(tmp_path / "w.yaml", tiny()), ["rows.length=9.5"])
    assert spec.rows.length == 9.5
    assert spec.domain == "synth_tiny_vineyard"
    assert spec.eval_gap == 1


def test_a_sharp_corner_between_long_segments_is_refused():
    """The turn check averaged the segment lengths, so a 60 degree corner between
    30 m segments passed although the rows cross at the corner."""
    corner = [[0, 0], [30, 0], [30 + 30 * math.cos(math.pi / 3), 30 * math.sin(math.pi / 3)]]
    with pytest.raises(ConfigError, match=r"rows.polyline: turns by 60.0 deg at point 1"):
        spec_from_dict(tiny(rows={"polyline": corner, "length": 20.0}))
    arc = [[40.0 * math.sin(t), 40.0 * (1 - math.cos(t))] for t in np.linspace(0, 0.6, 60)]
    spec_from_dict(tiny(rows={"polyline": arc, "length": 20.0}))  # a smooth bend stays fine


def test_a_gap_narrower_than_the_robot_is_refused():
    """Rows.spacing=0.3 (less than the robot's width) was accepted."""
    from segmin.data.synth.spec import MIN_GAP_WIDTH
    from segmin.nav_eval.sim.robot import RobotConfig

    assert RobotConfig().width < MIN_GAP_WIDTH  # the constant data keeps agrees with the robot
    with pytest.raises(ConfigError, match="rows.spacing: 0.3 m leaves a free gap"):
        spec_from_dict(tiny(rows={"spacing": 0.3}))
    with pytest.raises(ConfigError, match="rows.spacing"):  # hedges 0.6 m wide leave 0.5 m
        spec_from_dict(tiny(rows={"spacing": 1.1}, plants={"canopy_width": [0.5, 0.6]}))
