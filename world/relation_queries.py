"""Questions about how things stand, with their ground truth, generated from any scene.

`relational_questions(scene, asker_xyz, seed)` asks about a scene's things by their relations
("the mug on the desk", "which chair is next to the sofa", "what is on the dining table", "the
box between the two chairs", "the lamp closest to me", "the biggest box") and answers each from
the scene's own geometry: the placement engine's `support_id` (what each thing was stood on)
and the things' boxes, volumes and centres, never from the relation code under test
(app.relations). `plain_questions(scene)` are the categories' own paraphrases.

Every relation has two readings: a strict one, what the ground truth asserts, and a loose one,
what a reasonable reader might still accept. A question is asked only when exactly one thing
satisfies it strictly and nothing else satisfies it loosely, also counting the other
categories its words may be taken for ("the table" may mean a desk); a negative ("the mug under
the sofa") only when nothing satisfies it even loosely. Questions pick out one of several
things a target phrase names (same-label duplicates) unless they ask for anything ("what is on
the desk": every thing on it is a right answer).

Phrasing varies by template, by the names each category goes by (`NAMES`) and by seed; every
question records the relation kind, target and anchor phrases it was written with, so a
failure can be told apart as a parse, a grounding or a geometry problem.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from world.categories import CATEGORIES
from world.scene import Scene

NAMES: dict[str, tuple[str, ...]] = {
    "mug": ("mug", "cup", "coffee mug", "coffee cup"),
    "backpack": ("backpack", "bag", "rucksack"),
    "sofa": ("sofa", "couch"),
    "bookshelf": ("bookshelf", "bookcase", "shelf"),
    "wall shelf": ("wall shelf", "shelf"),
    "dining table": ("dining table", "kitchen table", "table"),
    "coffee table": ("coffee table", "table"),
    "desk": ("desk", "writing desk", "work desk"),
    "chair": ("chair", "wooden chair"),
    "office chair": ("office chair", "desk chair", "chair"),
    "armchair": ("armchair", "chair"),
    "floor lamp": ("floor lamp", "standing lamp", "lamp"),
    "table lamp": ("table lamp", "reading lamp", "lamp"),
    "nightstand": ("nightstand", "bedside table", "side table"),
    "cardboard box": ("cardboard box", "box", "carton"),
    "book": ("book", "novel"),
    "painting": ("painting", "picture"),
    "picture frame": ("picture frame", "photo frame"),
    "trash can": ("trash can", "bin"),
    "potted plant": ("potted plant", "plant"),
    "cell phone": ("cell phone", "phone"),
    "remote control": ("remote control", "remote"),
    "bottle": ("bottle",),
    "laptop": ("laptop",),
}
"""The names a category goes by in questions, its own name first; a category not listed goes
by its name alone. A name several categories share ("table", "lamp", "chair") names them all."""

ALSO_MEANT: dict[str, tuple[str, ...]] = {
    "table": ("desk", "nightstand", "tv stand"),
    "side table": ("coffee table",),
    "lamp": ("ceiling light",),
    "chair": ("bar stool", "ottoman"),
    "picture": ("picture frame",),
}
"""Categories a name might loosely be taken for besides those it names: a question whose
answer would change if the reader took them in is not asked."""

PAIRWISE_KINDS: tuple[str, ...] = (
    "on", "in", "under", "above", "next_to", "near", "left_of", "right_of",
)  # fmt: skip
SUPERLATIVE_KINDS: tuple[str, ...] = (
    "closest", "farthest", "biggest", "smallest", "highest", "lowest",
)  # fmt: skip
ANY_TARGET_KINDS: tuple[str, ...] = ("on", "in", "under")
"""Relations asked with any target: "what is on the desk"."""
NEGATIVE_KINDS: tuple[str, ...] = ("on", "in", "under", "next_to", "near")
GROUPS_PER_KIND: dict[str, int] = {
    "default": 6, "on": 10, "near": 3, "left_of": 3, "right_of": 3, "between": 3,
    "closest_to": 3,
}  # fmt: skip
"""At most this many ground truths of a kind per scene (each asked in up to `phrasings`
ways): the relations the issue names first (on, under, in, next to) stay the bulk."""
CONTAINERS: frozenset[str] = frozenset(
    {"bookshelf", "cabinet", "wardrobe", "cardboard box", "trash can", "bowl"}
)
"""Categories a thing can be in (strictly)."""

# strict / loose thresholds, metres unless named otherwise
NEXT_TO_GAP_M = 0.35
"""Next to: boxes at most this far apart, side by side at a similar height..."""
NEAR_GAP_M = 0.3
"""Near: boxes at most this far apart."""
LOOSE_NEAR_GAP_M = 1.0
"""...while anything within this counts as loosely near / next to (the relation code's near
reaches 0 at 0.8 m)."""
ABOVE_MAX_GAP_M = 1.2
LOOSE_ABOVE_GAP_M = 2.0
BETWEEN_MAX_SPAN_M = 3.0
BETWEEN_LATERAL_M = 0.3
LOOSE_BETWEEN_LATERAL_M = 0.8
SIDE_MIN_DEG = 15.0
"""Left / right of: the target's bearing at least this far to that side of the anchor's, as
seen from the asker (strict); loosely any bearing more than LOOSE_SIDE_DEG to that side."""
LOOSE_SIDE_DEG = -5.0
CLOSEST_MARGIN_M = 0.75
"""Closest / farthest: the runner-up at least this much (and CLOSEST_MARGIN_SHARE) farther
(nearer) than the answer."""
CLOSEST_MARGIN_SHARE = 0.3
SIZE_MARGIN_RATIO = 1.5
"""Biggest / smallest: the answer's volume at least this many times the runner-up's (or its
inverse)."""
HEIGHT_MARGIN_M = 0.25
"""Highest / lowest: the answer's bottom, centre and top all at least this far above (below)
every other candidate's."""

