"""Furniture builders: one function per category (or family of categories) that draws the
object as boxes, cylinders and ellipsoids in its own frame and returns the rectangles small
objects may stand on.

Object frame convention: x along the width, y from front (-y) to back (+y, the side that goes
against a wall), z up from the object's bottom (z = 0).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from world.meshes import Parts, rot_x, rot_y, rot_z, shade


@dataclass(frozen=True)
class LocalSupport:
    """A rectangle small objects may stand on, in the owner's frame."""

    rect: tuple[float, float, float, float]  # x0, y0, x1, y1
    z: float
    clearance: float
    kind: str  # "top" | "shelf"


# A builder draws the object into `p` inside [-w/2, w/2] x [-d/2, d/2] x [0, h] and returns
# the support rectangles it offers.
Builder = Callable[..., list[LocalSupport]]
_BUILDERS: dict[str, Builder] = {}

_DARK_WOOD = np.array([90.0, 64.0, 44.0])
_METAL_GREY = np.array([170.0, 172.0, 176.0])
_BLACK = np.array([28.0, 28.0, 30.0])
_SCREEN = np.array([14.0, 17.0, 24.0])
WHITE = np.array([238.0, 238.0, 234.0])  # also the ceilings'
_GLASS = np.array([165.0, 195.0, 220.0])


def _builder(*names: str) -> Callable[[Builder], Builder]:
    def register(fn: Builder) -> Builder:
        for n in names:
            _BUILDERS[n] = fn
        return fn

    return register


def build_furniture(
    category: str,
    size: tuple[float, float, float],
    color: np.ndarray,
    rng: np.random.Generator,
    **style,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[LocalSupport]]:
    """Draw one `category` object of `size` (w, d, h metres) in its own frame.

    Returns (vertices float [N, 3], triangles int [M, 3], colours float [N, 3] in [0, 1],
    the support rectangles it offers).
    """
    parts = Parts()
    supports = _BUILDERS[category](parts, *size, color, rng, category=category, **style)
    v, t, c = parts.arrays()
    return v, t, c, supports


def _top_support(w: float, d: float, z: float, inset: float = 0.03) -> LocalSupport:
    return LocalSupport(
        (-w / 2 + inset, -d / 2 + inset, w / 2 - inset, d / 2 - inset), z, 1.2, "top"
    )


def _legs(p: Parts, w: float, d: float, h: float, size: float, inset: float, color) -> None:
    for sx, sy in itertools.product((-1, 1), (-1, 1)):
        cx, cy = sx * (w / 2 - inset - size / 2), sy * (d / 2 - inset - size / 2)
        p.box((cx - size / 2, cy - size / 2, 0), (cx + size / 2, cy + size / 2, h), color)


@_builder("sofa", "armchair")
def _build_upholstered(p, w, d, h, color, rng, cushions: int | None = None, **_):
    arm, back, seat = 0.16, 0.2, 0.44
    _legs(p, w, d, 0.07, 0.05, 0.03, _DARK_WOOD)
    p.box((-w / 2, -d / 2, 0.07), (w / 2, d / 2 - back, seat - 0.1), color)
    p.box((-w / 2 + arm, d / 2 - back, 0.07), (w / 2 - arm, d / 2, h), color)
    for sx in (-1, 1):
        x_in, x_out = sx * (w / 2 - arm), sx * w / 2
        p.box((min(x_in, x_out), -d / 2, 0.07), (max(x_in, x_out), d / 2, 0.64), shade(color, 0.92))
    n = cushions or (1 if w < 1.2 else 3 if w > 2.0 else 2)
    inner = w - 2 * arm
    cushion = shade(color, 1.08)
    for k in range(n):
        x0 = -w / 2 + arm + k * inner / n + 0.005
        p.box((x0, -d / 2 + 0.02, seat - 0.1), (x0 + inner / n - 0.01, d / 2 - back, seat), cushion)
    return []


@_builder("coffee table", "dining table")
def _build_table(p, w, d, h, color, rng, **_):
    top = 0.04
    p.box((-w / 2, -d / 2, h - top), (w / 2, d / 2, h), color)
    _legs(p, w, d, h - top, 0.05 if h > 0.6 else 0.06, 0.06, shade(color, 0.8))
    if h < 0.6:  # coffee tables get a magazine shelf between the legs
        p.box((-w / 2 + 0.09, -d / 2 + 0.09, 0.1), (w / 2 - 0.09, d / 2 - 0.09, 0.12), color)
    return [_top_support(w, d, h)]


@_builder("desk")
def _build_desk(p, w, d, h, color, rng, **_):
    top = 0.03
    p.box((-w / 2, -d / 2, h - top), (w / 2, d / 2, h), color)
    x0 = w / 2 - 0.42
    p.box((x0, -d / 2 + 0.02, 0), (w / 2 - 0.01, d / 2 - 0.01, h - top), shade(color, 0.9))
    for k in range(3):  # drawer fronts on the pedestal
        z0 = 0.02 + k * (h - top - 0.03) / 3
        z1 = z0 + (h - top - 0.03) / 3 - 0.01
        p.box((x0 + 0.01, -d / 2, z0), (w / 2 - 0.02, -d / 2 + 0.02, z1), color)
        p.box(
            (x0 + 0.17, -d / 2 - 0.0, z1 - 0.05),
            (x0 + 0.25, -d / 2 + 0.005, z1 - 0.035),
            _METAL_GREY,
        )
    p.box(
        (-w / 2 + 0.01, -d / 2 + 0.02, 0),
        (-w / 2 + 0.04, d / 2 - 0.01, h - top),
        shade(color, 0.9),
    )
    p.box((-w / 2 + 0.04, d / 2 - 0.03, 0.3), (x0, d / 2 - 0.01, h - top), shade(color, 0.85))
    return [_top_support(w, d, h)]


