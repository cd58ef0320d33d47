"""SessionApi's living-map calls through a real server: the changes it concluded, and a query
that ranks removed things too ("where did I last see the book")."""

from __future__ import annotations

import asyncio

import pytest
from devices import stream_in_step
from living_world import BOOK, KNOBS, MUG, WALK_2_T, WALL, walk

from app.client import SessionApi, create_session

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def book_taken(live_server):
    """(server url, sid, token) of a session that mapped a mug and a book, then a second walk
    ten minutes later without the book."""
    server = live_server()

    async def visit() -> tuple[str, str]:
        sid, token, _ = await create_session(server.url, knobs=KNOBS)
        stream_url = f"{server.ws_url}/v1/sessions/{sid}/stream"
        await stream_in_step(stream_url, walk([WALL, MUG, BOOK], 0.0))
        await stream_in_step(stream_url, walk([WALL, MUG], WALK_2_T))
        return sid, token

    sid, token = asyncio.run(visit())
    return server.url, sid, token


def test_changes_lists_what_the_map_concluded_with_now_t_and_filters_by_kind(book_taken):
    async def ask() -> tuple[dict, dict]:
        async with SessionApi(*book_taken) as api:
            return await api.changes(), await api.changes(kind="moved", since_t=WALK_2_T)

    everything, moved = asyncio.run(ask())
    assert ("book", "removed") in {(c["label"], c["kind"]) for c in everything["changes"]}
    assert everything["now_t"] == WALK_2_T + 6
    assert moved["changes"] == []


def test_a_query_with_include_removed_answers_where_a_taken_thing_was_last_seen(book_taken):
    async def ask() -> tuple[dict, list[dict]]:
        async with SessionApi(*book_taken) as api:
            result = await api.query_result("book", k=3, include="removed")
            return result, await api.query("book", k=3)

    result, present_only = asyncio.run(ask())
    book = next(hit for hit in result["results"] if hit["label"] == "book")
    assert book["state"] == "removed" and "points" not in book
    assert book["last_seen_t"] < WALK_2_T <= result["now_t"]
    assert all(hit["state"] == "present" for hit in present_only)
    assert not any(hit["label"] == "book" for hit in present_only)
