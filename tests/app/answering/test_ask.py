"""`ask`: a question read, then answered relationally or left to the plain ranking; the one
way the server, the device's local map, its query router and the relations eval ask."""

from __future__ import annotations

import numpy as np
import pytest
from relation_scene import SCENE

from app.answering.ask import ask, relational_reading
from app.answering.relational import answer
from app.answering.things import MapThing
from app.relations.grammar import parse
from app.relations.index import ObjectGeometry, RelationIndex


@pytest.fixture(scope="module")
def scene(encoder):
    labels = sorted({label for label, _ in SCENE.values()})
    embedding = dict(zip(labels, encoder.encode(labels), strict=True))
    things = [MapThing(i, label, embedding[label]) for i, (label, _) in SCENE.items()]
    index = RelationIndex()
    index.update({i: ObjectGeometry(label, pts) for i, (label, pts) in SCENE.items()})
    return things, index, encoder


@pytest.mark.parametrize("text", ["where is my mug", "the coffee mug", "turn on the lamp"])
def test_a_plain_question_has_no_relational_reading(text):
    assert relational_reading(text) is None


@pytest.mark.parametrize("text", ["the mug on the desk", "the biggest table"])
def test_a_question_about_how_things_stand_has_its_reading(text):
    reading = relational_reading(text)
    assert reading is not None and reading == parse(text)
    assert relational_reading(reading) is reading


def test_a_plain_question_is_left_to_the_plain_ranking(scene):
    things, index, encoder = scene
    assert ask("where is my mug", things, index, encoder) is None


@pytest.mark.parametrize("text", ["the mug on the desk", "what is under the table"])
def test_ask_answers_as_the_relational_answer_does(scene, text):
    things, index, encoder = scene
    viewer = np.array([0.0, -2.0, 1.6])
    asked = ask(text, things, index, encoder, viewer, k=3)
    assert asked is not None and asked == answer(parse(text), things, index, encoder, viewer, 3)
