"""The recogniser pool: worker processes that decode a question's audio and transcribe it.

PocketSphinx holds the GIL while it decodes, and FFmpeg parses what the network sent, so
both run in their own processes: a question never stalls the server's other requests, and
a crash or a hang costs one worker, not the server. Workers start on the first question
(`python -m app.speech.worker`, a fresh interpreter: the server has threads, and however it
was started) and load their recogniser then; each
question has a hard time limit, past which its worker is killed and replaced. When every
worker is busy a question waits at most BUSY_WAIT_S, then is refused (`RecognisersBusy`:
the route answers 503 with Retry-After).
"""

from __future__ import annotations

import logging
import queue
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection

from app.speech.audio import AudioError
from app.speech.recognisers import AsrChoice

log = logging.getLogger("semanticxr.speech")

BUSY_WAIT_S = 0.5
"""How long a question waits for a free worker before it is refused."""


class RecognisersBusy(RuntimeError):
    """No worker could take the question now (all busy, or the last one timed out or
    crashed): try again in a moment."""


@dataclass(frozen=True)
class Heard:
    text: str
    confidence: float | None
    duration_s: float
    """Seconds of audio decoded."""


class RecogniserPool:
    """`workers` processes running the recogniser `choice`; `transcribe` is thread-safe."""

    def __init__(self, choice: AsrChoice, workers: int, timeout_s: float):
        self.choice, self.timeout_s = choice, timeout_s
        self._idle: queue.Queue[_Worker] = queue.Queue()
        for _ in range(workers):
            self._idle.put(_Worker(choice))
        self._all: list[_Worker] = list(self._idle.queue)
        self._lock = threading.Lock()

    def transcribe(self, data: bytes, content_type: str, labels: Sequence[str]) -> Heard:
        """The question in `data` heard by a worker. AudioError (the status it answers) for
        audio that is not a question; RecognisersBusy when no worker is free within
        BUSY_WAIT_S, or the worker took over `timeout_s` or died (it is replaced)."""
        try:
            worker = self._idle.get(timeout=BUSY_WAIT_S)
        except queue.Empty:
            raise RecognisersBusy(
                f"every speech recogniser is busy ({len(self._all)}, --asr-workers): "
                "ask again in a moment"
            ) from None
        try:
            reply = worker.ask((data, content_type, list(labels)), self.timeout_s)
        except _WorkerLost as exc:
            replacement = _Worker(self.choice)
            with self._lock:
                self._all[self._all.index(worker)] = replacement
            worker, reply = replacement, None
            raise RecognisersBusy(str(exc)) from None
        finally:
            self._idle.put(worker)
        if reply[0] == "error":
            raise AudioError(reply[1], reply[2])
        _, text, confidence, duration_s = reply
        return Heard(text, confidence, duration_s)

    def close(self) -> None:
        with self._lock:
            for worker in self._all:
                worker.stop()


class _WorkerLost(RuntimeError):
    pass


class _Worker:
    """One recogniser process, started on its first question."""

    def __init__(self, choice: AsrChoice):
        self.choice = choice
        self.process: subprocess.Popen | None = None
        self.conn: Connection | None = None

    def ask(self, request: tuple, timeout_s: float) -> tuple:
        if self.process is None or self.process.poll() is not None:
            self.stop()
            self._start()
        assert self.conn is not None
        t0 = time.perf_counter()
        try:
            self.conn.send(request)
            if self.conn.poll(timeout_s):
                return self.conn.recv()
        except (EOFError, OSError) as exc:
            self.stop()
            raise _WorkerLost(f"the speech recogniser stopped ({exc}); ask again") from None
        self.stop()
        log.warning(
            "speech recogniser killed after %.1f s on one question", time.perf_counter() - t0
        )
        raise _WorkerLost(
            f"recognising took over {timeout_s:g} s (--asr-timeout-s); the recogniser was "
            "restarted: ask again, or ask a shorter question"
        )

    def _start(self) -> None:
        parent, child = socket.socketpair()
        command = [sys.executable, "-m", "app.speech.worker", str(child.fileno()), self.choice.kind]
        self.process = subprocess.Popen(
            [*command, *([self.choice.model_dir] if self.choice.model_dir else [])],
            pass_fds=[child.fileno()],
            stdin=subprocess.DEVNULL,
        )
        child.close()
        self.conn = Connection(parent.detach())

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(5)
        if self.conn is not None:
            self.conn.close()
        self.process = self.conn = None
