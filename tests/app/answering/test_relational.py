"""Relational answers from a map of sampled-point boxes, with the real text encoder: the right
copy of a duplicated category, no match when nothing satisfies the relation, plain questions
left plain."""

from __future__ import annotations

import numpy as np
import pytest
from relation_scene import SCENE

from app.answering.phrases import head_noun, same_head
from app.answering.question import FLOOR_ANCHOR
from app.answering.relational import answer
from app.answering.superlative import category_of
from app.answering.things import MapThing, is_match
from app.relations.grammar import parse
from app.relations.index import ObjectGeometry, RelationIndex

Z_UP = np.array([0.0, 0.0, 1.0])


def map_of(room, encoder):
    """(things, relation index, encoder) of a room {id: (label, points)}, Z-up."""
    labels = sorted({label for label, _ in room.values()})
    embedding = dict(zip(labels, encoder.encode(labels), strict=True))
    things = [MapThing(i, label, embedding[label]) for i, (label, _) in room.items()]
    index = RelationIndex(Z_UP)
    index.update({i: ObjectGeometry(label, pts) for i, (label, pts) in room.items()})
    return things, index, encoder


@pytest.fixture(scope="module")
def scene(encoder):
    return map_of(SCENE, encoder)


def ask(scene, text, viewer=None, k=5):
    things, index, encoder = scene
    return answer(parse(text), things, index, encoder, viewer=viewer, k=k)


@pytest.mark.parametrize(
    ("text", "expected", "kind", "anchor"),
    [
        ("the mug on the desk", 10, "on", 1),
        ("the mug on the shelf", 11, "on", 2),
        ("mug sitting on the table", 12, "on", 3),
        ("which chair is next to the sofa", 21, "next_to", 4),
        ("what is under the table", 30, "under", 3),
    ],
)
def test_a_relation_picks_the_copy_that_stands_in_it(scene, text, expected, kind, anchor):
    hits = ask(scene, text)
    assert hits is not None
    best = hits[0]
    assert best.id == expected, [(h.id, h.label, round(h.score, 3)) for h in hits]
    assert best.relation.kind == kind
    assert best.relation.anchors == [(anchor, SCENE[anchor][0])]
    assert best.relation.degree > 0.5
    assert is_match(hits)


def test_a_relation_nothing_satisfies_answers_no_match(scene):
    hits = ask(scene, "the mug under the sofa")
    assert hits is not None and hits[0].label == "mug"
    assert hits[0].relation.degree == 0.0
    assert not is_match(hits)


@pytest.mark.parametrize("text", ["where are my keys", "the red mug", "keys on a ring"])
def test_a_plain_question_or_an_anchor_not_on_the_map_is_left_to_the_plain_ranking(scene, text):
    assert ask(scene, text) is None


def test_the_superlative_ranks_within_the_category(scene):
    hits = ask(scene, "the highest mug")
    assert hits is not None and hits[0].id == 11 and hits[0].relation.kind == "highest"
    assert {h.label for h in hits[:3]} == {"mug"}


def test_closest_to_me_needs_the_askers_position(scene):
    assert ask(scene, "the mug closest to me") is None
    hits = ask(scene, "the mug closest to me", viewer=np.array([1.0, 4.5, 1.6]))
    assert hits is not None and hits[0].id == 12 and is_match(hits)


@pytest.mark.parametrize(
    ("phrase", "head"),
    [
        ("dining table", "table"),
        ("the tables", "table"),
        ("shelves", "shelf"),
        ("glass", "glass"),
        ("boxes", "box"),
        ("batteries", "battery"),
        ("", ""),
    ],
)
def test_head_noun_is_the_last_word_singular(phrase, head):
    assert head_noun(phrase) == head


def test_an_anchor_named_by_its_head_noun_grounds_to_the_longer_label(encoder):
    """ "the table" means the map's dining table, "the counter" its kitchen counter, though
    the encoder rates those labels low for the bare word."""
    renamed = {3: "dining table", 2: "wall shelf"}
    room = {i: (renamed.get(i, label), points) for i, (label, points) in SCENE.items()}
    renamed_map = map_of(room, encoder)
    for text, expected, anchor in [
        ("the mug on the table", 12, 3),
        ("the mug on the shelf", 11, 2),
    ]:
        hits = ask(renamed_map, text)
        assert hits is not None and hits[0].id == expected, text
        assert hits[0].relation.anchors == [(anchor, renamed[anchor])]
        assert is_match(hits)
    assert same_head("the table", "dining table") and not same_head("table", "table lamp")


def test_the_floor_is_an_implicit_surface(scene):
    hits = ask(scene, "the bag on the floor")
    assert hits is not None and hits[0].id == 30 and is_match(hits)
    assert hits[0].relation.kind == "on" and hits[0].relation.anchors == [FLOOR_ANCHOR]
    on_ground = ask(scene, "the chair on the ground")
    assert on_ground is not None and {h.id for h in on_ground[:2]} == {20, 21}
    mugs = ask(scene, "the mug on the floor")  # every mug stands on furniture
    assert mugs is not None and mugs[0].label == "mug" and not is_match(mugs)
    assert ask(scene, "the bag under the floor") is None  # only "on the floor" is read


def test_a_map_holding_a_floor_object_answers_by_it(encoder):
    floor = np.stack(
        [*np.meshgrid(np.linspace(-1, 6, 30), np.linspace(-1, 6, 30)), np.zeros((30, 30))], -1
    ).reshape(-1, 3)
    room = {**SCENE, 99: ("floor", floor)}
    hits = ask(map_of(room, encoder), "what is under the floor")
    assert hits is not None and hits[0].relation.anchors == [(99, "floor")]


@pytest.mark.parametrize(
    ("phrase", "label", "names"),
    [
        ("the table", "dining table", True),
        ("dining table", "dining table", True),
        ("the shelf", "bookshelf", True),
        ("counter", "kitchen counter", True),
        ("side table", "dining table", False),  # a modifier the label lacks
        ("table", "table lamp", False),
        ("case", "bookcase", False),  # too short a head for a compound
        ("floor", "floor lamp", False),
    ],
)
def test_a_phrase_names_a_label_by_its_head_noun_and_its_modifiers(phrase, label, names):
    assert same_head(phrase, label) is names


@pytest.mark.parametrize(
    ("relevance", "members"),
    [
        ([0.9, 0.4, 0.75], [0, 2]),  # the confident ones near the best
        ([1.0, 0.6, 0.85], [0, 2]),  # not one a margin behind the best (a floor lamp)
        ([1.0, 0.75, 0.7], [0, 1]),  # but always one its head noun names (a table lamp)
        ([0.35, 0.35, 0.1], [0, 1]),  # none confident: those rated as the best one is
        ([0.2, 0.1], []),  # nothing is what the phrase names
        ([], []),
    ],
)
def test_a_superlatives_category(relevance, members):
    assert category_of(np.array(relevance, np.float64)).tolist() == members


def test_what_stands_on_a_thing_is_not_a_piece_of_it(encoder):
    """A shelf mapped as two objects: the second piece is not "what is on the shelf"."""
    room = {**SCENE, 77: ("shelf", SCENE[2][1] + np.array([0.0, 0.0, 0.2]))}
    hits = ask(map_of(room, encoder), "what is on the shelf")
    assert hits is not None and hits[0].id == 11 and "shelf" not in {h.label for h in hits[:1]}
