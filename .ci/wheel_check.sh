#!/usr/bin/env bash
# What a user installs: build the wheel, install it outside the checkout, run it from an empty folder.
#   1. the wheel holds only segmin/ and its dist-info;
#   2. `pip install <wheel>[all]`: version, shipped configs, a 3-frame render, a 3 m oracle nav-eval,
#      and an ONNX export of a tiny untrained model;
#   3. bare `pip install <wheel>` (the robot runtime): navigator + segmenter on that ONNX file (also by a
#      shipped name, `segmin models list`),
#      `segmin navigate-demo --no-figure`, and the one-line error of a command that needs an extra;
#   4. the robot install for ROS 2 Humble's Python: the wheel admits 3.10, and the dependencies of
#      `pip install segmin`, `segmin[ros]` and `segmin[litert]` (the fast INT8 runtime) resolve for
#      3.10 from the registry (binary wheels only).
# Prints the wheel size, the lean install's size and its import time.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "== wheel"
$PYTHON -m pip wheel --quiet --no-deps -w "$work/dist" . 2>&1 | grep -v "^WARNING: Location" || true
wheel=$(ls "$work"/dist/segmin-*.whl)
$PYTHON - "$wheel" <<'PY'
import sys, zipfile
names = zipfile.ZipFile(sys.argv[1]).namelist()
tops = sorted({n.split("/")[0] for n in names})
print("wheel:", sys.argv[1].rsplit("/", 1)[-1], f"{sum(i.file_size for i in zipfile.ZipFile(sys.argv[1]).infolist()) / 1e6:.2f} MB unpacked, top level:", tops)
assert len(tops) == 2 and tops[0] == "segmin" and tops[1].startswith("segmin-") and tops[1].endswith(".dist-info"), tops
for needed in ("segmin/configs/worlds/straight_vineyard.yaml", "segmin/configs/pipeline/quick.yaml",
               "segmin/data/synth/render.py", "segmin/nav_eval/runtime/navigator.py", "segmin/app/cli.py"):
    assert needed in names, needed
PY
ls -l "$wheel" | awk '{printf "wheel file: %.1f kB\n", $5 / 1024}'

echo "== full install (segmin[all])"
$PYTHON -m venv "$work/full"
"$work/full/bin/pip" install --quiet "$wheel[all]" 2>&1 | grep -v "^WARNING: Location" || true
mkdir "$work/run" && cd "$work/run"
full="$work/full/bin"
"$full/segmin" --version
"$full/segmin" configs list
"$full/segmin" synth render --world straight_vineyard --frames 3 --size 64 --out render --no-progress
test "$(ls render/*/*/images | wc -l)" -ge 1
"$full/segmin" nav-eval --model oracle --fields straight_vineyard --methods segmind --runs 1 --no-plots \
    --no-progress --out nav --set run.length_m=3
grep -q segmind nav/results.csv
"$full/python" - <<'PY'
from segmin.models import build_model
from segmin.models.checkpoint import model_info, save_checkpoint
info = model_info(backbone_weights="none", input_size=(64, 64), family="vineyards", train_data="none", threshold=0.5)
save_checkpoint("tiny.pt", {"model": build_model("none").eval().state_dict(), "model_info": info, "epoch": 0, "metrics": {}})
PY
"$full/segmin" export --checkpoint tiny.pt --out tiny.onnx --calib-data render --verify-frames 3 > /dev/null
test -s tiny.onnx

echo "== robot runtime (bare pip install <wheel>)"
$PYTHON -m venv "$work/lean"
lean="$work/lean/bin"
"$lean/pip" install --quiet "$wheel" 2>&1 | grep -v "^WARNING: Location" || true
"$lean/python" - <<'PY'
import importlib.metadata as md, sys
bad = [str(f) for f in md.files("segmin") if not (str(f).startswith(("segmin/", "segmin-")) or "bin/segmin" in str(f))]
assert not bad, bad
heavy = [m for m in ("torch", "pybullet", "matplotlib", "torchvision") if md.packages_distributions().get(m)]
assert not heavy, f"the bare install pulled in {heavy}"
import numpy as np
from segmin.nav_eval.runtime import Navigator, NavigatorConfig, OnnxSegmenter
mask = OnnxSegmenter("tiny.onnx", threads=1).segment(np.zeros((48, 64, 3), np.uint8))
command = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0)).step(mask, np.full(mask.shape, 3.0, np.float32))
import os, shutil
os.makedirs("shipped", exist_ok=True)
shutil.copy("tiny.onnx", "shipped/vineyards.onnx")
os.environ["SEGMIN_MODELS_DIR"] = "shipped"  # a registry outside the package: a shipped name resolves offline
assert OnnxSegmenter("vineyards", threads=1).path.name == "vineyards.onnx"
loaded = [m for m in ("torch", "pybullet", "matplotlib") if m in sys.modules]
assert not loaded, loaded
print(f"robot runtime: mask {mask.shape}, command v={command.v:.3f} omega={command.omega:.3f}")
PY
SEGMIN_MODELS_DIR=shipped "$lean/segmin" models list
"$lean/segmin" navigate-demo --no-figure --out demo --size 96 | tail -n 3
if "$lean/segmin" train --config quick --out t 2> err.txt; then echo "train ran without torch?"; exit 1; fi
cat err.txt
grep -q "\[train\] extra" err.txt && test "$(wc -l < err.txt)" -eq 1
site=$("$lean/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
echo "lean install: $(du -sm "$site" | cut -f1) MB in site-packages (segmin itself $(du -sk "$site/segmin" | cut -f1) kB)"
"$lean/python" - <<'PY'
import statistics, subprocess, sys, time
code = "import segmin.nav_eval.runtime.navigator, segmin.nav_eval.runtime.segmenter, onnxruntime"
walls = []
for _ in range(5):
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True)
    walls.append(time.perf_counter() - start)
print(f"lean import (navigator + segmenter + onnxruntime, fresh interpreter): median {statistics.median(walls):.2f} s of 5")
PY

echo "== robot install on Python 3.10 (ROS 2 Humble)"
"$lean/python" - <<'PY'
import importlib.metadata as md
from packaging.specifiers import SpecifierSet  # onnxruntime's dependency, so in the bare install
requires = md.metadata("segmin")["Requires-Python"]
assert SpecifierSet(requires).contains("3.10"), f"the wheel's Requires-Python {requires} excludes 3.10"
print(f"Requires-Python: {requires}")
PY
# pip checks the dependencies' Requires-Python against --python-version (not the named wheel's: above).
if ! $PYTHON -m pip install --dry-run --ignore-installed --quiet --python-version 3.10 --only-binary=:all: \
    --target "$work/py310" --report "$work/py310.json" "$wheel" "$wheel[ros,litert]" > "$work/py310.log" 2>&1; then
    grep -v "^WARNING: Location" "$work/py310.log"
    echo "the robot install (segmin, segmin[ros,litert]) does not resolve for Python 3.10"
    exit 1
fi
$PYTHON - "$work/py310.json" <<'PY'
import json, sys
chosen = sorted(f"{item['metadata']['name']}=={item['metadata']['version']}" for item in json.load(open(sys.argv[1]))["install"])
print("resolved for Python 3.10:", " ".join(chosen))
PY
echo "wheel checks passed"
