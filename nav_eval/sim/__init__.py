"""The simulator: a rendered world as a row gap to drive, robot models (kinematic unicycle and
skid-steer with slip), sensors (camera, depth noise, IMU), the oracle segmenter and the
Gymnasium env `segmin/RowFollow-v0`. Needs the [sim] extra (pybullet, gymnasium)."""
