"""Varied trellis posts: wood, concrete or metal, round or square, thicker end posts on anchors.

Real rows are carried by whatever the grower bought: grey-brown wooden stakes, pale square
concrete posts, thin galvanised or painted steel profiles; the row's end posts are thicker and
often lean outwards, held by a wire to a ground anchor. A model that saw one kind of pole only
takes the others for trunks. Posts are obstacles, never vegetation; each material keeps its own
colour (a `backdrop`-kind chunk: own texture and tint, re-tinted a little per episode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from segmin.data.synth.mesh import Mesh, cylinders

# Per material: RGB tint ranges (low, high) on the texture it uses, and a radius factor.
POST_TINTS = {
    "wood": ((0.35, 0.25, 0.16), (0.75, 0.62, 0.48)),  # weathered brown to silver-grey, on the structure texture
    "concrete": ((0.62, 0.62, 0.6), (0.9, 0.9, 0.86)),
    "metal": ((0.2, 0.24, 0.22), (0.75, 0.78, 0.8)),  # dark painted to galvanised
}
RADIUS_FACTOR = {"wood": 1.0, "concrete": 1.0, "metal": 0.6}
END_POST_FACTOR = 1.35  # end posts carry the wires' pull: thicker
ANCHOR_REACH = (1.0, 1.8)  # anchor stake distance beyond the end post (m)


@dataclass
class PostLook:
    """How one world draws posts of one material."""

    style: str
    tint: tuple[float, float, float, float]
    square: bool


def post_looks(styles: list[str], square_probability: float, rng: np.random.Generator) -> dict[str, PostLook]:
    """One look per material for this world (the renderer varies the tint a little per episode)."""
    looks = {}
    for style in styles:
        lo, hi = (np.asarray(v) for v in POST_TINTS[style])
        t = rng.uniform(0, 1)  # one brightness across the channels: greys stay grey
        r, g, b = (float(v) for v in lo + t * (hi - lo))
        looks[style] = PostLook(style, (r, g, b, 1.0), bool(rng.uniform() < square_probability))
    return looks


def post_mesh(p0: np.ndarray, p1: np.ndarray, radius: float, square: bool) -> Mesh:
    """A post from its foot (below the ground) to its top, capped: square posts are 4-sided prisms."""
    r = radius * (np.sqrt(2) if square else 1.0)  # a square's corners lie on the circle
    return cylinders(p0, p1, r, r * 0.95, 4 if square else 6, caps=True)


def anchor(top: np.ndarray, foot: np.ndarray, outward: np.ndarray, ground, rng: np.random.Generator) -> list[Mesh]:
    """An anchor wire from near an end post's top to a stake in the ground beyond the row end.

    `ground(x, y)` is the terrain height; the wire comes in 1 m pieces (each triangle's screen box
    is what TinyRenderer pays for)."""
    reach = rng.uniform(*ANCHOR_REACH)
    xy = foot[:2] + outward[:2] * reach
    stake = np.array([xy[0], xy[1], float(ground(xy[0], xy[1]))])
    start = foot + 0.85 * (top - foot)
    n = max(2, int(np.ceil(np.linalg.norm(start - stake))) + 1)
    pts = start[None, :] + np.linspace(0, 1, n)[:, None] * (stake - start)[None, :]
    return [
        cylinders(pts[:-1], pts[1:], 0.006, 0.006, 3),
        cylinders(stake - [0, 0, 0.1], stake + [0, 0, 0.12], 0.03, 0.03, 4, caps=True),
    ]
