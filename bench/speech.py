"""Ask aloud on the apartment: the map of an eval walk, served by a real server on loopback,
asked every paraphrase of every category in view, typed and spoken (espeak-ng, several
voices and speeds, posted as WAV to POST .../query/speech as curl posts it).

Prints every transcript with the spoken and typed top-1 category, then spoken vs typed
top-1 over the paraphrases and the time from the end of the upload to the answer (p50,
p95). `--asr whisper:DIR` runs the same with a Whisper folder (a tiny random one proves the
plumbing only: its transcripts are noise).

    python -m bench.speech                       # the embedded recogniser (pocketsphinx)
    python -m bench.speech --asr whisper:DIR     # Whisper weights in DIR
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from bench.common import bench_parser, check, machine, write_outputs

VOICES = (("en-us", 150), ("en-us+f3", 175), ("en-gb", 130), ("en-us+m3", 190))
"""espeak-ng voices and words per minute the questions are spoken in."""


def build_map(scene: str, frames: int, seed: int):
    """The semanticxr engine after the eval walk, and each object's true category."""
    from app.mapping.engine import MappingEngine, make_perception
    from app.semantics import get_text_encoder
    from evaluation.pipeline import map_keyframes
    from evaluation.semantic_scores import majority_gt_class
    from evaluation.walk import EvalConfig, encode_keyframes
    from world.gt import gt_point_cloud

    cfg = EvalConfig(scene=scene, frames=frames, seed=seed, modes=("semanticxr",))
    ratio = cfg.knobs.depth_downsampling_ratio
    messages, world, _, in_view, sightings = encode_keyframes(cfg, [ratio], print)
    engine = MappingEngine(
        get_text_encoder(), cfg.knobs, "semanticxr", backend=make_perception(mode="semanticxr")
    )
    map_keyframes(
        {"semanticxr": messages[ratio]},
        {"semanticxr": engine},
        print,
        sightings,
        {"semanticxr": ratio},
    )
    gt = gt_point_cloud(world)
    objects = engine.confirmed_objects()
    truth = majority_gt_class([o.points for o in objects], gt.points, gt.class_idx)
    category = {
        o.id: (gt.class_names[c] if c >= 0 else None) for o, c in zip(objects, truth, strict=True)
    }
    observed = [name for name in world.categories_present if in_view.get(name, 0) >= 8]
    return engine, category, observed


def export_body(engine) -> bytes:
    from app.mapping.export import export_json_chunks
    from app.protocol.rest import EXPORT_FORMAT, EXPORT_VERSION

    header = {
        "format": EXPORT_FORMAT,
        "version": EXPORT_VERSION,
        "session": {
            "name": "speech-bench",
            "mode": "semanticxr",
            "knobs": {},
            "embedding": {"model": engine.encoder.model_id, "dim": engine.encoder.dim},
        },
    }
    return b"".join(export_json_chunks(header, engine.confirmed_objects(), [], [], True))


def speak(text: str, voice: str, wpm: int, folder: Path) -> bytes:
    path = folder / "q.wav"
    subprocess.run(["espeak-ng", "-v", voice, "-s", str(wpm), "-w", str(path), text], check=True)
    return path.read_bytes()


def main() -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--asr", default="pocketsphinx")
    parser.add_argument("--scene", default="apartment")
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--voices", type=int, default=2, help="how many of VOICES")
    parser.add_argument("--out", default="out", help="folder of bench_speech.json")
    args = parser.parse_args()
    if shutil.which("espeak-ng") is None:
        print("bench.speech: needs Debian's espeak-ng (apt-get install espeak-ng)", file=sys.stderr)
        return 2

    from app.semantics import get_text_encoder
    from app.server.runner import ServerThread
    from app.server.settings import ServerSettings
    from world.categories import CATEGORIES

    engine, category, observed = build_map(args.scene, args.frames, args.seed)
    folder = Path(tempfile.mkdtemp(prefix="semanticxr-speech-"))
    settings = ServerSettings(
        port=0,
        data_dir=str(folder / "data"),
        asr=args.asr,
        asr_timeout_s=60,
        max_body_bytes=1 << 28,
    )
    server = ServerThread(settings, get_text_encoder()).start()
    rows, times_ms = [], []
    try:
        with httpx.Client(base_url=server.url, timeout=120) as http:
            created = http.post(
                "/v1/sessions/import",
                content=export_body(engine),
                headers={"Content-Type": "application/json"},
            )
            created.raise_for_status()
            sid = created.json()["session_id"]
            # the recogniser starts and builds this map's vocabulary: not timed
            http.post(
                f"/v1/sessions/{sid}/query/speech",
                content=speak("the sofa", *VOICES[0], folder),
                headers={"Content-Type": "audio/wav"},
            )
            for voice, wpm in VOICES[: args.voices]:
                for name in observed:
                    for text in CATEGORIES[name].paraphrases:
                        typed = http.get(
                            f"/v1/sessions/{sid}/query",
                            params={"text": text, "k": 1, "points": "false"},
                        ).json()
                        wav = speak(text, voice, wpm, folder)
                        t0 = time.perf_counter()
                        reply = http.post(
                            f"/v1/sessions/{sid}/query/speech",
                            content=wav,
                            params={"k": 1, "points": "false"},
                            headers={"Content-Type": "audio/wav"},
                        )
                        times_ms.append((time.perf_counter() - t0) * 1e3)
                        body = reply.json()
                        typed_top = (
                            category.get(typed["results"][0]["id"]) if typed["results"] else None
                        )
                        spoken_top = (
                            category.get(body["results"][0]["id"])
                            if reply.status_code == 200 and body["results"]
                            else None
                        )
                        transcript = body.get("transcript", f"[{reply.status_code}]")
                        rows.append(
                            {
                                "voice": f"{voice}@{wpm}",
                                "category": name,
                                "question": text,
                                "transcript": transcript,
                                "typed_top1": typed_top,
                                "spoken_top1": spoken_top,
                                "asr_ms": body.get("asr_ms"),
                            }
                        )
                        mark = "=" if spoken_top == typed_top else "x"
                        print(
                            f"{voice:>9}@{wpm} {mark} {text!r} -> {transcript!r}  "
                            f"spoken {spoken_top}, typed {typed_top}, expected {name}"
                        )
    finally:
        server.stop()
        shutil.rmtree(folder, ignore_errors=True)
    n = len(rows)
    typed_pct = 100 * sum(r["typed_top1"] == r["category"] for r in rows) / n
    spoken_pct = 100 * sum(r["spoken_top1"] == r["category"] for r in rows) / n
    p50, p95 = (float(p) for p in np.percentile(times_ms, [50, 95]))
    print(
        f"\n{n} spoken questions ({args.asr}, {args.voices} voices), {len(observed)} categories in view"
    )
    print(
        f"top-1: typed {typed_pct:.1f}%, spoken {spoken_pct:.1f}%; end of upload to answer p50 {p50:.0f} ms, p95 {p95:.0f} ms"
    )
    checks = [
        check("spoken top-1 behind typed", typed_pct - spoken_pct, "<=", 10, " points"),
        check("end of upload to answer p50", p50, "<=", 1000, " ms"),
    ]
    write_outputs(
        args.out,
        "bench_speech",
        {
            "machine": machine(),
            "asr": args.asr,
            "typed_top1": typed_pct,
            "spoken_top1": spoken_pct,
            "answer_ms": {"p50": p50, "p95": p95},
            "checks": [c | {"ok": bool(c["ok"])} for c in checks],
            "rows": rows,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
