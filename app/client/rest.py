"""The REST calls of wire protocol v1: create, list, read, export, import and delete sessions,
change their knobs, query them."""

from __future__ import annotations

import asyncio
import ssl
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx

from app.client.connection import auth_headers, http_base_url
from app.errors import InputError
from app.protocol import (
    SessionStats,
    SessionSummary,
    SpokenQueryResult,
    parse_query_result,
    parse_record,
)
from app.protocol.rest import R

REST_TIMEOUT_S = 10.0
"""Longest wait for one REST call, whole (connect, send, answer)."""
SPEECH_TIMEOUT_S = 60.0
"""Longest wait for a spoken question, whole: its upload (up to the server's
`--max-audio-bytes`, about 4 MiB) and its recognition."""
AUDIO_FILE_TYPES = {
    ".wav": "audio/wav",
    ".webm": "audio/webm",
    ".ogg": "audio/ogg",
    ".m4a": "audio/mp4",
    ".mp4": "audio/mp4",
}
"""The Content-Type of an audio file by its extension, for `POST .../query/speech`."""


class ApiError(RuntimeError):
    """A REST call failed: the server was unreachable or slow, or answered with another
    status than expected, or with a body that is not JSON. The message names the call."""

    def __init__(self, message: str, status: int | None = None):
        super().__init__(message)
        self.status = status
        """The HTTP status, when the server answered."""


def audio_type(path: str | Path) -> str:
    """The Content-Type of a recorded question, from its file's extension (case ignored);
    ValueError naming the extensions known."""
    suffix = Path(path).suffix.lower()
    if suffix not in AUDIO_FILE_TYPES:
        known = " ".join(AUDIO_FILE_TYPES)
        raise ValueError(
            f"{path}: cannot tell the audio type of {suffix or 'no extension'}: use {known}"
        )
    return AUDIO_FILE_TYPES[suffix]


def http_client(
    token: str | None,
    *,
    timeout_s: float = REST_TIMEOUT_S,
    ssl_context: ssl.SSLContext | None = None,
    headers: dict[str, str] | None = None,
) -> httpx.AsyncClient:
    """An HTTP client of the API: `Authorization` for `token` (a session's token or the API
    key), `headers` besides; ssl_context: whom an https:// server must prove to be
    (`app.client.connection.trusting`), default the system's CAs."""
    return httpx.AsyncClient(
        timeout=timeout_s,
        headers={**auth_headers(token), **(headers or {})},
        verify=ssl_context if ssl_context is not None else True,
    )