_TEMPLATES: dict[str, tuple[str, ...]] = {
    "on": (
        "the {t} on the {a}", "which {t} is on the {a}", "the {t} sitting on the {a}",
        "the {t} on top of the {a}", "where is the {t} that is on the {a}",
        "show me the {t} resting on the {a}", "find the {t} on the {a}", "my {t} on the {a}",
    ),
    "in": (
        "the {t} in the {a}", "the {t} inside the {a}", "which {t} is in the {a}",
        "where is the {t} that is in the {a}", "the {t} kept in the {a}",
    ),
    "under": (
        "the {t} under the {a}", "the {t} underneath the {a}", "which {t} is under the {a}",
        "the {t} beneath the {a}", "find the {t} lying under the {a}",
    ),
    "above": (
        "the {t} above the {a}", "which {t} is above the {a}", "the {t} hanging above the {a}",
        "the {t} over the {a}",
    ),
    "next_to": (
        "the {t} next to the {a}", "the {t} beside the {a}", "the {t} by the {a}",
        "which {t} is next to the {a}", "the {t} standing beside the {a}", "the {t} at the {a}",
    ),
    "near": ("the {t} near the {a}", "the {t} close to the {a}", "which {t} is near the {a}"),
    "left_of": (
        "the {t} to the left of the {a}", "the {t} on the left of the {a}",
        "which {t} is left of the {a}",
    ),
    "right_of": (
        "the {t} to the right of the {a}", "the {t} on the right of the {a}",
        "which {t} is right of the {a}",
    ),
    "between": (
        "the {t} between the {a} and the {b}", "which {t} is between the {a} and the {b}",
        "the {t} in between the {a} and the {b}",
    ),
    "between_two": (
        "the {t} between the two {as}", "the {t} between the {a} and the other {a}",
    ),
    "closest": (
        "the {t} closest to me", "the nearest {t}", "which {t} is closest to me",
        "the {t} nearest to me",
    ),
    "farthest": ("the {t} farthest from me", "the furthest {t}", "which {t} is farthest away"),
    "closest_to": (
        "the {t} closest to the {a}", "the {t} nearest to the {a}",
        "which {t} is closest to the {a}",
    ),
    "biggest": ("the biggest {t}", "the largest {t}", "which {t} is the biggest"),
    "smallest": ("the smallest {t}", "which {t} is the smallest", "the tiniest {t}"),
    "highest": ("the highest {t}", "which {t} is the highest", "the topmost {t}"),
    "lowest": ("the lowest {t}", "which {t} is the lowest"),
    "any_on": (
        "what is on the {a}", "what's on top of the {a}", "anything on the {a}",
        "show me what is on the {a}",
    ),
    "any_in": ("what is in the {a}", "what's inside the {a}", "anything in the {a}"),
    "any_under": ("what is under the {a}", "anything underneath the {a}", "what's under the {a}"),
}  # fmt: skip
"""Phrasings per kind: {t} the target phrase, {a} / {b} anchor phrases, {as} {a}'s plural."""