@_builder("chair")
def _build_chair(p, w, d, h, color, rng, **_):
    seat = 0.46
    leg = 0.035
    _legs(p, w, d, seat - 0.04, leg, 0.015, shade(color, 0.85))
    p.box((-w / 2, -d / 2, seat - 0.04), (w / 2, d / 2, seat), color)
    for sx in (-1, 1):
        x = sx * (w / 2 - 0.015 - leg / 2)
        p.box((x - leg / 2, d / 2 - leg, seat), (x + leg / 2, d / 2, h), shade(color, 0.85))
    p.box(
        (-w / 2 + 0.015 + leg, d / 2 - 0.03, h - 0.28),
        (w / 2 - 0.015 - leg, d / 2, h - 0.02),
        color,
    )
    return []


@_builder("office chair")
def _build_office_chair(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2 - 0.03
    for k in range(5):
        rot = rot_z(2 * math.pi * k / 5 + 0.3)
        p.box((0, -0.025, 0.06), (r, 0.025, 0.1), _BLACK, rot)
        cx, cy = (rot @ [r - 0.02, 0, 0])[:2]
        p.cylinder((cx, cy, 0), 0.025, 0.06, _BLACK, 8)
    p.cylinder((0, 0, 0.1), 0.025, 0.32, _METAL_GREY, 10)
    p.box((-w / 2 + 0.06, -d / 2 + 0.02, 0.42), (w / 2 - 0.06, d / 2 - 0.1, 0.5), color)
    p.box((-w / 2 + 0.1, d / 2 - 0.07, 0.56), (w / 2 - 0.1, d / 2, h), color)
    p.box((-0.03, d / 2 - 0.1, 0.45), (0.03, d / 2 - 0.07, 0.62), _BLACK)
    for sx in (-1, 1):
        x = sx * (w / 2 - 0.04)
        p.box((x - 0.02, -0.05, 0.5), (x + 0.02, 0.0, 0.64), _BLACK)
        p.box((x - 0.035, -0.2, 0.64), (x + 0.035, 0.05, 0.67), _BLACK)
    return []


@_builder("ottoman")
def _build_ottoman(p, w, d, h, color, rng, **_):
    if rng.random() < 0.5:
        p.frustum((0, 0, 0), min(w, d) / 2 * 0.92, min(w, d) / 2, h, color, 20)
    else:
        _legs(p, w, d, 0.06, 0.04, 0.04, _DARK_WOOD)
        p.box((-w / 2, -d / 2, 0.06), (w / 2, d / 2, h), color)
    return []


@_builder("bar stool")
def _build_bar_stool(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, 0), r * 0.9, 0.03, color, 16)
    p.cylinder((0, 0, 0.03), 0.025, h - 0.08, _METAL_GREY, 10)
    p.cylinder((0, 0, 0.28), r * 0.75, 0.02, _METAL_GREY, 16)
    p.cylinder((0, 0, h - 0.06), r, 0.06, color, 20)
    return []


@_builder("bed")
def _build_bed(p, w, d, h, color, rng, duvet=None, **_):
    duvet = np.asarray(duvet if duvet is not None else (200, 186, 160), float)
    head = 0.06
    _legs(p, w, d - head, 0.12, 0.06, 0.02, shade(color, 0.8))
    p.box((-w / 2, -d / 2, 0.12), (w / 2, d / 2 - head, 0.32), color)
    p.box((-w / 2, d / 2 - head, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.03, -d / 2 + 0.03, 0.32), (w / 2 - 0.03, d / 2 - head - 0.01, 0.54), WHITE)
    p.box((-w / 2 + 0.01, -d / 2 + 0.01, 0.54), (w / 2 - 0.01, d / 2 - 0.7, 0.58), duvet)
    n_pillows = 2 if w > 1.2 else 1
    pw = (w - 0.1) / n_pillows
    for k in range(n_pillows):
        x0 = -w / 2 + 0.05 + k * pw
        p.box(
            (x0 + 0.02, d / 2 - head - 0.5, 0.54),
            (x0 + pw - 0.02, d / 2 - head - 0.06, 0.66),
            WHITE,
        )
    return [
        LocalSupport((-w / 2 + 0.12, -d / 2 + 0.15, w / 2 - 0.12, d / 2 - 0.75), 0.58, 0.6, "top")
    ]


def _drawer_fronts(p, x0, x1, z0, z1, front_y, rows, color) -> None:
    step = (z1 - z0) / rows
    for k in range(rows):
        za, zb = z0 + k * step + 0.005, z0 + (k + 1) * step - 0.005
        p.box((x0 + 0.01, front_y - 0.02, za), (x1 - 0.01, front_y, zb), color)
        cx, cz = (x0 + x1) / 2, (za + zb) / 2
        p.box(
            (cx - 0.05, front_y - 0.03, cz - 0.008),
            (cx + 0.05, front_y - 0.02, cz + 0.008),
            _METAL_GREY,
        )


@_builder("nightstand", "dresser", "filing cabinet")
def _build_drawers(p, w, d, h, color, rng, **_):
    plinth = 0.05
    front = -d / 2 + 0.03
    p.box((-w / 2 + 0.02, front, 0), (w / 2 - 0.02, d / 2, plinth), shade(color, 0.7))
    p.box((-w / 2, front, plinth), (w / 2, d / 2, h - 0.03), color)
    p.box((-w / 2, -d / 2 + 0.025, h - 0.03), (w / 2, d / 2, h), shade(color, 0.92))
    rows = max(1, round((h - plinth) / 0.25))
    front_color = shade(color, 1.06)
    if w > 1.05:  # two columns of drawers on wide dressers
        _drawer_fronts(p, -w / 2, 0, plinth, h - 0.03, front, rows, front_color)
        _drawer_fronts(p, 0, w / 2, plinth, h - 0.03, front, rows, front_color)
    else:
        _drawer_fronts(p, -w / 2, w / 2, plinth, h - 0.03, front, rows, front_color)
    return [_top_support(w, d, h)]


