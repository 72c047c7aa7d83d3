"""SegCorridor: a fourth navigator, beyond the paper, that steers along the corridor's centreline.

SegMin and SegMinD steer to the image column with the least near vegetation: the far end of the
visible corridor, so the robot cuts bends, and under merged crowns the column sits wherever the
canopy is thinnest. SegCorridor uses what they throw away, the depth of each vegetation pixel and
the known camera, which place the pixel on the ground in the robot frame (x forward, y left,
h up; levelled with the IMU's roll and pitch when the robot has one). Per command:

1. the fused mask's pixels with valid depth, every `stride`-th, back-projected and kept in range
   (`x_min`..`x_max`, `h_min`..`h_max`, near the split line: the previous centreline, or the ray
   through SegMinD's column);
2. split into the left and the right row, fitted as parallel curves, trimmed of outliers, the
   bend kept only when both rows show it (`row_fit`);
3. the centreline between them (or one row moved by half the running width), averaged with the
   previous one (`centre_memory`);
4. under a roof (`roof_share` of the points above `roof_min_height`): SegMinD when the roof has an
   opening along the corridor, else the rows' trunks (`trunk_mode`);
5. pure pursuit to the centreline at `lookahead`, or `centre_hold` on a skid-steer robot
   (`steering`); no centreline: SegMinD's column and control law (the fallback). The paper's
   EMA smooths every command.

The equations, the reasons for each choice and the measurements behind them:
docs/reference/equations.md (SegCorridor), docs/results/history/segcorridor.md.
`CorridorNavigator` is a `MaskNavigator` (nav_eval.runtime.protocols) like the paper's
`Navigator`: it declares what it reads besides the masks (`inputs`: depth, the image, the IMU's
attitude and its camera), and its per-run statistics are the shares of commands found on one
row, on the trunks and by the fallback.
"""

from __future__ import annotations

from ..camera import CameraGeometry
from .config import CONTROLLERS, ROOF_BIN, CorridorConfig
from .navigator import MODES, OBSERVED_MODES, CorridorCommand, CorridorNavigator
from .row_fit import RowsFit, fit_parallel_rows, polyval

__all__ = [
    "CONTROLLERS",
    "MODES",
    "OBSERVED_MODES",
    "ROOF_BIN",
    "CameraGeometry",
    "CorridorCommand",
    "CorridorConfig",
    "CorridorNavigator",
    "RowsFit",
    "fit_parallel_rows",
    "polyval",
]