@dataclass(frozen=True)
class Question:
    """One question and its ground truth."""

    text: str
    family: str
    """"relational" (a relation or superlative picks one thing), "any" ("what is on the
    desk": any thing standing so answers), "negative" (nothing satisfies it) or "plain"."""
    kind: str
    """A PAIRWISE_KINDS or SUPERLATIVE_KINDS entry, "between", "closest_to" (a superlative
    from an anchor), or "plain"."""
    expected: tuple[int, ...]
    """Instance ids of the answer: one (relational), every strict answer (any), none
    (negative), every instance of the category (plain)."""
    acceptable: tuple[int, ...]
    """Instance ids a right top-1 may name: `expected`, and for "any" the loose answers."""
    anchors: tuple[int, ...]
    """Instance ids of the anchors the answer stands in the relation to ((): none)."""
    target: str
    """The target phrase ("" for any target, the category for plain)."""
    anchor_phrases: tuple[str, ...]
    category: str
    """The expected thing's category (relational), the target's (negative), or the category
    asked for (plain); "" for any."""


@dataclass(frozen=True)
class Thing:
    """A scene object as the ground truth sees it: its box, centre, size and support."""

    id: int
    category: str
    lo: np.ndarray
    """float64 [3], metres, world (Z up)."""
    hi: np.ndarray
    volume_m3: float
    """Volume of its convex hull."""
    support_id: int
    """What it stands on (0: the floor or a wall)."""

    @property
    def centre(self) -> np.ndarray:
        return (self.lo + self.hi) / 2

    @property
    def height_m(self) -> float:
        return float(self.hi[2] - self.lo[2])


def things_of(scene: Scene) -> list[Thing]:
    """The scene's non-background objects as `Thing`s, in scene order."""
    out = []
    for o in scene.objects:
        if o.is_background:
            continue
        vertices = np.asarray(o.mesh.vertices, np.float64)
        try:
            volume = float(ConvexHull(vertices).volume)
        except (QhullError, ValueError):  # a flat thing
            volume = float(np.prod(np.maximum(o.bbox[3:] - o.bbox[:3], 1e-3)))
        out.append(Thing(o.instance_id, o.category, o.bbox[:3], o.bbox[3:], volume, o.support_id))
    return out


# --- relations, strict and loose --------------------------------------------------------------


def _footprint_share(a: Thing, b: Thing) -> float:
    """Share of a's footprint (box seen from above) over b's."""
    overlap = np.clip(np.minimum(a.hi[:2], b.hi[:2]) - np.maximum(a.lo[:2], b.lo[:2]), 0, None)
    area = float(np.prod(np.maximum(a.hi[:2] - a.lo[:2], 1e-6)))
    return float(np.prod(overlap)) / area


def _box_gap(a: Thing, b: Thing) -> float:
    gap = np.maximum(np.maximum(a.lo - b.hi, b.lo - a.hi), 0.0)
    return float(np.linalg.norm(gap))