def _doors(p, x0, x1, z0, z1, front_y, n, color) -> None:
    step = (x1 - x0) / n
    for k in range(n):
        xa, xb = x0 + k * step + 0.004, x0 + (k + 1) * step - 0.004
        p.box((xa, front_y - 0.02, z0), (xb, front_y, z1), color)
        hx = xb - 0.04 if k % 2 == 0 else xa + 0.04
        hz0 = 1.0 if z1 > 1.2 else z1 - 0.2  # tall doors get handles at hand height
        p.box(
            (hx - 0.008, front_y - 0.035, hz0),
            (hx + 0.008, front_y - 0.02, hz0 + 0.14),
            _METAL_GREY,
        )


@_builder("wardrobe", "cabinet", "tv stand", "wall cabinet")
def _build_cupboard(p, w, d, h, color, rng, category: str = "cabinet", **_):
    front = -d / 2 + 0.035
    floor_standing = category != "wall cabinet"
    z0 = 0.06 if floor_standing else 0.0
    if floor_standing:
        p.box((-w / 2 + 0.03, front + 0.03, 0), (w / 2 - 0.03, d / 2, z0), shade(color, 0.6))
    p.box((-w / 2, front, z0), (w / 2, d / 2, h), color)
    n_doors = max(2, round(w / 0.5)) if category != "tv stand" else 3
    _doors(p, -w / 2, w / 2, z0 + 0.01, h - 0.01, front, n_doors, shade(color, 1.06))
    return [_top_support(w, d, h)] if category in ("cabinet", "tv stand") else []


@_builder("bookshelf")
def _build_bookshelf(p, w, d, h, color, rng, **_):
    t = 0.022
    p.box((-w / 2, -d / 2, 0), (-w / 2 + t, d / 2, h), color)
    p.box((w / 2 - t, -d / 2, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + t, d / 2 - 0.012, 0), (w / 2 - t, d / 2, h), shade(color, 0.8))
    levels = max(3, int((h - 0.08) // 0.34))
    zs = np.linspace(0.06, h - t, levels + 1)
    supports = []
    p.box((-w / 2 + t, -d / 2, 0), (w / 2 - t, d / 2 - 0.012, 0.06), shade(color, 0.9))
    for k, z in enumerate(zs[1:]):
        p.box((-w / 2 + t, -d / 2, z), (w / 2 - t, d / 2 - 0.012, z + t), color)
        below = zs[k] + (0 if k == 0 else t)
        supports.append(
            LocalSupport(
                (-w / 2 + t + 0.005, -d / 2 + 0.01, w / 2 - t - 0.005, d / 2 - 0.02),
                below,
                z - below - 0.01,
                "shelf",
            )
        )
    return supports


@_builder("kitchen counter", "sink")
def _build_counter(p, w, d, h, color, rng, top_color=None, category: str = "kitchen counter", **_):
    top_color = np.asarray(top_color if top_color is not None else (200, 196, 188), float)
    slab = 0.04
    p.box((-w / 2, -d / 2 + 0.08, 0), (w / 2, d / 2, 0.1), _BLACK)
    _doors(
        p,
        -w / 2,
        w / 2,
        0.11,
        h - slab - 0.01,
        -d / 2 + 0.03,
        max(1, round(w / 0.5)),
        shade(color, 1.05),
    )
    if category == "kitchen counter":
        p.box((-w / 2, -d / 2 + 0.03, 0.1), (w / 2, d / 2, h - slab), color)
        p.box((-w / 2, -d / 2, h - slab), (w / 2, d / 2, h), top_color)
        return [_top_support(w, d, h, inset=0.04)]
    # Sink: a slab with a hole, a metal basin below it and a tap behind it; the cabinet is
    # hollow above the basin's bottom so that the basin is open from above.
    bx0, bx1, by0, by1 = -w / 2 + 0.1, w / 2 - 0.1, -d / 2 + 0.08, d / 2 - 0.15
    zb = h - 0.2
    p.box((-w / 2, -d / 2 + 0.03, 0.1), (w / 2, d / 2, zb), color)
    for lo, hi in (
        ((-w / 2, -d / 2 + 0.03, zb), (bx0, d / 2, h - slab)),
        ((bx1, -d / 2 + 0.03, zb), (w / 2, d / 2, h - slab)),
        ((bx0, -d / 2 + 0.03, zb), (bx1, by0, h - slab)),
        ((bx0, by1, zb), (bx1, d / 2, h - slab)),
    ):
        p.box(lo, hi, color)
    p.box((-w / 2, -d / 2, h - slab), (bx0, d / 2, h), top_color)
    p.box((bx1, -d / 2, h - slab), (w / 2, d / 2, h), top_color)
    p.box((bx0, -d / 2, h - slab), (bx1, by0, h), top_color)
    p.box((bx0, by1, h - slab), (bx1, d / 2, h), top_color)
    p.box((bx0, by0, zb), (bx1, by1, zb + 0.01), _METAL_GREY)
    for lo, hi in (
        ((bx0, by0, zb), (bx0 + 0.01, by1, h - slab)),
        ((bx1 - 0.01, by0, zb), (bx1, by1, h - slab)),
        ((bx0, by0, zb), (bx1, by0 + 0.01, h - slab)),
        ((bx0, by1 - 0.01, zb), (bx1, by1, h - slab)),
    ):
        p.box(lo, hi, _METAL_GREY)
    ty = d / 2 - 0.08
    p.cylinder((0, ty, h), 0.015, 0.28, _METAL_GREY, 10)
    p.box((-0.012, ty - 0.2, h + 0.25), (0.012, ty, h + 0.28), _METAL_GREY)
    return []


@_builder("refrigerator")
def _build_fridge(p, w, d, h, color, rng, **_):
    front = -d / 2 + 0.04
    p.box((-w / 2, front, 0), (w / 2, d / 2, h), color)
    split = h * rng.uniform(0.58, 0.68)
    p.box(
        (-w / 2 + 0.005, front - 0.03, 0.02),
        (w / 2 - 0.005, front, split - 0.006),
        shade(color, 1.04),
    )
    p.box(
        (-w / 2 + 0.005, front - 0.03, split + 0.006),
        (w / 2 - 0.005, front, h - 0.01),
        shade(color, 1.04),
    )
    hx = w / 2 - 0.06
    p.box(
        (hx - 0.012, -d / 2, split - 0.45),
        (hx + 0.012, front - 0.03, split - 0.1),
        shade(color, 0.75),
    )
    p.box(
        (hx - 0.012, -d / 2, split + 0.1),
        (hx + 0.012, front - 0.03, split + 0.35),
        shade(color, 0.75),
    )
    return []


@_builder("stove")
def _build_stove(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.02, 0), (w / 2, d / 2, h - 0.03), color)
    p.box((-w / 2 + 0.05, -d / 2, 0.12), (w / 2 - 0.05, -d / 2 + 0.02, h - 0.2), _SCREEN)
    p.box(
        (-w / 2 + 0.08, -d / 2 - 0.0, h - 0.16),
        (w / 2 - 0.08, -d / 2 + 0.02, h - 0.14),
        _METAL_GREY,
    )
    p.box((-w / 2, -d / 2 + 0.02, h - 0.03), (w / 2, d / 2, h), _BLACK)
    for sx, sy in itertools.product((-1, 1), (-1, 1)):
        p.cylinder((sx * w / 4, sy * d / 4, h), 0.07 if sy < 0 else 0.09, 0.006, (60, 60, 62), 14)
    for k in range(4):
        x = -w / 2 + (k + 0.5) * w / 4
        p.cylinder((x, -d / 2 + 0.02, h - 0.07), 0.018, 0.02, _METAL_GREY, 10, rot_x(math.pi / 2))
    return [
        LocalSupport(
            (-w / 2 + 0.04, -d / 2 + 0.06, w / 2 - 0.04, d / 2 - 0.04), h + 0.006, 0.7, "top"
        )
    ]


@_builder("dishwasher")
def _build_dishwasher(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.03, 0), (w / 2, d / 2, h), color)
    p.box(
        (-w / 2 + 0.01, -d / 2 + 0.01, 0.1),
        (w / 2 - 0.01, -d / 2 + 0.03, h - 0.12),
        shade(color, 1.05),
    )
    p.box((-w / 2 + 0.01, -d / 2 + 0.01, h - 0.11), (w / 2 - 0.01, -d / 2 + 0.03, h - 0.01), _BLACK)
    p.box((-w / 2 + 0.1, -d / 2, h - 0.18), (w / 2 - 0.1, -d / 2 + 0.01, h - 0.16), _METAL_GREY)
    return []


