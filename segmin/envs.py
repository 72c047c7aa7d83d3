"""segmin's Gymnasium environments, registered when this module is imported (the one place that
registers them):

    import gymnasium
    import segmin.envs

    env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard")

or, with no import of segmin at all, `gymnasium.make("segmin.envs:segmin/RowFollow-v0", ...)`
(Gymnasium imports the module before the name). Gymnasium 1.x loads no plugin entry points, so an
import is needed; `import segmin` alone does not register them, because the bare robot install has
no gymnasium.

Registering imports gymnasium only: the env is named by its import path and built, with pybullet
and the simulator, when `gymnasium.make` is called. Needs the [sim] extra.
"""

from __future__ import annotations

try:
    import gymnasium
except ModuleNotFoundError as exc:  # the bare install
    raise ModuleNotFoundError(
        "segmin.envs needs gymnasium, part of the [sim] extra: pip install 'segmin[sim]'", name=exc.name
    ) from exc

ROW_FOLLOW = "segmin/RowFollow-v0"
"""A robot following one row gap of a synth field (`segmin.nav_eval.sim.gym_env.RowFollowEnv`)."""

if ROW_FOLLOW not in gymnasium.registry:  # importing twice (or a reload) registers once
    gymnasium.register(id=ROW_FOLLOW, entry_point="segmin.nav_eval.sim.gym_env:RowFollowEnv")