def _inside_share(a: Thing, b: Thing) -> float:
    """Share of a's box volume inside b's box."""
    overlap = np.clip(np.minimum(a.hi, b.hi) - np.maximum(a.lo, b.lo), 0, None)
    return float(np.prod(overlap)) / float(np.prod(np.maximum(a.hi - a.lo, 1e-6)))


def _height_overlap(a: Thing, b: Thing) -> float:
    """Overlap of the height ranges as a share of the shorter one's height."""
    overlap = min(a.hi[2], b.hi[2]) - max(a.lo[2], b.lo[2])
    return max(overlap, 0.0) / max(min(a.height_m, b.height_m), 1e-6)


def holds(kind: str, a: Thing, b: Thing, loose: bool = False, viewer=None) -> bool:
    """Whether `a` stands in `kind` (a PAIRWISE_KINDS entry) to `b`; `loose`: as a reader
    might still take it. `viewer` (float [3]) is needed for left_of / right_of."""
    if a.id == b.id:
        return False
    if kind == "on":
        if a.support_id == b.id:
            return True
        resting = b.hi[2] - 0.05 <= a.lo[2] <= b.hi[2] + 0.15
        return loose and resting and _footprint_share(a, b) >= 0.2
    if kind == "in":
        share = _inside_share(a, b)
        return share >= 0.3 if loose else b.category in CONTAINERS and share >= 0.8
    if kind == "under":
        if a.support_id == b.id or a.lo[2] >= b.hi[2] - 0.05:
            return False
        if loose:
            return _footprint_share(a, b) >= 0.1 and a.hi[2] <= b.hi[2] + 0.02
        return _footprint_share(a, b) >= 0.6 and a.hi[2] <= b.hi[2] - 0.1
    if kind == "above":
        gap = a.lo[2] - b.hi[2]
        if loose:
            return gap >= -0.05 and gap <= LOOSE_ABOVE_GAP_M and _footprint_share(a, b) >= 0.1
        return 0.05 <= gap <= ABOVE_MAX_GAP_M and _footprint_share(a, b) >= 0.5
    if kind in ("next_to", "near"):
        gap = _box_gap(a, b)
        if loose:
            return gap <= LOOSE_NEAR_GAP_M
        if kind == "near":
            return gap <= NEAR_GAP_M
        side_by_side = max(_footprint_share(a, b), _footprint_share(b, a)) < 0.2
        return gap <= NEXT_TO_GAP_M and _height_overlap(a, b) >= 0.5 and side_by_side
    if kind in ("left_of", "right_of"):
        bearing = _bearing_deg(a, b, viewer) * (1 if kind == "left_of" else -1)
        return bearing > LOOSE_SIDE_DEG if loose else SIDE_MIN_DEG <= bearing <= 90.0
    raise ValueError(f"unknown relation {kind!r}")


def _bearing_deg(a: Thing, b: Thing, viewer) -> float:
    """a's bearing from the line of sight to b, seen from above at `viewer` (+: left)."""
    if viewer is None:
        raise ValueError("left_of / right_of need the asker's position")
    view = b.centre[:2] - np.asarray(viewer, np.float64)[:2]
    to_a = a.centre[:2] - np.asarray(viewer, np.float64)[:2]
    cross = view[0] * to_a[1] - view[1] * to_a[0]
    return math.degrees(math.atan2(cross, float(view @ to_a)))


def between_holds(a: Thing, b: Thing, c: Thing, loose: bool = False) -> bool:
    """Whether a stands between b and c, seen from above."""
    if len({a.id, b.id, c.id}) < 3:
        return False
    segment = c.centre[:2] - b.centre[:2]
    length = float(np.linalg.norm(segment))
    if length < 1e-6 or (not loose and length > BETWEEN_MAX_SPAN_M):
        return False
    offset = a.centre[:2] - b.centre[:2]
    t = float(offset @ segment) / length**2
    lateral = float(np.linalg.norm(offset - t * segment))
    if loose:
        return -0.1 <= t <= 1.1 and lateral <= LOOSE_BETWEEN_LATERAL_M
    return 0.2 <= t <= 0.8 and lateral <= BETWEEN_LATERAL_M


