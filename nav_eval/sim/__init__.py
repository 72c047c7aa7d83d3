"""The simulator: a rendered world as a row gap to drive (`row_env.RowEnv`), robot models (kinematic
unicycle and skid-steer with slip), sensors (camera, depth noise, IMU), the simulator's segmenters
(the exact-mask oracle, the ONNX model on rendered frames, a helper thread that segments while
the next frame renders) and the Gymnasium env `segmin/RowFollow-v0`, a thin adapter over it
(registered by `segmin.envs`). What it needs of a world, a renderer and a segmenter is in
`protocols`. Needs the [sim] extra (pybullet, gymnasium)."""
