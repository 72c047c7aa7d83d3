"""The ground layer: strict configs, atomic files and small helpers every package shares.

Nothing here imports any other part of segmin, so every layer above may import it.
"""
