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

# Two workers: most tests wait on servers, sockets and browsers, so the suite takes ~16 min
# on two cores instead of ~21; every cluster test goes to one worker (one Ray head).
test: setup
	$(PY) -m pytest -q -n 2 --dist loadgroup

lint: setup
	.venv/bin/ruff check . && .venv/bin/ruff format --check .
	.venv/bin/lint-imports --no-cache

# Every bench but bench.scale, which needs a PostgreSQL server and Ray (its --store is a
# postgresql:// URL; see README "Development"). A bench that misses a target exits non-zero:
# the others still run, and the ones that missed or failed are listed at the end.
BENCHES := mapping server device local_map xr_page load perception relations \
	relations_device relevance speech

bench: setup
	@failed=""; for name in $(BENCHES); do \
		echo "== bench.$$name"; \
		$(PY) -m bench.$$name --out out || failed="$$failed $$name"; \
	done; \
	if [ -n "$$failed" ]; then echo "missed a target or failed:$$failed"; exit 1; fi

clean:
	rm -rf .venv out .pytest_cache .hypothesis
