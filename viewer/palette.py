"""Colours of the viewer's scene: one per object or per class, dimmed behind query hits,
faded into the background as ghosts age (pure helpers, no viser)."""

from __future__ import annotations

import colorsys
import zlib

Rgb = tuple[int, int, int]

HIT_BOX_RGB: Rgb = (255, 214, 0)
"""Bright yellow: readable against every object colour and the light background."""
DIM_GREY_RGB: Rgb = (150, 150, 150)
"""What dimmed colours are blended towards."""
DIM_KEEP = 0.25
"""Share of an object's own colour left when it is dimmed."""
BACKGROUND_RGB: Rgb = (255, 255, 255)
"""The viewer's background (viser's light theme): what ghosts and move lines fade into."""
GHOST_RGB: Rgb = (120, 120, 120)
"""A fresh ghost: mid grey, plainly not a live object's saturated colour."""
MOVE_LINE_RGB: Rgb = (30, 100, 230)
"""A fresh move line at its new end (blue; its old end is ghost grey, so it reads as an arrow)."""
TARGET_RGB: Rgb = (235, 80, 0)
"""A relational answer's target (the thing asked about): orange, the dashboard's accent."""
ANCHOR_RGB: Rgb = (0, 150, 136)
"""What the target is measured against ("the desk"): teal, far from orange, move-line blue
and the hit yellow."""
GHOST_FADE_S = 300.0
"""Device seconds over which a ghost or a move line fades into the background, then goes."""


def _hue_color(key: int) -> Rgb:
    """A saturated colour from an integer key; golden-ratio hue steps keep consecutive keys
    far apart on the colour wheel."""
    hue = (key * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.65, 0.92)
    return (round(r * 255), round(g * 255), round(b * 255))


def object_color(object_id: int) -> Rgb:
    """A stable colour per object id (the same in every run and every viewer)."""
    return _hue_color(object_id)  # ids are consecutive: neighbours get distant hues


def class_color(label: str) -> Rgb:
    """A stable colour per class label (crc32: Python's str hash is salted per process)."""
    return _hue_color(zlib.crc32(label.encode("utf-8")))


def dimmed(color: Rgb) -> Rgb:
    """`color` faded towards grey: still tells objects apart, but recedes behind the hits."""
    return tuple(  # type: ignore[return-value]
        round(DIM_KEEP * c + (1 - DIM_KEEP) * g) for c, g in zip(color, DIM_GREY_RGB, strict=True)
    )


def blend(start: Rgb, end: Rgb, t: float) -> Rgb:
    """The colour a share `t` in [0, 1] of the way from `start` to `end`."""
    t = min(max(float(t), 0.0), 1.0)
    return tuple(round(a + t * (b - a)) for a, b in zip(start, end, strict=True))  # type: ignore[return-value]


def hit_color(color: Rgb, relevance: float) -> Rgb:
    """A hit's colour: as dimmed as a non-hit at relevance 0, its own colour at 1."""
    return blend(dimmed(color), color, relevance)


def hit_box_color(relevance: float) -> Rgb:
    """A hit's box colour: grey at relevance 0, bright HIT_BOX_RGB at 1."""
    return blend(DIM_GREY_RGB, HIT_BOX_RGB, relevance)


def faded(color: Rgb, age_s: float) -> Rgb:
    """`color` after `age_s` device seconds: linearly into BACKGROUND_RGB over GHOST_FADE_S."""
    return blend(color, BACKGROUND_RGB, max(age_s, 0.0) / GHOST_FADE_S)
