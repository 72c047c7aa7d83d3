"""Procedural textures (numpy, deterministic per seed) loaded into pybullet.

Plant atlas: left half bark, right half leaves (mottled greens with veins, or autumn tones).
Ground: soil with grass patches. Structures: weathered grey/wood. Files go to a temporary
folder only long enough for `loadTexture` to read them.
"""

from __future__ import annotations

import colorsys
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pybullet as p

from segmin.data.synth.spec import GROUND_STYLE_NAMES

SIZE = 128


def _noise(rng: np.random.Generator, size: int, scales: tuple[int, ...] = (4, 8, 16, 32)) -> np.ndarray:
    """Multi-octave value noise in [0, 1]."""
    out = np.zeros((size, size), np.float32)
    weight = 1.0
    total = 0.0
    for s in scales:
        small = rng.uniform(0, 1, size=(s, s)).astype(np.float32)
        out += weight * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
        total += weight
        weight *= 0.6
    out /= total
    out -= out.min()
    return out / max(float(out.max()), 1e-6)


def _hsv(h_deg: float, s: float, v: float) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb((h_deg % 360) / 360.0, float(np.clip(s, 0, 1)), float(np.clip(v, 0, 1))))


def plant_atlas(rng: np.random.Generator, appearance, autumn: bool, shade: bool = False) -> np.ndarray:
    """RGB uint8 atlas: bark on the left half, leaves on the right half; `shade`: canopy in deep
    shade (under nets, seen against the light), dark and grey-green."""
    size = SIZE
    img = np.zeros((size, size, 3), np.float32)
    half = size // 2
    # Bark: brown-grey with vertical streaks.
    bark_v = rng.uniform(*appearance.bark_value)
    bark = _hsv(rng.uniform(20, 38), rng.uniform(0.25, 0.5), bark_v)
    streaks = cv2.resize(rng.uniform(0, 1, size=(half // 4, 4)).astype(np.float32), (half, size))
    bark_noise = 0.7 + 0.5 * (0.5 * _noise(rng, size)[:, :half] + 0.5 * streaks)
    img[:, :half] = bark[None, None, :] * bark_noise[..., None]
    # Leaves: a base colour, mottling, lighter veins, a few yellow/brown spots.
    if autumn:
        hue = rng.uniform(15, 55)
        sat = rng.uniform(0.55, 0.85)
    else:
        hue = rng.uniform(*appearance.leaf_hue)
        sat = rng.uniform(*appearance.leaf_saturation)
    val = rng.uniform(*appearance.leaf_value)
    if shade:  # drawn after the usual colour: the draws of unshaded variants stay as they were
        sat = rng.uniform(*appearance.shade_saturation)
        val = rng.uniform(*appearance.shade_value)
    mottle = _noise(rng, size, (8, 16, 32, 64))[:, half:]
    hue_field = hue + (mottle - 0.5) * (30 if autumn else 14)
    hsv = np.stack(
        [
            (hue_field % 360) / 2.0,
            np.full_like(mottle, sat) * 255 * (0.85 + 0.3 * mottle),
            np.clip(val * (0.7 + 0.6 * mottle), 0, 1) * 255,
        ],
        axis=-1,
    ).astype(np.float32)
    hsv[..., 1] = np.clip(hsv[..., 1], 0, 255)
    leaf = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB).astype(np.float32) / 255.0
    ys, xs = np.mgrid[0:size, 0:half]
    veins = (np.abs(((xs + ys * 0.6) % 16) - 8) < 0.7) | (np.abs(((xs - ys * 0.6) % 16) - 8) < 0.7)
    leaf[veins] = np.clip(leaf[veins] * 1.25 + 0.03, 0, 1)
    # Fine detail (leaf edges, serration, light through leaves): real canopy has ~4x the rendered one.
    grain = rng.uniform(-1, 1, size=(size, half)).astype(np.float32)
    leaf *= np.clip(1 + appearance.leaf_detail * grain, 0, None)[..., None]
    spots = _noise(rng, size, (16, 32))[:, :half] > 0.92
    leaf[spots] = leaf[spots] * 0.6 + _hsv(35, 0.6, val * 0.9)[None, :] * 0.4
    img[:, half:] = leaf
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


GROUND_STYLES = GROUND_STYLE_NAMES
GROUND_SIZE = 256  # ground texels are ~8 mm at the default 2 m repeat: grass blades stay sharp near the camera


def _blades(rng: np.random.Generator, size: int, length: int) -> np.ndarray:
    """Zero-mean fine detail of grass: per-texel noise smeared along short random-direction strokes.

    Real grass between rows has about three times the fine detail (mean absolute Laplacian) of a
    smooth texture; the model reads fine detail as vegetation, so ground must carry it too.
    """
    white = rng.uniform(-1, 1, size=(size, size)).astype(np.float32)
    out = np.zeros_like(white)
    for angle in rng.uniform(0, np.pi, 3):
        k = np.zeros((length, length), np.float32)
        c = (length - 1) / 2
        for t in np.linspace(-c, c, 2 * length):
            k[int(round(c + t * np.sin(angle))), int(round(c + t * np.cos(angle)))] = 1.0
        pad = length // 2 + 1  # wrap around by hand: the texture tiles, so its detail must too
        big = np.pad(white, pad, mode="wrap")
        out += cv2.filter2D(big, -1, k / k.sum())[pad:-pad, pad:-pad]
    out /= max(float(np.abs(out).max()), 1e-6)
    return out


def _spots(rng: np.random.Generator, size: int, count: int, radius: tuple[int, int]) -> np.ndarray:
    """A float mask of `count` small soft blobs (flowers, clods, fallen leaves, stones)."""
    m = np.zeros((size, size), np.float32)
    for _ in range(count):
        x, y = (int(v) for v in rng.integers(0, size, 2))
        cv2.circle(m, (x, y), int(rng.integers(radius[0], radius[1] + 1)), 1.0, -1)
    return m


def ground_texture(rng: np.random.Generator, appearance, style: str = "patchy") -> np.ndarray:
    """Ground of one style (see GROUND_STYLES), with grass-like fine detail scaled by
    `appearance.ground_detail`; ground is never vegetation in the mask, whatever its colour."""
    size = GROUND_SIZE
    detail = appearance.ground_detail
    soil = _hsv(rng.uniform(20, 38), rng.uniform(0.25, 0.5), rng.uniform(0.3, 0.55))
    grass = _hsv(rng.uniform(65, 110), rng.uniform(0.4, 0.75), rng.uniform(0.35, 0.65))
    straw = _hsv(rng.uniform(38, 55), rng.uniform(0.3, 0.55), rng.uniform(0.5, 0.75))
    patches = _noise(rng, size, (4, 8, 16))
    fine = _noise(rng, size, (32, 64, 128))
    blades = _blades(rng, size, 5 if style != "long" else 9)
    if style == "patchy":  # the original look: soil with patches of grass
        green = rng.uniform(*appearance.ground_green)
        cover = np.clip((patches - (1 - green)) * 4 + 0.5, 0, 1) * (0.6 + 0.4 * fine)
        base = soil[None, None] * (1 - cover[..., None]) + grass[None, None] * cover[..., None]
    elif style == "mown":  # dense short grass, lighter and darker patches, clover
        base = grass[None, None] * (0.8 + 0.4 * patches)[..., None]
        clover = _spots(rng, size, int(rng.integers(0, 60)), (1, 3))
        base = base * (1 - 0.5 * clover[..., None]) + _hsv(rng.uniform(60, 90), 0.3, 0.8) * 0.5 * clover[..., None]
    elif style == "long":  # long grass and weeds: green to straw, dark weed leaves, flowers
        mix = np.clip((patches - rng.uniform(0.3, 0.8)) * 3 + 0.5, 0, 1)[..., None]
        base = grass[None, None] * (1 - mix) + straw[None, None] * mix
        weeds = _spots(rng, size, int(rng.integers(10, 40)), (2, 6))
        base = base * (1 - 0.45 * weeds[..., None])
        flowers = _spots(rng, size, int(rng.integers(0, 80)), (1, 1))
        base = (
            base * (1 - flowers[..., None])
            + _hsv(rng.choice([50, 55, 0]), rng.uniform(0, 0.8), 0.95) * flowers[..., None]
        )
    elif style == "dry":  # dry summer grass: straw with a few green tufts
        cover = np.clip((patches - rng.uniform(0.5, 0.9)) * 4 + 0.5, 0, 1)[..., None]
        base = straw[None, None] * (1 - cover) + grass[None, None] * cover
    elif style == "soil":  # bare or tilled soil: furrows, clods, stones, sparse weeds
        ys = np.arange(size, dtype=np.float32)[:, None]
        furrows = 0.5 + 0.5 * np.sin(ys * (2 * np.pi * rng.integers(2, 9) / size) + 3 * fine)
        base = soil[None, None] * (0.7 + 0.5 * furrows * rng.uniform(0, 1) + 0.3 * patches)[..., None]
        weeds = _spots(rng, size, int(rng.integers(0, 40)), (1, 4))
        base = base * (1 - weeds[..., None]) + grass[None, None] * weeds[..., None]
    elif style == "litter":  # grass or soil with fallen leaves and twigs
        under = grass if rng.uniform() < 0.5 else soil
        base = under[None, None] * (0.8 + 0.4 * patches)[..., None]
        litter = _spots(rng, size, int(rng.integers(60, 250)), (1, 4))
        leaf = _hsv(rng.uniform(15, 45), rng.uniform(0.4, 0.8), rng.uniform(0.35, 0.7))
        base = base * (1 - litter[..., None]) + leaf[None, None] * litter[..., None] * (0.7 + 0.6 * fine[..., None])
    else:
        raise ValueError(f"unknown ground style {style!r}; choose from {', '.join(GROUND_STYLES)}")
    img = base * (0.85 + 0.3 * fine)[..., None] * (1 + detail * blades)[..., None]
    stones = _noise(rng, size, (64, 128)) > 0.95
    img[stones] = img[stones] * 0.5 + 0.3
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def grass_texture(rng: np.random.Generator, appearance) -> np.ndarray:
    """Blades of grass and weeds: greens to straw, streaked along the blade."""
    size = SIZE
    green = _hsv(rng.uniform(55, 100), rng.uniform(0.4, 0.7), rng.uniform(0.35, 0.6))
    straw = _hsv(rng.uniform(38, 50), rng.uniform(0.35, 0.55), rng.uniform(0.5, 0.7))
    mix = np.clip(_noise(rng, size, (4, 8)) - (1 - rng.uniform(0.1, 0.5)) + 0.5, 0, 1)[..., None]
    streaks = cv2.resize(rng.uniform(0.75, 1.15, size=(4, size)).astype(np.float32), (size, size))[..., None]
    img = (green[None, None] * (1 - mix) + straw[None, None] * mix) * streaks
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def lush_grass_texture(rng: np.random.Generator) -> np.ndarray:
    """Young grass and broad-leaved weeds in spring or after rain: bright, saturated greens with
    lighter and darker streaks and a few flowers, as close to the crop's leaves as grass gets."""
    size = SIZE
    green = _hsv(rng.uniform(72, 108), rng.uniform(0.55, 0.85), rng.uniform(0.6, 0.9))
    light = _hsv(rng.uniform(60, 85), rng.uniform(0.45, 0.7), rng.uniform(0.8, 1.0))
    mix = np.clip(_noise(rng, size, (4, 8, 16)) - 0.35, 0, 1)[..., None]
    streaks = cv2.resize(rng.uniform(0.7, 1.2, size=(6, size)).astype(np.float32), (size, size))[..., None]
    img = (green[None, None] * (1 - mix) + light[None, None] * mix) * streaks
    flowers = _noise(rng, size, (32, 64)) > rng.uniform(0.9, 0.97)
    img[flowers] = _hsv(rng.choice([50.0, 55.0, 0.0]), rng.uniform(0.0, 0.9), 0.95)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def structure_texture(rng: np.random.Generator) -> np.ndarray:
    size = SIZE
    base = _hsv(rng.uniform(25, 40), rng.uniform(0.05, 0.25), rng.uniform(0.45, 0.7))
    img = base[None, None] * (0.8 + 0.35 * _noise(rng, size))[..., None]
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def plain_texture(rng: np.random.Generator) -> np.ndarray:
    """Near-white with faint mottling: nets and posts take their colour from the chunk's tint."""
    img = (0.85 + 0.15 * _noise(rng, SIZE, (8, 32)))[..., None] * np.ones(3, np.float32)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def load_textures(client_id: int, images: dict[str, np.ndarray]) -> dict[str, int]:
    """pybullet texture ids of RGB images, through PNG files that live only as long as the load."""
    folder = Path(tempfile.mkdtemp(prefix="segmin_tex_"))
    try:
        ids = {}
        for name, img in images.items():
            path = folder / f"{name}.png"
            cv2.imwrite(str(path), img[:, :, ::-1])
            ids[name] = p.loadTexture(str(path), physicsClientId=client_id)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return ids


class TextureSet:
    """Texture ids loaded into one pybullet client: plant variants, ground variants, structures."""

    def __init__(self, client_id: int, appearance, rng: np.random.Generator) -> None:
        n = appearance.texture_variants
        self.autumn = [bool(rng.uniform() < appearance.autumn_probability) for _ in range(n)]
        # Keep at least one green variant: the default look of a world is summer.
        self.autumn[0] = False
        self.shade = [False] * n  # variant 0 stays in the light too
        if appearance.shade_probability > 0:
            self.shade[1:] = [bool(rng.uniform() < appearance.shade_probability) for _ in range(n - 1)]
        images = {f"plant{i}": plant_atlas(rng, appearance, self.autumn[i], self.shade[i]) for i in range(n)}
        styles = list(appearance.ground_styles)
        self.ground_style = [styles[int(rng.integers(len(styles)))] if i else styles[0] for i in range(n)]
        images.update({f"ground{i}": ground_texture(rng, appearance, self.ground_style[i]) for i in range(n)})
        images.update({f"grass{i}": grass_texture(rng, appearance) for i in range(n)})
        images["structure"] = structure_texture(rng)
        ids = load_textures(client_id, images)
        self.client_id = client_id
        self.plant = [ids[f"plant{i}"] for i in range(n)]
        self.ground = [ids[f"ground{i}"] for i in range(n)]
        self.grass = [ids[f"grass{i}"] for i in range(n)]
        self.structure = ids["structure"]
        # The pixels behind each texture id, for renderers other than pybullet's.
        self.images = {ids[name]: img for name, img in images.items()}
        # Mean colour of each ground texture (0..1), used to paint ground beyond the tiles.
        self.ground_mean = [images[f"ground{i}"].reshape(-1, 3).mean(axis=0) / 255.0 * 0.8 for i in range(n)]
        self._plain: int | None = None
        self._lush: int | None = None

    def plain(self) -> int:
        """The near-white texture of nets and posts, loaded the first time a world needs it (worlds
        without them keep their texture ids as they were); one fixed pattern, the tint varies."""
        if self._plain is None:
            img = plain_texture(np.random.default_rng(0))
            self._plain = load_textures(self.client_id, {"plain": img})["plain"]
            self.images[self._plain] = img
        return self._plain

    def lush(self, rng: np.random.Generator) -> int:
        """The lush grass texture of the strips between the rows, loaded the first time a world
        needs it (drawn from `rng`, the caller's stream); other worlds keep their texture ids."""
        if self._lush is None:
            img = lush_grass_texture(rng)
            self._lush = load_textures(self.client_id, {"lush": img})["lush"]
            self.images[self._lush] = img
        return self._lush
