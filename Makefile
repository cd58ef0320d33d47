# Two entry points do all the set-up on a fresh machine (see README):
#   make demo   set up, then run the main job on the embedded synthetic scene
#   make test   set up, then run the whole test suite
.PHONY: setup demo eval test lint bench clean
PY := .venv/bin/python

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) -m app.cli demo

eval: setup
	$(PY) -m app.cli eval --scene apartment --json out/eval.json

test: setup
	$(PY) -m pytest -q

lint: setup
	.venv/bin/ruff check . && .venv/bin/ruff format --check .
	.venv/bin/lint-imports --no-cache

bench: setup
	$(PY) -m bench.mapping --out out
	$(PY) -m bench.server --out out
	$(PY) -m bench.device --out out
	$(PY) -m bench.local_map --out out
	$(PY) -m bench.xr_page --out out

clean:
	rm -rf .venv out .pytest_cache .hypothesis
