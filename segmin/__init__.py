"""segmin: shared utilities (config, atomic files) and the `segmin` command line."""

__version__ = "0.1.0"