@_builder("microwave")
def _build_microwave(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.01, 0.01), (w / 2, d / 2, h), color)
    for sx in (-1, 1):
        for sy in (-1, 1):
            p.box(
                (sx * w / 2 * 0.8 - 0.01, sy * d / 3 - 0.01, 0),
                (sx * w / 2 * 0.8 + 0.01, sy * d / 3 + 0.01, 0.01),
                _BLACK,
            )
    split = w / 2 - 0.13
    p.box((-w / 2 + 0.03, -d / 2, 0.04), (split - 0.02, -d / 2 + 0.01, h - 0.04), _SCREEN)
    p.box((split, -d / 2 + 0.003, 0.03), (w / 2 - 0.02, -d / 2 + 0.01, h - 0.03), shade(color, 0.6))
    return []


@_builder("toaster")
def _build_toaster(p, w, d, h, color, rng, **_):
    p.box((-w / 2 + 0.015, -d / 2, 0), (w / 2 - 0.015, d / 2, h - 0.004), color)
    for k in (-1, 1):
        y = k * d / 5
        p.box((-w / 2 + 0.04, y - 0.014, h - 0.004), (w / 2 - 0.04, y + 0.014, h), _BLACK)
    p.box((w / 2 - 0.015, -0.012, h * 0.5), (w / 2, 0.012, h * 0.7), _BLACK)
    return []


@_builder("kettle")
def _build_kettle(p, w, d, h, color, rng, **_):
    r = d / 2
    p.cylinder((0, 0, 0), r, 0.02, _BLACK, 16)
    p.frustum((0, 0, 0.02), r * 0.95, r * 0.72, h - 0.05, color, 16)
    p.cylinder((0, 0, h - 0.03), r * 0.45, 0.03, _BLACK, 14)
    xb = w / 2 - 0.025
    p.box((xb, -0.012, 0.05), (w / 2, 0.012, h - 0.04), _BLACK)
    p.box((r * 0.7, -0.012, h - 0.07), (w / 2, 0.012, h - 0.04), _BLACK)
    p.box((-w / 2, -0.01, h * 0.55), (-r * 0.8, 0.01, h * 0.7), color)
    return []


@_builder("coffee maker")
def _build_coffee_maker(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, 0.03), color)
    p.box((-w / 2, 0, 0.03), (w / 2, d / 2, h), color)
    p.box((-w / 2, -d / 2, h - 0.08), (w / 2, 0, h), shade(color, 0.9))
    p.cylinder((0, -d / 4, 0.03), min(w, d) * 0.28, h * 0.45, _SCREEN, 16)
    return []


