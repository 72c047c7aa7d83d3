"""The navigator's optional mask closing (`NavigatorConfig.mask_closing`), at one scale whatever
the camera: `close_mask` closes at `REFERENCE_WIDTH` and scales back.

Its code is segmin's one closing, segmin.common.mask_closing (the label, the simulator and the
navigator close the same way); the names are importable from here as before.
"""

from __future__ import annotations

from segmin.common.mask_closing import REFERENCE_WIDTH, close_mask

__all__ = ["REFERENCE_WIDTH", "close_mask"]