def distance_to(thing: Thing, xyz: np.ndarray) -> float:
    """From a point to the thing's box, metres."""
    gap = np.maximum(np.maximum(thing.lo - xyz, xyz - thing.hi), 0.0)
    return float(np.linalg.norm(gap))


# --- names ------------------------------------------------------------------------------------


def names_of(category: str) -> tuple[str, ...]:
    return NAMES.get(category, (category,))


def named(phrase: str, loose: bool = False) -> set[str]:
    """The categories a phrase names (loose: and those it might be taken for)."""
    out = {c for c in CATEGORIES if phrase in names_of(c)}
    if loose:
        out |= set(ALSO_MEANT.get(phrase, ()))
    return out


def plural(phrase: str) -> str:
    if phrase.endswith("shelf"):
        return phrase[:-1] + "ves"
    if phrase.endswith(("s", "x", "ch", "sh")):
        return phrase + "es"
    return phrase + "s"


# --- questions ---------------------------------------------------------------------------------


def plain_questions(scene: Scene) -> list[Question]:
    """Each category's built-in paraphrases (the plain query set of `semanticxr eval`)."""
    things = things_of(scene)
    out = []
    for category in sorted({t.category for t in things}):
        ids = tuple(t.id for t in things if t.category == category)
        for text in CATEGORIES[category].paraphrases:
            out.append(Question(text, "plain", "plain", ids, ids, (), category, (), category))
    return out


def relational_questions(
    scene: Scene,
    asker_xyz: Sequence[float] | None,
    seed: int = 0,
    phrasings: int = 3,
    negative_share: float = 0.35,
) -> list[Question]:
    """Questions about how the scene's things stand, each answered by its geometry (module
    docstring): up to `phrasings` phrasings of every uniquely answered relation, and about
    `negative_share` as many negatives. asker_xyz: where the asker stands (world metres) for
    closest / farthest from me and left / right of; None leaves those out."""
    return _Generator(scene, asker_xyz, seed, phrasings).questions(negative_share)