@_builder("cooking pot")
def _build_pot(p, w, d, h, color, rng, **_):
    r = d / 2
    p.cylinder((0, 0, 0), r, h - 0.02, color, 20)
    p.cylinder((0, 0, h - 0.02), r * 1.02, 0.006, shade(color, 1.1), 20)
    p.cylinder((0, 0, h - 0.014), 0.015, 0.014, _BLACK, 8)
    for sx in (-1, 1):
        x0, x1 = sorted((sx * r * 0.95, sx * w / 2))
        p.box((x0, -0.02, h - 0.05), (x1, 0.02, h - 0.035), _BLACK)
    return []


@_builder("cutting board", "keyboard", "remote control", "cell phone")
def _build_slab(p, w, d, h, color, rng, category: str = "", **_):
    if category == "cell phone":
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h - 0.001), color)
        p.box(
            (-w / 2 + 0.004, -d / 2 + 0.008, h - 0.001), (w / 2 - 0.004, d / 2 - 0.008, h), _SCREEN
        )
    elif category == "keyboard":
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h * 0.6), color)
        keys = shade(color, 0.75) if color.mean() > 128 else shade(color, 1.8)
        p.box((-w / 2 + 0.015, -d / 2 + 0.015, h * 0.6), (w / 2 - 0.015, d / 2 - 0.01, h), keys)
    elif category == "remote control":
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h - 0.003), color)
        for k in range(4):
            x = -w / 2 + 0.03 + k * 0.035
            p.box(
                (x, -0.01, h - 0.003),
                (x + 0.015, 0.01, h),
                (200, 60, 50) if k == 0 else (150, 150, 150),
            )
    else:
        p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h), color)
    return []


@_builder("bowl")
def _build_bowl(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.frustum((0, 0, 0), r * 0.5, r, h - 0.002, color, 20)
    p.cylinder((0, 0, h - 0.002), r * 0.9, 0.002, shade(color, 0.8), 20)
    return []


@_builder("mug")
def _build_mug(p, w, d, h, color, rng, **_):
    r = d / 2
    p.cylinder((-(w - d) / 2, 0, 0), r, h, color, 18)
    p.cylinder((-(w - d) / 2, 0, h), r * 0.85, 0.001, (70, 45, 30), 18)  # coffee, seen from above
    cx = -(w - d) / 2 + r * 0.9
    p.box((cx, -0.006, h - 0.025), (w / 2, 0.006, h - 0.015), color)
    p.box((cx, -0.006, h * 0.25), (w / 2, 0.006, h * 0.25 + 0.01), color)
    p.box((w / 2 - 0.01, -0.006, h * 0.25), (w / 2, 0.006, h - 0.015), color)
    return []


@_builder("bottle")
def _build_bottle(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, 0), r, h * 0.6, color, 16)
    p.frustum((0, 0, h * 0.6), r, r * 0.35, h * 0.15, color, 16)
    p.cylinder((0, 0, h * 0.75), r * 0.35, h * 0.2, color, 12)
    p.cylinder((0, 0, h * 0.95), r * 0.4, h * 0.05, WHITE if color.mean() < 128 else _BLACK, 12)
    return []


