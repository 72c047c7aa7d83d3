"""Navigation: what the robot runs, and how segmin validates it before a robot does.

One concern per sub-package, lowest first (nothing imports a later one; the architecture test
checks it):

- `runtime`: the robot side, what the bare install ships (numpy, OpenCV, onnxruntime): the
  navigators (SegMin, SegMinD, SegZeros, SegCorridor), the ONNX segmenter and `RowFollower`,
  which turns timed frames into timed commands.
- `replay`: the runtime over recorded sequences (frame folders, videos).
- `demo`: the navigators on analytic scenes, no simulator and no model.
- `seg_eval`: segmentation models scored on labelled photos.
- `sim`: the simulator: worlds as a row to drive, robot models (kinematic, skid-steer), sensors,
  the oracle segmenter, the Gymnasium env.
- `evaluation`: closed-loop jobs, the paper's Table 3 metrics, reports and figures.
- `sweeps`: robustness sweeps of the closed loop, one parameter at a time.
- `bench`: speed figures of the closed loop and of the navigators.

Old module paths that the documentation of earlier releases showed still import, with a
`DeprecationWarning`, for one release.
"""

from segmin.common.moved import install_moved_modules

install_moved_modules(
    __name__,
    {
        "navigator": "runtime.navigator",
        "segmenter": "runtime.segmenter",
        "corridor": "runtime.corridor",
        "gym_env": "sim.gym_env",
    },
)