class _Generator:
    def __init__(self, scene: Scene, asker_xyz, seed: int, phrasings: int):
        self.things = things_of(scene)
        self.viewer = None if asker_xyz is None else np.asarray(asker_xyz, np.float64)
        self.rng = np.random.default_rng([int(seed), 0x9E5])
        self.phrasings = phrasings
        self.by_category: dict[str, list[Thing]] = {}
        for t in self.things:
            self.by_category.setdefault(t.category, []).append(t)
        self.phrases = sorted(
            {name for c in self.by_category for name in names_of(c) if self.denoted(name)}
        )
        self._holds: dict[tuple[str, bool], np.ndarray] = {}

    # what a phrase names in this scene
    def denoted(self, phrase: str, loose: bool = False) -> list[Thing]:
        return [t for c in sorted(named(phrase, loose)) for t in self.by_category.get(c, [])]

    def matrix(self, kind: str, loose: bool) -> np.ndarray:
        """bool [n, n]: holds(kind, things[i], things[j], loose)."""
        key = (kind, loose)
        if key not in self._holds:
            n = len(self.things)
            index = np.zeros((n, n), bool)
            if kind not in ("left_of", "right_of") or self.viewer is not None:
                for i, j in itertools.permutations(range(n), 2):
                    index[i, j] = holds(kind, self.things[i], self.things[j], loose, self.viewer)
            self._holds[key] = index
        return self._holds[key]

    def rows(self, things: Iterable[Thing]) -> list[int]:
        position = {t.id: k for k, t in enumerate(self.things)}
        return [position[t.id] for t in things]

    def questions(self, negative_share: float) -> list[Question]:
        groups: dict[tuple, list[tuple]] = {}
        for found in (self.pairwise(), self.between(), self.superlatives(), self.any_target()):
            for key, option in found:
                groups.setdefault(key, []).append(option)
        by_kind: dict[tuple[str, str], list[tuple]] = {}
        for key in sorted(groups, key=repr):
            by_kind.setdefault(key[:2], []).append(key)
        out = []
        for (_, kind), keys in sorted(by_kind.items()):
            cap = GROUPS_PER_KIND.get(kind, GROUPS_PER_KIND["default"])
            if len(keys) > cap:
                keys = [keys[i] for i in sorted(self.rng.choice(len(keys), cap, replace=False))]
            for key in keys:
                out.extend(self.phrase(key, groups[key]))
        negatives = self.negatives(max(1, round(negative_share * len(out))))
        return out + negatives

    def phrase(self, key: tuple, options: list[tuple]) -> list[Question]:
        """Up to `phrasings` distinct questions for one ground truth, drawn from its options
        (template kind, target phrase, anchor phrases)."""
        family, kind, expected, acceptable, anchors, category = key
        written: dict[str, Question] = {}
        for _ in range(4 * self.phrasings):
            if len(written) >= self.phrasings:
                break
            template_kind, target, anchor_phrases = options[int(self.rng.integers(len(options)))]
            templates = _TEMPLATES[template_kind]
            template = templates[int(self.rng.integers(len(templates)))]
            text = _fill(template, target, anchor_phrases)
            written.setdefault(
                text,
                Question(
                    text, family, kind, expected, acceptable, anchors, target,
                    tuple(anchor_phrases), category,
                ),
            )  # fmt: skip
        return list(written.values())

    def targets(self, kind: str) -> list[tuple[str, list[Thing], list[Thing]]]:
        """(phrase, what it names, what it may be taken for) for the phrases naming two or
        more things of the scene (questions pick one of several), some of them fit to be the
        target of `kind` (the answer must be)."""
        out = []
        for phrase in self.phrases:
            strict = self.denoted(phrase)
            if len(strict) >= 2 and any(_fits(kind, "target", t) for t in strict):
                out.append((phrase, strict, self.denoted(phrase, loose=True)))
        return out

    def anchors(self, kind: str) -> list[tuple[str, list[Thing], list[Thing]]]:
        """(phrase, what it names, what it may be taken for) fit to be an anchor of `kind`."""
        out = []
        for phrase in self.phrases:
            strict = self.denoted(phrase)
            if strict and all(_fits(kind, "anchor", t) for t in strict):
                out.append((phrase, strict, self.denoted(phrase, loose=True)))
        return out

    def pairwise(self):
        for kind in PAIRWISE_KINDS:
            if kind in ("left_of", "right_of") and self.viewer is None:
                continue
            strict_m, loose_m = self.matrix(kind, False), self.matrix(kind, True)
            for target, strict_t, loose_t in self.targets(kind):
                for anchor, strict_a, loose_a in self.anchors(kind):
                    if _overlap(loose_t, loose_a):
                        continue  # "the chair next to the chair"
                    rows_a = self.rows(strict_a)
                    sat = [i for i in self.rows(strict_t) if strict_m[i, rows_a].any()]
                    loose_rows_a = self.rows(loose_a)
                    loose_sat = [i for i in self.rows(loose_t) if loose_m[i, loose_rows_a].any()]
                    if len(sat) != 1 or loose_sat != sat:
                        continue
                    answer = self.things[sat[0]]
                    if not _fits(kind, "target", answer):
                        continue
                    anchors = tuple(
                        sorted(self.things[j].id for j in rows_a if strict_m[sat[0], j])
                    )
                    key = ("relational", kind, (answer.id,), (answer.id,), anchors, answer.category)
                    yield key, (kind, target, (anchor,))

    def between(self):
        anchors = self.anchors("between")
        pairs = [*itertools.combinations(anchors, 2), *((a, a) for a in anchors)]
        for target, strict_t, loose_t in self.targets("between"):
            for (phrase_b, strict_b, loose_b), (phrase_c, strict_c, loose_c) in pairs:
                if _overlap(loose_t, loose_b + loose_c):
                    continue
                sat: dict[int, set[int]] = {}
                for t, b, c in itertools.product(strict_t, strict_b, strict_c):
                    if between_holds(t, b, c):
                        sat.setdefault(t.id, set()).update((b.id, c.id))
                if len(sat) != 1:
                    continue
                loose_sat = {
                    t.id
                    for t, b, c in itertools.product(loose_t, loose_b, loose_c)
                    if between_holds(t, b, c, loose=True)
                }
                if loose_sat != set(sat):
                    continue
                ((answer_id, anchor_ids),) = sat.items()
                answer = next(t for t in strict_t if t.id == answer_id)
                if not _fits("between", "target", answer):
                    continue
                category = answer.category
                key = (
                    "relational", "between", (answer_id,), (answer_id,),
                    tuple(sorted(anchor_ids)), category,
                )  # fmt: skip
                if phrase_b == phrase_c:
                    yield key, ("between_two", target, (phrase_b,))
                else:
                    yield key, ("between", target, (phrase_b, phrase_c))

    def superlatives(self):
        for kind in SUPERLATIVE_KINDS:
            if kind in ("closest", "farthest") and self.viewer is None:
                continue
            for target, strict_t, loose_t in self.targets(kind):
                distance = None if kind not in ("closest", "farthest") else self.from_asker
                answer = _extreme(kind, strict_t, loose_t, distance)
                if answer is not None and _fits(kind, "target", answer):
                    key = ("relational", kind, (answer.id,), (answer.id,), (), answer.category)
                    yield key, (kind, target, ())
        for target, strict_t, loose_t in self.targets("closest_to"):
            for anchor, _, loose_a in self.anchors("closest_to"):
                if len(loose_a) != 1 or _overlap(loose_t, loose_a):
                    continue  # from one thing only
                (a,) = loose_a
                answer = _extreme("closest", strict_t, loose_t, lambda t, a=a: _box_gap(t, a))
                if answer is not None:
                    key = (
                        "relational", "closest_to", (answer.id,), (answer.id,), (a.id,),
                        answer.category,
                    )  # fmt: skip
                    yield key, ("closest_to", target, (anchor,))

    def from_asker(self, thing: Thing) -> float:
        return distance_to(thing, self.viewer)

    def any_target(self):
        for kind in ANY_TARGET_KINDS:
            strict_m, loose_m = self.matrix(kind, False), self.matrix(kind, True)
            for anchor, strict_a, loose_a in self.anchors(kind):
                if len(strict_a) != 1 or len(loose_a) != 1:
                    continue  # "what is on the table" with two tables: which one?
                (j,) = self.rows(strict_a)
                expected = tuple(t.id for i, t in enumerate(self.things) if strict_m[i, j])
                acceptable = tuple(t.id for i, t in enumerate(self.things) if loose_m[i, j])
                if expected:
                    key = ("any", kind, expected, acceptable, (self.things[j].id,), "")
                    yield key, (f"any_{kind}", "", (anchor,))

    def negatives(self, count: int) -> list[Question]:
        """Up to `count` questions nothing satisfies, even loosely, each of a different
        (target category, relation, anchor category), spread over the kinds."""
        by_kind: dict[str, list[tuple]] = {}
        for kind in NEGATIVE_KINDS:
            loose_m = self.matrix(kind, True)
            for target in self.phrases:
                strict_t = self.denoted(target)
                if not strict_t or not any(_fits(kind, "target", t) for t in strict_t):
                    continue
                loose_t = self.denoted(target, loose=True)
                for anchor, strict_a, loose_a in self.anchors(kind):
                    if _overlap(loose_t, loose_a):
                        continue
                    if loose_m[np.ix_(self.rows(loose_t), self.rows(loose_a))].any():
                        continue
                    option = (kind, target, anchor, strict_t[0].category, strict_a)
                    by_kind.setdefault(kind, []).append(option)
        for options in by_kind.values():
            self.rng.shuffle(options)
        out: list[Question] = []
        seen: set[tuple] = set()
        while len(out) < count and any(by_kind.values()):
            for kind in NEGATIVE_KINDS:  # round robin over the kinds
                options = by_kind.get(kind, [])
                while options and len(out) < count:
                    kind, target, anchor, category_t, strict_a = options.pop()
                    if (category_t, kind, strict_a[0].category) in seen:
                        continue
                    seen.add((category_t, kind, strict_a[0].category))
                    templates = _TEMPLATES[kind]
                    text = _fill(
                        templates[int(self.rng.integers(len(templates)))], target, (anchor,)
                    )
                    anchors = tuple(t.id for t in strict_a)
                    out.append(
                        Question(
                            text, "negative", kind, (), (), anchors, target, (anchor,), category_t
                        )
                    )
                    break
        return out