@_builder("vase")
def _build_vase(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    flowers = rng.random() < 0.5
    body = h * (0.65 if flowers else 1.0)
    p.frustum((0, 0, 0), r * 0.6, r, body * 0.45, color, 18)
    p.frustum((0, 0, body * 0.45), r, r * 0.45, body * 0.4, color, 18)
    p.frustum((0, 0, body * 0.85), r * 0.45, r * 0.6, body * 0.15, color, 18)
    if flowers:
        petal = np.array(
            [(220, 60, 80), (245, 200, 60), (240, 240, 240), (150, 90, 200)][rng.integers(4)], float
        )
        for k in range(4):
            a = 2 * math.pi * k / 4 + 0.4
            fx, fy = math.cos(a) * r * 0.5, math.sin(a) * r * 0.5
            top = h - 0.03 - 0.03 * (k % 2)
            p.box((fx - 0.003, fy - 0.003, body), (fx + 0.003, fy + 0.003, top), (60, 120, 50))
            p.ellipsoid((fx, fy, top), (0.025, 0.025, 0.025), petal, 5, 8)
    return []


@_builder("potted plant")
def _build_plant(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    pot_h = min(0.35, h * 0.3)
    pot = np.array([(190, 110, 80), (235, 232, 225), (60, 60, 62)][rng.integers(3)], float)
    p.frustum((0, 0, 0), r * 0.55, r * 0.7, pot_h, pot, 16)
    p.cylinder((0, 0, pot_h), r * 0.65, 0.005, (70, 50, 35), 16)
    if h > 1.0:  # a small tree: trunk and a crown
        p.cylinder((0, 0, pot_h), 0.025, h * 0.45, (100, 75, 50), 8)
        blobs = [
            ((0, 0, h - r * 0.9), r * 0.9),
            ((r * 0.35, 0.1 * r, h - r * 1.4), r * 0.6),
            ((-r * 0.35, -0.1 * r, h - r * 1.3), r * 0.6),
        ]
    else:
        blobs = [
            ((0, 0, pot_h + (h - pot_h) * 0.5), r * 0.85),
            # the top blob touches the plant's full height
            ((r * 0.3, r * 0.2, h - min(r * 0.6, (h - pot_h) * 0.3)), r * 0.6),
            ((-r * 0.3, -r * 0.2, h - (h - pot_h) * 0.35), r * 0.6),
        ]
    for k, (c, rad) in enumerate(blobs):
        zr = min(rad, h - c[2], c[2] - pot_h + rad * 0.5)
        p.ellipsoid(c, (rad, rad, max(0.05, zr)), shade(color, 0.85 + 0.12 * k), 6, 12)
    return []


@_builder("floor lamp", "table lamp")
def _build_lamp(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    tall = h > 1.0
    shade_h = 0.32 if tall else h * 0.45
    base = np.array([(40, 40, 42), (190, 170, 120), (200, 200, 200)][rng.integers(3)], float)
    if tall:
        p.cylinder((0, 0, 0), min(0.15, r), 0.03, base, 18)
    else:
        p.ellipsoid((0, 0, h * 0.13), (r * 0.45, r * 0.45, h * 0.13), base, 6, 12)
    p.cylinder((0, 0, 0.02), 0.012, h - shade_h * 0.5, base, 8)
    p.frustum((0, 0, h - shade_h), r, r * 0.7, shade_h, color, 20)
    return []


@_builder("picture frame")
def _build_picture_frame(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2, 0), (w / 2, -d / 2 + 0.018, h), color)
    photo = np.array([(120, 160, 200), (200, 170, 130), (110, 150, 100)][rng.integers(3)], float)
    p.box((-w / 2 + 0.02, -d / 2 - 0.0, 0.02), (w / 2 - 0.02, -d / 2 + 0.001, h - 0.02), photo)
    p.box((-0.02, -d / 2 + 0.018, 0), (0.02, d / 2, 0.01), color)
    p.box((-0.02, -d / 2 + 0.018, 0.01), (0.02, -d / 2 + 0.028, h * 0.6), color)
    return []


@_builder("candle")
def _build_candle(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, 0), r, h - 0.012, color, 14)
    p.box((-0.0015, -0.0015, h - 0.012), (0.0015, 0.0015, h), _BLACK)
    return []


@_builder("teddy bear")
def _build_teddy(p, w, d, h, color, rng, **_):
    hr = h * 0.2
    p.ellipsoid((0, 0.01, h * 0.3), (w * 0.3, d * 0.38, h * 0.3), color)
    p.ellipsoid((0, 0, h - hr), (hr, hr * 0.95, hr), color)
    for sx in (-1, 1):
        p.ellipsoid(
            (sx * hr * 0.75, 0.01, h - hr * 0.3), (hr * 0.3, hr * 0.2, hr * 0.3), color, 5, 8
        )
        p.ellipsoid(
            (sx * w * 0.36, -d * 0.05, h * 0.4), (w * 0.13, d * 0.18, h * 0.16), color, 5, 8
        )
        p.ellipsoid((sx * w * 0.18, -d * 0.25, h * 0.1), (w * 0.12, d * 0.25, h * 0.1), color, 5, 8)
    p.ellipsoid(
        (0, -hr * 0.85, h - hr * 1.1), (hr * 0.35, hr * 0.25, hr * 0.28), shade(color, 1.3), 5, 8
    )
    return []


@_builder("laptop")
def _build_laptop(p, w, d, h, color, rng, **_):
    tilt = math.radians(rng.uniform(10, 20))
    base_h = 0.018
    length = (h - base_h) / math.cos(tilt)
    base_d = d - length * math.sin(tilt) - 0.008
    y0 = -d / 2
    hinge_y = y0 + base_d
    p.box((-w / 2, y0, 0), (w / 2, hinge_y, base_h), color)
    p.box(
        (-w / 2 + 0.02, y0 + 0.07, base_h), (w / 2 - 0.02, hinge_y - 0.02, base_h + 0.001), _BLACK
    )
    rot = rot_x(-tilt)
    pivot = (0.0, hinge_y, base_h)
    p.box((-w / 2, hinge_y, base_h), (w / 2, hinge_y + 0.008, base_h + length), color, rot, pivot)
    p.box(
        (-w / 2 + 0.012, hinge_y - 0.001, base_h + 0.012),
        (w / 2 - 0.012, hinge_y, base_h + length - 0.012),
        _SCREEN,
        rot,
        pivot,
    )
    return []


@_builder("monitor")
def _build_monitor(p, w, d, h, color, rng, **_):
    p.box((-0.12, -d / 2, 0), (0.12, d / 2, 0.015), color)
    p.box((-0.025, 0.02, 0.015), (0.025, 0.05, h * 0.5), color)
    p.box((-w / 2, -0.015, 0.09), (w / 2, 0.02, h), color)
    p.box((-w / 2 + 0.012, -0.017, 0.1), (w / 2 - 0.012, -0.015, h - 0.012), _SCREEN)
    return []


@_builder("printer")
def _build_printer(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.08, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.08, -d / 2, 0.03), (w / 2 - 0.08, -d / 2 + 0.08, 0.05), shade(color, 0.85))
    p.box((-w / 2 + 0.06, -d / 2 + 0.12, h), (w / 2 - 0.06, d / 2 - 0.08, h + 0.002), _BLACK)
    p.box(
        (w / 2 - 0.12, -d / 2 + 0.075, h - 0.06), (w / 2 - 0.02, -d / 2 + 0.08, h - 0.02), _SCREEN
    )
    return []


@_builder("keys")
def _build_keys(p, w, d, h, color, rng, **_):
    ring_r = 0.012
    rx = -w / 2 + ring_r
    p.cylinder((rx, 0, 0), ring_r, 0.003, _METAL_GREY, 10)
    for k, angle in enumerate((-0.35, 0.0, 0.35)[: 2 + rng.integers(2)]):
        rot = rot_z(angle)
        metal = np.asarray(color, float) if k == 0 else _METAL_GREY
        p.box(
            (rx + ring_r * 0.5, -0.009, 0.001 + 0.002 * k),
            (w / 2 - 0.006, 0.009, 0.003 + 0.002 * k),
            metal,
            rot,
            (rx, 0, 0),
        )
    fob = np.array([(200, 40, 40), (40, 90, 160), (30, 30, 32)][rng.integers(3)], float)
    p.box((rx - 0.01, -d / 2, 0), (rx + 0.012, -d / 2 + 0.02, h), fob)
    return []


