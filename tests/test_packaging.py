"""The install a robot gets: the bare `pip install segmin` runs the navigator and the ONNX segmenter.

The robot runtime must not need torch, pybullet or matplotlib. These tests run the runtime in a
fresh interpreter, from an empty folder (so nothing is found through the working directory),
with those modules blocked at import, which is what a machine without the extras looks like.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from importlib.metadata import requires
from pathlib import Path

import numpy as np
import pytest
from export_helpers import SIZE

from segmin.common.extras import EXTRA_OF_MODULE

BLOCKED = (
    "torch",
    "torchvision",
    "pybullet",
    "matplotlib",
    "albumentations",
    "onnx",
    "onnxscript",
    "tensorboard",
    "tqdm",
    "markdown",
)
# Installs a finder that makes the blocked modules unimportable, then runs the given code.
BLOCKER = """
import importlib.abc, sys
BLOCKED = {blocked!r}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None
sys.meta_path.insert(0, Block())
"""


def run_lean(code: str, cwd: Path) -> subprocess.CompletedProcess:
    script = BLOCKER.format(blocked=BLOCKED) + code
    return subprocess.run(
        [sys.executable, "-c", script], check=False, capture_output=True, text=True, timeout=180, cwd=cwd
    )


def test_the_robot_runtime_runs_without_torch_pybullet_or_matplotlib(
    exported: tuple[Path, dict], tmp_path: Path
) -> None:
    model = exported[0]
    rgb = np.random.default_rng(0).integers(0, 256, (SIZE + 16, SIZE, 3), dtype=np.uint8)
    np.save(tmp_path / "rgb.npy", rgb)
    code = f"""
import json, numpy as np
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
segmenter = OnnxSegmenter({str(model)!r}, threads=1)
mask = segmenter.segment(np.load("rgb.npy"))
command = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0)).step(
    mask, np.full(mask.shape, 3.0, np.float32))
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.replay.run import replay
from segmin.nav_eval.replay.sequence import read_sequence
follower = RowFollower(segmenter, Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0)))
out = [follower.step(np.load("rgb.npy"), np.full(mask.shape, 3.0, np.float32), i / 30) for i in range(7)]
assert sum(o.fresh for o in out) == 2 and np.isfinite(out[-1].command.v)
loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
print(json.dumps({{"shape": list(mask.shape), "v": command.v, "loaded": loaded}}))
"""
    result = run_lean(code, tmp_path)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["shape"] == [SIZE + 16, SIZE]
    assert np.isfinite(report["v"])
    assert report["loaded"] == []


def test_robot_commands_run_and_the_others_name_their_extra(tmp_path: Path) -> None:
    code = """
from segmin.app.cli import main
assert main(["navigate-demo", "--no-figure", "--out", "demo", "--size", "64"]) == 0
assert main(["configs", "list"]) == 0
code = main(["train", "--config", "quick", "--out", "run"])
print("train exit", code)
"""
    result = run_lean(code, tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "demo" / "summary.txt").is_file()
    assert not (tmp_path / "demo" / "navigator_demo.png").exists()
    assert "train exit 2" in result.stdout
    error_lines = [line for line in result.stderr.splitlines() if line.startswith("segmin: error:")]
    assert error_lines == [error_lines[0]] and "[train] extra" in error_lines[0], result.stderr
    assert "Traceback" not in result.stderr


def test_the_extras_table_follows_the_package_metadata() -> None:
    """Each module the error table names is a requirement of that extra in pyproject.toml."""
    by_extra: dict[str, set[str]] = {}
    for requirement in requires("segmin") or []:
        match = re.search(r'extra == "([\w-]+)"', requirement)
        if match:
            name = re.split(r"[<>=!~ ;\[]", requirement, maxsplit=1)[0].lower()
            by_extra.setdefault(match.group(1), set()).add(name)
    # Import names that are not their distribution's.
    distribution = {
        "foxglove": "foxglove-sdk",
        "ai_edge_litert": "ai-edge-litert",
        "litert_torch": "litert-torch",
        "ai_edge_quantizer": "ai-edge-quantizer",
    }
    for module, extra in EXTRA_OF_MODULE.items():
        assert distribution.get(module, module) in by_extra[extra], f"{module} is not in the [{extra}] extra"
    base = {re.split(r"[<>=!~ ;\[]", r, maxsplit=1)[0].lower() for r in requires("segmin") or [] if "extra ==" not in r}
    assert base == {"numpy", "opencv-python-headless", "onnxruntime", "pyyaml"}


def test_every_shipped_data_folder_is_packaged() -> None:
    """A new folder of configs or real photos must be listed in pyproject.toml, or the wheel
    silently leaves its files out (setuptools only ships data of listed packages)."""
    import tomllib

    root = Path(__file__).resolve().parent.parent
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    for base, package in (("configs", "segmin.configs"), ("data/real", "segmin.data.real")):
        for folder in sorted((root / base).rglob("*")):
            if not folder.is_dir() or not any(
                f.is_file() and f.suffix in (".yaml", ".png", ".md") for f in folder.iterdir()
            ):
                continue
            name = ".".join([package, *folder.relative_to(root / base).parts])
            assert name in setup["packages"], f"{folder} is not in [tool.setuptools] packages"
            patterns = setup["package-data"].get(name, [])
            for f in folder.iterdir():
                if f.is_file() and f.suffix in (".yaml", ".png", ".md"):
                    assert any(f.match(p) for p in patterns), f"{f} matches no package-data pattern of {name}"


def test_every_code_package_is_packaged() -> None:
    """A new sub-package (a folder with an __init__.py) must be listed in pyproject.toml, or the
    wheel leaves it out and its imports fail only on a user's machine, never in the checkout."""
    import tomllib

    root = Path(__file__).resolve().parent.parent
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    for package, folder in setup["package-dir"].items():
        for init in sorted((root / folder).rglob("__init__.py")):
            name = ".".join([package, *init.parent.relative_to(root / folder).parts])
            assert name in setup["packages"], f"{init.parent} is not in [tool.setuptools] packages"