def _extreme(kind: str, strict: list[Thing], loose: list[Thing], distance) -> Thing | None:
    """The one strict candidate that is `kind` (a superlative) by a clear margin over every
    other loose candidate, or None."""
    if kind in ("closest", "farthest"):
        value = {t.id: distance(t) for t in loose}
        sign = 1 if kind == "closest" else -1
        best = min(strict, key=lambda t: sign * value[t.id])
        others = [value[t.id] for t in loose if t.id != best.id]
        if not others:
            return None
        gap = min(sign * (v - value[best.id]) for v in others)
        scale = max(value[best.id], min(others)) if kind == "closest" else value[best.id]
        return best if gap >= max(CLOSEST_MARGIN_M, CLOSEST_MARGIN_SHARE * scale) else None
    if kind in ("biggest", "smallest"):
        sign = 1 if kind == "biggest" else -1
        best = max(strict, key=lambda t: sign * math.log(t.volume_m3))
        others = [t.volume_m3 for t in loose if t.id != best.id]
        if not others:
            return None
        ratio = min((best.volume_m3 / v) ** sign for v in others)
        return best if ratio >= SIZE_MARGIN_RATIO else None
    sign = 1 if kind == "highest" else -1
    best = max(strict, key=lambda t: sign * t.centre[2])
    for other in loose:
        if other.id == best.id:
            continue
        for height in (lambda t: t.lo[2], lambda t: t.centre[2], lambda t: t.hi[2]):
            if sign * (height(best) - height(other)) < HEIGHT_MARGIN_M:
                return None
    return best if len(loose) > 1 else None


