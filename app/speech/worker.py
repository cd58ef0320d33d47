"""A recogniser worker process: `python -m app.speech.worker FD KIND [MODEL_DIR]`, started by
`pool.RecogniserPool`, serving questions on the connection at file descriptor FD until it
closes. Decoding (FFmpeg) and recognising (PocketSphinx holds the GIL) happen here, never in
the server's process.
"""

from __future__ import annotations

import sys
from multiprocessing.connection import Connection

from app.speech.audio import AudioError, decode_audio
from app.speech.recognisers import AsrChoice, Recogniser


def load_recogniser(choice: AsrChoice) -> Recogniser:
    """The recogniser of a checked choice, loaded (in the worker process that runs it)."""
    if choice.kind == "whisper":
        from app.speech.whisper import WhisperRecogniser

        return WhisperRecogniser(choice.model_dir or "")
    from app.speech.sphinx import SphinxRecogniser

    return SphinxRecogniser()


def serve(conn: Connection, choice: AsrChoice) -> None:
    """A worker's loop: (audio bytes, content type, labels) -> ("ok", text, confidence,
    duration_s) or ("error", status, message). The recogniser loads on the first question."""
    recogniser = None
    while True:
        try:
            data, content_type, labels = conn.recv()
        except (EOFError, OSError):
            return
        try:
            audio = decode_audio(data, content_type)
            if recogniser is None:
                recogniser = load_recogniser(choice)
            heard = recogniser.transcribe(audio.samples, labels)
            conn.send(("ok", heard.text, heard.confidence, audio.duration_s))
        except AudioError as exc:
            conn.send(("error", exc.status, str(exc)))


if __name__ == "__main__":
    serve(Connection(int(sys.argv[1])), AsrChoice(sys.argv[2], (sys.argv[3:] or [None])[0]))