@_builder("speaker")
def _build_speaker(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.006, 0), (w / 2, d / 2, h), color)
    front = np.array([40.0, 40.0, 44.0])
    r = min(w, h) * 0.32
    p.cylinder((0, -d / 2 + 0.006, h * 0.35), r, 0.006, front, 18, rot_x(math.pi / 2))
    p.cylinder((0, -d / 2 + 0.006, h * 0.78), r * 0.35, 0.006, front, 12, rot_x(math.pi / 2))
    return []


@_builder("book")
def _build_book(p, w, d, h, color, rng, standing: bool = False, **_):
    if standing:
        # Upright on a shelf: thickness h along x, the spine (cover colour) at the front.
        t, depth, height = h, w, d
        p.box((-t / 2, -depth / 2, 0), (t / 2, depth / 2 - 0.003, height - 0.002), WHITE)
        p.box((-t / 2, -depth / 2, 0), (t / 2, -depth / 2 + 0.006, height), color)
        p.box((-t / 2, -depth / 2, 0), (-t / 2 + 0.002, depth / 2, height), color)
        p.box((t / 2 - 0.002, -depth / 2, 0), (t / 2, depth / 2, height), color)
        return []
    p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, 0.002), color)
    p.box((-w / 2, -d / 2, h - 0.002), (w / 2, d / 2, h), color)
    p.box((-w / 2, -d / 2, 0.002), (-w / 2 + 0.006, d / 2, h - 0.002), color)
    p.box((-w / 2 + 0.006, -d / 2 + 0.002, 0.002), (w / 2 - 0.003, d / 2 - 0.002, h - 0.002), WHITE)
    return []


@_builder("backpack")
def _build_backpack(p, w, d, h, color, rng, **_):
    body_d = d * 0.6
    r = body_d / 2
    p.box((-w / 2, -body_d / 2 + 0.01, 0), (w / 2, body_d / 2 + 0.01, h - r), color)
    p.cylinder((-w / 2, 0.01, h - r), r, w, color, 14, rot_y(math.pi / 2))
    p.box((-w * 0.35, -d / 2, 0.04), (w * 0.35, -body_d / 2 + 0.01, h * 0.45), shade(color, 0.85))
    for sx in (-1, 1):
        x = sx * w * 0.25
        p.box((x - 0.025, body_d / 2 + 0.01, 0.08), (x + 0.025, d / 2, h - r), _BLACK)
    return []


@_builder("cardboard box")
def _build_box(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2, 0), (w / 2, d / 2, h - 0.001), color)
    p.box((-w / 2 + 0.005, -0.025, h - 0.001), (w / 2 - 0.005, 0.025, h), (205, 190, 160))
    return []


@_builder("trash can")
def _build_trash_can(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    if rng.random() < 0.6:
        p.frustum((0, 0, 0), r * 0.85, r * 0.97, h - 0.02, color, 20)
        p.cylinder((0, 0, h - 0.02), r, 0.02, shade(color, 0.7), 20)
    else:
        p.box((-w / 2 + 0.01, -d / 2 + 0.01, 0), (w / 2 - 0.01, d / 2 - 0.01, h - 0.02), color)
        p.box((-w / 2, -d / 2, h - 0.02), (w / 2, d / 2, h), shade(color, 0.7))
    return []


# --- wall-mounted (back at +y against the wall, z from the item's bottom) ---------------


@_builder("tv")
def _build_tv(p, w, d, h, color, rng, standing: bool = False, **_):
    z0, y0, y1 = 0.0, -d / 2, d / 2
    if standing:  # on a foot: d is the foot's depth, the panel is 6 cm thick
        p.box((-0.15, -d / 2, 0), (0.15, d / 2, 0.015), color)
        p.box((-0.03, 0.0, 0.015), (0.03, 0.04, 0.12), color)
        z0, y0, y1 = 0.1, -0.03, 0.03
    p.box((-w / 2, y0 + 0.004, z0), (w / 2, y1, h), color)
    p.box((-w / 2 + 0.015, y0, z0 + 0.015), (w / 2 - 0.015, y0 + 0.004, h - 0.015), _SCREEN)
    return []


def _frame(p, w, d, h, color, border) -> None:
    for lo, hi in (
        ((-w / 2, -d / 2, 0), (w / 2, d / 2, border)),
        ((-w / 2, -d / 2, h - border), (w / 2, d / 2, h)),
        ((-w / 2, -d / 2, border), (-w / 2 + border, d / 2, h - border)),
        ((w / 2 - border, -d / 2, border), (w / 2, d / 2, h - border)),
    ):
        p.box(lo, hi, color)


@_builder("painting")
def _build_painting(p, w, d, h, color, rng, **_):
    b = 0.035
    _frame(p, w, d, h, color, b)
    palette = np.array(
        [
            (200, 70, 60),
            (235, 200, 90),
            (60, 100, 160),
            (90, 150, 110),
            (230, 225, 210),
            (40, 40, 60),
            (220, 140, 90),
        ],
        float,
    )
    # Abstract art: the canvas split into a few coloured blocks.
    x0, x1, z0, z1 = -w / 2 + b, w / 2 - b, b, h - b
    xs = sorted(rng.uniform(x0 + 0.05, x1 - 0.05, size=rng.integers(1, 3)))
    edges = [x0, *xs, x1]
    zc = rng.uniform(z0 + 0.4 * (z1 - z0), z0 + 0.7 * (z1 - z0))
    colors = palette[rng.permutation(len(palette))]
    k = 0
    for xa, xb in itertools.pairwise(edges):
        for za, zb in ((z0, zc), (zc, z1)):
            p.box((xa, -d / 2 + 0.008, za), (xb, d / 2, zb), colors[k % len(colors)])
            k += 1
    return []


@_builder("mirror")
def _build_mirror(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.004, 0), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.03, -d / 2, 0.03), (w / 2 - 0.03, -d / 2 + 0.004, h - 0.03), (196, 208, 215))
    return []


