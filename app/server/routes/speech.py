"""Ask aloud: `POST /v1/sessions/{sid}/query/speech`, a spoken question answered as the typed
one (docs/protocol.md, "Spoken questions").

The caller is authorised before the body is read; the audio then goes to a recogniser
worker process (`app.speech.RecogniserPool`), which decodes it, measures it and hears it
with a vocabulary shaped by the session's labels; the transcript is answered by the same
code as `GET .../query?text=` (relations and the living map included).
"""

from __future__ import annotations

import time

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from app import protocol
from app.server.routes.depends import Manager
from app.server.routes.rest import (
    ROUTER_ERRORS,
    SESSION_ERRORS,
    QueryFrom,
    QueryInclude,
    QueryK,
    QueryPoints,
    QueryRerank,
    _errors,
    answer_query,
    checked_query_options,
    session_in_use,
)
from app.server.sessions import SessionManager
from app.speech import (
    AUDIO_TYPES,
    MAX_SPEECH_S,
    AudioError,
    RecogniserPool,
    RecognisersBusy,
    audio_type,
)

BUSY_RETRY_AFTER_S = 1
"""Retry-After (seconds) of a 503 when every recogniser is busy or one was restarted."""

router = APIRouter(prefix="/v1", responses=ROUTER_ERRORS)

AUDIO_BODY = {
    "requestBody": {
        "required": True,
        "description": "the recorded question, as MediaRecorder or a WAV writer makes it "
        f"(at most {MAX_SPEECH_S:g} s; `;codecs=` and other parameters are ignored)",
        "content": {
            mime: {"schema": {"type": "string", "format": "binary"}} for mime in AUDIO_TYPES
        },
    }
}
SPEECH_ERRORS = SESSION_ERRORS | _errors(
    _400="the body is empty, or not audio of its Content-Type",
    _413="the audio is over the server's max_audio_bytes (--max-audio-bytes)",
    _415="a Content-Type other than audio/wav, audio/webm, audio/ogg or audio/mp4",
    _422=f"a query parameter of the wrong type or out of range, audio over {MAX_SPEECH_S:g} s "
    "(measured by decoding), or no speech recognised in it",
    _503="every speech recogniser is busy, or one took over --asr-timeout-s and was restarted "
    "(see Retry-After); or the session is not in memory and there is no room to load it now",
)


def speech_pool(request: Request) -> RecogniserPool:
    return request.app.state.speech


def _session_labels(manager: SessionManager, request: Request, sid: str) -> list[str]:
    """The caller's session's labels (present objects), after its credentials are checked
    (HTTPException otherwise, as for every session call)."""
    with session_in_use(manager, request, sid) as session:
        return sorted({o.label for o in session.objects()})


def _answer(manager, request, sid, text, k, points, include, asker, rerank) -> protocol.QueryResult:
    with session_in_use(manager, request, sid) as session:
        teacher = manager.encoder if rerank else None
        return answer_query(manager, session, text, k, points, include, asker, teacher)


@router.post(
    "/sessions/{sid}/query/speech",
    response_model=protocol.SpokenQueryResult,
    summary="Spoken question: the audio is the body; answered as the typed query of its transcript",
    responses=SPEECH_ERRORS,
    openapi_extra=AUDIO_BODY,
)
async def query_speech(
    sid: str,
    request: Request,
    manager: Manager,
    k: QueryK = 5,
    points: QueryPoints = True,
    include: QueryInclude = None,
    from_: QueryFrom = None,
    rerank: QueryRerank = False,
) -> protocol.SpokenQueryResult | Response:
    asker = checked_query_options(manager, k, from_)
    labels = await run_in_threadpool(_session_labels, manager, request, sid)  # auth before the body
    content_type = request.headers.get("content-type")
    try:
        audio_type(content_type)  # 415 before reading the body
    except AudioError as exc:
        raise HTTPException(exc.status, str(exc)) from None
    try:
        data = await request.body()
    except ClientDisconnect:  # over --max-audio-bytes: the 413 has gone out
        return Response(status_code=413)
    if not data:
        raise HTTPException(400, "the body is empty: send the recorded audio as the request body")
    t0 = time.perf_counter()
    try:
        heard = await run_in_threadpool(speech_pool(request).transcribe, data, content_type, labels)
    except AudioError as exc:
        raise HTTPException(exc.status, str(exc)) from None
    except RecognisersBusy as exc:
        raise HTTPException(
            503, str(exc), headers={"Retry-After": str(BUSY_RETRY_AFTER_S)}
        ) from None
    asr_ms = (time.perf_counter() - t0) * 1e3
    text = heard.text.strip()[: protocol.MAX_QUERY_CHARS]
    if not text:
        raise HTTPException(
            422,
            f"no speech recognised in {heard.duration_s:.1f} s of audio: ask again, closer to "
            "the microphone",
        )
    result = await run_in_threadpool(
        _answer, manager, request, sid, text, k, points, include, asker, rerank
    )
    return protocol.SpokenQueryResult(
        **dict(result), transcript=text, confidence=heard.confidence, asr_ms=asr_ms
    )
