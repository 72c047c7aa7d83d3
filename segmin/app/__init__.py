"""The application layer: the `segmin` command line, the pipeline and the cross-package benches.

It joins every package; no package imports it.
"""
