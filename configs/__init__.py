"""Shipped configuration files (YAML): worlds, training recipes, nav-eval settings, pipeline profiles.

Installed as `segmin.configs` and read with `importlib.resources` (see `segmin.common.shipped`),
so a wheel carries them; this file only makes the folder a package.
"""