def _overlap(a: Sequence[Thing], b: Sequence[Thing]) -> bool:
    return bool({t.id for t in a} & {t.id for t in b})


_FLOOR_THINGS = ("floor_wall", "floor_free")
_SEATS = frozenset({"chair", "sofa", "armchair", "office chair", "ottoman", "bar stool", "bed"})
_NOT_ANCHORS = frozenset({"potted plant", "trash can", "backpack", "floor lamp", "ottoman"})


def _fits(kind: str, role: str, thing: Thing) -> bool:
    """Whether a thing is fit to be the target or the anchor of a `kind` question: what
    people ask about ("the painting above the sofa", "the bag under the table"), not every
    geometric truth ("the painting between the chair and the nightstand")."""
    placement = CATEGORIES[thing.category].placement
    on_floor = thing.support_id == 0 and thing.lo[2] < 0.05 and placement in _FLOOR_THINGS
    if role == "anchor":
        if kind == "in":
            return thing.category in CONTAINERS
        if kind in ("on", "under"):
            surface = CATEGORIES[thing.category].is_surface or thing.category in _SEATS
            return on_floor and surface
        if kind == "closest_to":
            return on_floor and thing.category not in _NOT_ANCHORS or thing.category == "window"
        return on_floor and thing.category not in _NOT_ANCHORS
    if kind == "above":
        return placement in ("wall", "ceiling")
    if placement in ("wall", "ceiling"):
        return False
    if kind in ("under", "next_to", "near", "left_of", "right_of", "between"):
        return on_floor
    return True


def _fill(template: str, target: str, anchors: Sequence[str]) -> str:
    a = anchors[0] if anchors else ""
    b = anchors[1] if len(anchors) > 1 else ""
    return template.format(t=target, a=a, b=b, **{"as": plural(a)})