def test_the_developers_benchmarks_stay_out_of_the_wheel() -> None:
    """benchmarks/ is the repository's, not the users': no package of the wheel is it or maps to it
    (`.ci/wheel_check.sh` checks the built wheel holds only segmin/)."""
    import tomllib

    root = Path(__file__).resolve().parent.parent
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert (root / "benchmarks" / "__main__.py").is_file()
    assert all(package.split(".")[0] == "segmin" for package in setup["packages"])
    assert not any(folder.split("/")[0] == "benchmarks" for folder in setup["package-dir"].values())


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("segmin.nav_eval.navigator", "segmin.nav_eval.runtime.navigator"),
        ("segmin.nav_eval.segmenter", "segmin.nav_eval.runtime.segmenter"),
        ("segmin.nav_eval.corridor", "segmin.nav_eval.runtime.corridor"),
    ],
)
def test_a_moved_module_still_imports_for_one_release_with_a_warning(old: str, new: str) -> None:
    code = (
        "import importlib, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        f"new = importlib.import_module({new!r})\n"
        "names = [n for n in dir(new) if not n.startswith('_')]\n"
        "assert names and all(getattr(old, n) is getattr(new, n) for n in names), names\n"
        "print([str(w.message) for w in caught if w.category is DeprecationWarning])\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert f"{old} moved to {new}" in result.stdout


def test_the_ros2_parameter_files_ship_from_the_ros_package_folder() -> None:
    """The ROS 2 parameter files have one copy, in the ROS 2 package (ros/segmin_ros/config, which
    colcon installs): the wheel installs the same folder as segmin.configs.ros2, and nothing else of
    ros/ (the ROS 2 package is built by colcon, not pip)."""
    import tomllib

    root = Path(__file__).resolve().parent.parent
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert setup["package-dir"]["segmin.configs.ros2"] == "ros/segmin_ros/config"
    assert [name for name, folder in setup["package-dir"].items() if folder.startswith("ros")] == [
        "segmin.configs.ros2"
    ]
    files = sorted((root / "ros" / "segmin_ros" / "config").iterdir())
    assert files and all(any(f.match(p) for p in setup["package-data"]["segmin.configs.ros2"]) for f in files)
    assert not (root / "configs" / "ros2").exists()


def test_the_ros2_package_executable_without_segmin_names_the_pip_install(tmp_path: Path) -> None:
    """segmin_ros does not vendor segmin: in a ROS 2 Python without it, `ros2 run segmin_ros follow`
    says in one line what to install instead of a traceback."""
    follow = Path(__file__).resolve().parent.parent / "ros" / "segmin_ros" / "segmin_ros" / "follow.py"
    code = BLOCKER.format(blocked=("segmin",)) + f"import runpy; runpy.run_path({str(follow)!r}, run_name='__main__')"
    result = subprocess.run(
        [sys.executable, "-c", code, "--params", "x.yaml"],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        "follow: error: segmin_ros needs segmin in the Python of the robot's ROS 2: pip install 'segmin[ros]'"
    ]