@_builder("clock")
def _build_clock(p, w, d, h, color, rng, **_):
    r = min(w, h) / 2
    face = rot_x(math.pi / 2)  # cylinder axis +z -> -y (facing out of the wall)
    p.cylinder((0, d / 2, r), r, d - 0.004, color, 24, face)
    p.cylinder((0, -d / 2 + 0.004, r), r * 0.88, 0.002, WHITE, 24, face)
    for k in range(4):
        a = k * math.pi / 2
        cx, cz = math.sin(a) * r * 0.75, r + math.cos(a) * r * 0.75
        p.box((cx - 0.006, -d / 2, cz - 0.006), (cx + 0.006, -d / 2 + 0.002, cz + 0.006), _BLACK)
    for length, angle in (
        (r * 0.5, rng.uniform(0, 2 * math.pi)),
        (r * 0.75, rng.uniform(0, 2 * math.pi)),
    ):
        rot = rot_y(angle)
        p.box((-0.004, -d / 2, r), (0.004, -d / 2 + 0.002, r + length), _BLACK, rot, (0, 0, r))
    return []


@_builder("wall shelf")
def _build_wall_shelf(p, w, d, h, color, rng, **_):
    t = 0.03
    p.box((-w / 2, -d / 2, h - t), (w / 2, d / 2, h), color)
    for sx in (-1, 1):
        x = sx * (w / 2 - 0.1)
        p.box((x - 0.01, d / 2 - 0.02, 0), (x + 0.01, d / 2, h - t), _BLACK)
        p.box((x - 0.01, -d / 2 + 0.04, h - t - 0.02), (x + 0.01, d / 2 - 0.02, h - t), _BLACK)
    return [
        LocalSupport((-w / 2 + 0.01, -d / 2 + 0.01, w / 2 - 0.01, d / 2 - 0.01), h, 0.4, "shelf")
    ]


@_builder("whiteboard")
def _build_whiteboard(p, w, d, h, color, rng, **_):
    _frame(p, w, 0.02, h, _METAL_GREY, 0.02)
    p.box((-w / 2 + 0.02, -0.008, 0.02), (w / 2 - 0.02, 0.01, h - 0.02), color)
    p.box((-w / 2 + 0.1, -d / 2, 0), (w / 2 - 0.1, -0.01, 0.02), _METAL_GREY)
    for k in range(rng.integers(2, 5)):
        ink = np.array([(30, 30, 160), (180, 30, 30), (30, 30, 30), (30, 130, 50)][k % 4], float)
        x = rng.uniform(-w / 2 + 0.1, w / 2 - 0.45)
        z = rng.uniform(0.15, h - 0.15)
        p.box((x, -0.0095, z), (x + rng.uniform(0.15, 0.35), -0.008, z + 0.008), ink)
    p.box((-w / 2 + 0.02, 0.01, 0.02), (w / 2 - 0.02, d / 2, h - 0.02), _METAL_GREY)
    return []


@_builder("window")
def _build_window(p, w, d, h, color, rng, **_):
    b = 0.06
    _frame(p, w, d - 0.02, h, color, b)
    p.box((-w / 2 + b, 0.0, b), (w / 2 - b, d / 2 - 0.01, h - b), _GLASS)
    p.box((-0.02, -d / 2 + 0.02, b), (0.02, 0.0, h - b), color)
    p.box((-w / 2 - 0.03, -d / 2, 0.0), (w / 2 + 0.03, d / 2, 0.03), color)  # sill
    return []


@_builder("air conditioner")
def _build_ac(p, w, d, h, color, rng, **_):
    p.box((-w / 2, -d / 2 + 0.01, 0.04), (w / 2, d / 2, h), color)
    p.box((-w / 2 + 0.03, -d / 2 + 0.03, 0), (w / 2 - 0.03, d / 2, 0.04), shade(color, 0.75))
    p.box((-w / 2 + 0.05, -d / 2, 0.05), (w / 2 - 0.05, -d / 2 + 0.01, 0.09), shade(color, 0.6))
    return []


# --- ceiling (z from the item's bottom; the top touches the ceiling) -------------------


@_builder("ceiling light")
def _build_ceiling_light(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, h - 0.02), r * 0.4, 0.02, WHITE, 16)
    p.frustum((0, 0, 0), r * 0.85, r, h - 0.02, color, 24)
    return []


@_builder("ceiling fan")
def _build_ceiling_fan(p, w, d, h, color, rng, **_):
    r = min(w, d) / 2
    p.cylinder((0, 0, h - 0.04), 0.07, 0.04, color, 14)
    p.cylinder((0, 0, 0.12), 0.015, h - 0.16, color, 8)
    p.cylinder((0, 0, 0.06), 0.11, 0.08, color, 18)
    p.ellipsoid((0, 0, 0.06), (0.08, 0.08, 0.06), (250, 246, 230), 5, 10)
    blade = _DARK_WOOD if color.mean() > 150 else shade(color, 1.4)
    for k in range(5):
        p.box((0.09, -0.06, 0.1), (r, 0.06, 0.11), blade, rot_z(2 * math.pi * k / 5))
    return []