def _answer(method: str, url: str, response: httpx.Response, expect: int) -> Any:
    """The JSON body of an answer with status `expect`, or ApiError naming the status and
    the server's detail."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if response.status_code != expect:
        detail = body.get("detail", body) if isinstance(body, dict) else response.text[:200]
        raise ApiError(
            f"{method} {url}: HTTP {response.status_code}: {detail}", response.status_code
        )
    if body is None:
        raise ApiError(f"{method} {url}: the answer is not JSON", response.status_code)
    return body


async def request(
    http: httpx.AsyncClient,
    method: str,
    url: str,
    *,
    expect: int = 200,
    timeout_s: float = REST_TIMEOUT_S,
    **kwargs: Any,
) -> Any:
    """One REST call on `http`, bounded by `timeout_s` as a whole; its JSON answer."""
    try:
        # wait_for bounds the whole call; httpx's timeout bounds each phase only.
        response = await asyncio.wait_for(http.request(method, url, **kwargs), timeout_s)
    except (httpx.HTTPError, TimeoutError) as exc:
        raise ApiError(f"{method} {url}: {type(exc).__name__}: {exc}") from exc
    return _answer(method, url, response, expect)


async def create_session(
    server_url: str,
    *,
    name: str | None = None,
    mode: str = "semanticxr",
    knobs: dict | None = None,
    api_key: str | None = None,
    ssl_context: ssl.SSLContext | None = None,
    text_tower: str | None = None,
) -> tuple[str, str, dict]:
    """POST /v1/sessions -> (session_id, token, the whole answer incl. embedding, knobs).
    text_tower: "minilm" or "static" (None: the server's default, minilm); the first static
    session of a server may wait minutes for its tower's distillation."""
    body: dict[str, Any] = {"mode": mode, "knobs": knobs or {}}
    if name is not None:
        body["name"] = name
    if text_tower is not None:
        body["text_tower"] = text_tower
    url = f"{http_base_url(server_url)}/v1/sessions"
    timeout_s = REST_TIMEOUT_S if text_tower in (None, "minilm") else TOWER_DISTIL_TIMEOUT_S
    async with http_client(api_key, ssl_context=ssl_context, timeout_s=timeout_s) as http:
        answer = await request(http, "POST", url, expect=201, json=body, timeout_s=timeout_s)
    return answer["session_id"], answer["token"], answer


TOWER_DISTIL_TIMEOUT_S = 900.0
"""Longest wait for a static session's creation: a server's first one distils its tower."""
EXPORT_TIMEOUT_S = 300.0
"""Longest wait for an export or import, whole (a map may be tens of megabytes)."""


async def list_sessions(
    server_url: str, *, api_key: str | None = None, ssl_context: ssl.SSLContext | None = None
) -> list[SessionSummary]:
    """GET /v1/sessions: every session's summary, parsed by the protocol."""
    url = f"{http_base_url(server_url)}/v1/sessions"
    async with http_client(api_key, ssl_context=ssl_context) as http:
        answer = await request(http, "GET", url)
    if not isinstance(answer, list):
        raise ApiError(f"GET {url}: a malformed answer: expected a list of sessions")
    return [parsed_answer(SessionSummary, entry, f"GET {url}") for entry in answer]


async def delete_session(
    server_url: str,
    session_id: str,
    *,
    token: str | None = None,
    ssl_context: ssl.SSLContext | None = None,
) -> None:
    """DELETE /v1/sessions/{sid} (token: the session's, or the API key)."""
    url = f"{http_base_url(server_url)}/v1/sessions/{session_id}"
    async with http_client(token, ssl_context=ssl_context) as http:
        try:
            response = await asyncio.wait_for(http.delete(url), REST_TIMEOUT_S)
        except (httpx.HTTPError, TimeoutError) as exc:
            raise ApiError(f"DELETE {url}: {type(exc).__name__}: {exc}") from exc
    if response.status_code != 204:
        _answer("DELETE", url, response, 204)  # raises, with the server's detail


async def export_map(
    server_url: str,
    session_id: str,
    out: Path,
    *,
    format: str = "json",
    embeddings: bool = False,
    token: str | None = None,
    ssl_context: ssl.SSLContext | None = None,
) -> int:
    """GET /v1/sessions/{sid}/export, streamed to `out` (written only when the answer is
    200); returns the bytes written."""
    url = f"{http_base_url(server_url)}/v1/sessions/{session_id}/export"
    params = {"format": format, "embeddings": "true" if embeddings else "false"}
    partial = out.with_name(out.name + ".part")

    async def fetch() -> int:
        async with (
            http_client(token, ssl_context=ssl_context) as http,
            http.stream("GET", url, params=params) as response,
        ):
            if response.status_code != 200:
                await response.aread()
                _answer("GET", url, response, 200)  # raises, with the server's detail
            written = 0
            with partial.open("wb") as f:
                async for chunk in response.aiter_bytes():
                    written += f.write(chunk)
            partial.replace(out)
            return written

    try:
        return await asyncio.wait_for(fetch(), EXPORT_TIMEOUT_S)
    except (httpx.HTTPError, TimeoutError) as exc:
        raise ApiError(f"GET {url}: {type(exc).__name__}: {exc}") from exc
    finally:
        partial.unlink(missing_ok=True)


async def import_map(
    server_url: str,
    export: bytes,
    *,
    api_key: str | None = None,
    ssl_context: ssl.SSLContext | None = None,
) -> dict:
    """POST /v1/sessions/import with a JSON export (its bytes) -> the SessionCreated answer.
    A map bigger than the server's body limit is refused (413): the error says so."""
    url = f"{http_base_url(server_url)}/v1/sessions/import"
    headers = {"Content-Type": "application/json"}
    async with http_client(api_key, ssl_context=ssl_context, headers=headers) as http:
        try:
            return await request(
                http, "POST", url, expect=201, timeout_s=EXPORT_TIMEOUT_S, content=export
            )
        except ApiError as exc:
            if exc.status == 413:
                raise ApiError(
                    f"{exc}: this map is {len(export)} bytes, over the server's request body "
                    "limit; start the server with a bigger --max-body-bytes to import it",
                    413,
                ) from None
            raise


MAX_TOWER_BYTES = 64 << 20
"""Largest static text tower a client downloads (a 256-d int8 table of 30,522 tokens is
about 8 MB)."""
TOWER_TIMEOUT_S = 120.0
"""Longest wait for a tower's download, whole."""


def fetch_text_tower(
    server_url: str,
    sha256: str,
    *,
    ssl_context: ssl.SSLContext | None = None,
    max_bytes: int = MAX_TOWER_BYTES,
    timeout_s: float = TOWER_TIMEOUT_S,
) -> bytes:
    """GET /v1/text-towers/{sha256}: the tower file's bytes (blocking: call it from a
    thread). ApiError naming the call when the server is unreachable or slow (over
    `timeout_s` in all), answers another status than 200, or sends more than `max_bytes`
    (refused as soon as its Content-Length or its bytes say so). The caller checks the hash."""
    url = f"{http_base_url(server_url)}/v1/text-towers/{sha256}"
    deadline = time.monotonic() + timeout_s
    try:
        with (
            httpx.Client(
                timeout=timeout_s, verify=ssl_context if ssl_context is not None else True
            ) as http,
            http.stream("GET", url) as response,
        ):
            if response.status_code != 200:
                response.read()
                _answer("GET", url, response, 200)  # raises, with the server's detail
            length = response.headers.get("content-length")
            if length is not None and length.isdigit() and int(length) > max_bytes:
                raise ApiError(f"GET {url}: the tower is {length} bytes, over {max_bytes}")
            chunks, size = [], 0
            for chunk in response.iter_bytes():
                size += len(chunk)
                if size > max_bytes:
                    raise ApiError(f"GET {url}: the tower is over {max_bytes} bytes")
                if time.monotonic() > deadline:
                    raise ApiError(f"GET {url}: the download took over {timeout_s:g} s")
                chunks.append(chunk)
    except httpx.HTTPError as exc:
        raise ApiError(f"GET {url}: {type(exc).__name__}: {exc}") from exc
    return b"".join(chunks)


class SessionApi:
    """The REST calls on one session, over one kept-alive HTTP connection.

    server_url: http(s)://host:port (ws(s):// is mapped back). token: the session's token or
    the API key (None for an open server). timeout_s: longest wait for each call, whole.
    ssl_context: whom an https:// server must prove to be (default: the system's CAs).
    Use `async with`, or `aclose()` when done; the connection opens at the first call (on
    the loop of that call).
    """

    def __init__(
        self,
        server_url: str,
        session_id: str,
        token: str | None = None,
        *,
        timeout_s: float = REST_TIMEOUT_S,
        ssl_context: ssl.SSLContext | None = None,
    ):
        self.http_url = http_base_url(server_url)
        self.session_id = session_id
        self.token = token
        self.timeout_s = float(timeout_s)
        self.ssl_context = ssl_context
        self.session_url = f"{self.http_url}/v1/sessions/{session_id}"
        self._http: httpx.AsyncClient | None = None

    def _client(self) -> httpx.AsyncClient:
        if self._http is None:
            self._http = http_client(
                self.token, timeout_s=self.timeout_s, ssl_context=self.ssl_context
            )
        return self._http

    async def _call(self, method: str, url: str, expect: int = 200, **kwargs: Any) -> Any:
        return await request(
            self._client(), method, url, expect=expect, timeout_s=self.timeout_s, **kwargs
        )

    async def fetch(self) -> SessionStats:
        """GET /v1/sessions/{sid}, parsed by the protocol: stats, knobs in force, embedding
        model and dimension."""
        answer = await self._call("GET", self.session_url)
        return parsed_answer(SessionStats, answer, f"GET {self.session_url}")

    async def patch_knobs(self, changes: dict) -> dict:
        """PATCH /v1/sessions/{sid}/knobs -> the knobs now in force."""
        return await self._call("PATCH", f"{self.session_url}/knobs", json=changes)

    async def query(
        self,
        text: str,
        k: int = 5,
        *,
        include: str | None = None,
        from_xyz: Sequence[float] | None = None,
    ) -> list[dict]:
        """GET /v1/sessions/{sid}/query: the k best hits, best first, without their points
        ({"id", "label", "score", "bbox", "centroid"}; "relation" for a question about how
        things stand). include="removed" ranks the living map's removed objects too (where a
        thing was last seen); from_xyz: where the asker stands, world metres, for questions
        seen from them ("the lamp closest to me"; default: the session's newest pose)."""
        return (await self.query_result(text, k, include=include, from_xyz=from_xyz))["results"]

    async def query_result(
        self,
        text: str,
        k: int = 5,
        *,
        include: str | None = None,
        from_xyz: Sequence[float] | None = None,
        rerank: bool = False,
    ) -> dict:
        """`query`'s whole answer: {"text", "match", "results" (as `query` gives them),
        "latency_ms", "now_t", "ranked_by"} (now_t: the session's newest frame t, what "last
        seen ... ago" counts from; None from a server without the living map). rerank: on a
        static-tower session, MiniLM re-ranks on the server (`ranked_by` says which did)."""
        params = _query_params(text, k, include, from_xyz, rerank)
        answer = await self._call("GET", f"{self.session_url}/query", params=params)
        return _result(answer)

    async def query_speech(
        self,
        audio: bytes,
        content_type: str,
        k: int = 5,
        *,
        include: str | None = None,
        from_xyz: Sequence[float] | None = None,
        rerank: bool = False,
    ) -> dict:
        """POST /v1/sessions/{sid}/query/speech: `audio` (a whole file of `content_type`:
        audio/wav, audio/webm, audio/ogg or audio/mp4; `audio_type` of its name) recognised by
        the server and answered as `query_result` answers the text it heard: that dict plus
        "transcript", "confidence" (None when the recogniser gives none) and "asr_ms" (the
        recognition's own time). Bounded by SPEECH_TIMEOUT_S, not the session's timeout. rerank:
        as `query_result`'s."""
        params = _query_params(None, k, include, from_xyz, rerank)
        url = f"{self.session_url}/query/speech"
        answer = await request(
            self._client(),
            "POST",
            url,
            timeout_s=SPEECH_TIMEOUT_S,
            timeout=SPEECH_TIMEOUT_S,  # each phase too: the answer waits for the recognition
            params=params,
            content=audio,
            headers={"Content-Type": content_type},
        )
        return _spoken_result(answer, f"POST {url}")

    async def changes(
        self,
        *,
        since_t: float | None = None,
        until_t: float | None = None,
        since_seq: int | None = None,
        kind: str | None = None,
        limit: int | None = None,
    ) -> dict:
        """GET /v1/sessions/{sid}/changes: {"changes": [{"id", "kind", "t", "label", "from"?,
        "to"?, "seq", "place"}], "now_t"}, what the living map concluded, in arrival order
        (filters as docs/protocol.md says; None leaves one out)."""
        filters = {
            "since_t": since_t,
            "until_t": until_t,
            "since_seq": since_seq,
            "kind": kind,
            "limit": limit,
        }
        params = {name: value for name, value in filters.items() if value is not None}
        return await self._call("GET", f"{self.session_url}/changes", params=params)

    async def objects(self, *, points: bool = False) -> list[dict]:
        """GET /v1/sessions/{sid}/objects: the confirmed objects (with their points if asked)."""
        params = {"points": "true" if points else "false"}
        return await self._call("GET", f"{self.session_url}/objects", params=params)

    def query_blocking(self, text: str, k: int = 5) -> list[dict]:
        """`query` for a caller without an event loop (a GUI callback's thread)."""
        return self.query_result_blocking(text, k)["results"]

    def query_result_blocking(self, text: str, k: int = 5) -> dict:
        """`query_result` for a caller without an event loop (a GUI callback's thread): the
        whole answer, with `match` (a relational answer's is not the hits' relevance)."""
        url = f"{self.session_url}/query"
        try:
            response = httpx.get(
                url,
                params=_query_params(text, k),
                headers=auth_headers(self.token),
                timeout=self.timeout_s,
                verify=self.ssl_context if self.ssl_context is not None else True,
            )
        except httpx.HTTPError as exc:
            raise ApiError(f"GET {url}: {type(exc).__name__}: {exc}") from exc
        return _result(_answer("GET", url, response, 200))

    async def health(self) -> None:
        """GET /healthz (the cheapest round trip); ApiError unless the server is up."""
        await self._call("GET", f"{self.http_url}/healthz")

    async def aclose(self) -> None:
        if self._http is not None:
            await self._http.aclose()
            self._http = None

    async def __aenter__(self) -> SessionApi:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()


def parsed_answer(model: type[R], answer: Any, call: str) -> R:
    """An answer parsed by its protocol model (`app.protocol.parse_record`); ApiError naming
    the call and the wrong field if it does not fit."""
    try:
        return parse_record(model, answer)
    except InputError as exc:
        raise ApiError(f"{call}: a malformed answer: {exc}") from exc


def _query_params(
    text: str | None,
    k: int,
    include: str | None = None,
    from_xyz: Sequence[float] | None = None,
    rerank: bool = False,
) -> dict[str, Any]:
    """A query's parameters; text None for a spoken question (its text is in the audio)."""
    # Points left out: the device and the viewer already hold the geometry they need.
    params: dict[str, Any] = {} if text is None else {"text": text}
    params.update(k=k, points="false")
    if include is not None:
        params["include"] = include
    if from_xyz is not None:
        # repr: the shortest text that reads back as the same float, so the server places
        # the asker exactly where the device's own answer does
        params["from"] = ",".join(repr(float(v)) for v in from_xyz)
    if rerank:
        params["rerank"] = "true"
    return params


def _result(answer: Any) -> dict:
    """A query answer, parsed by the protocol, as a dict with hits without points."""
    try:
        result = parse_query_result(answer)
    except InputError as exc:
        raise ApiError(f"a malformed query answer: {exc}") from exc
    return result.model_dump(exclude={"results": {"__all__": {"points"}}})


def _spoken_result(answer: Any, call: str) -> dict:
    """A spoken question's answer: `_result` of its query part, with what was heard
    (`SpokenQueryResult`: transcript, confidence, asr_ms)."""
    heard = parsed_answer(SpokenQueryResult, answer, call)
    return {
        **_result(answer),
        "transcript": heard.transcript,
        "confidence": heard.confidence,
        "asr_ms": heard.asr_ms,
    }
