# The two commands of the README. Each installs what it needs first (idempotently).
.PHONY: demo test install lint

install:
	@scripts/install.sh

demo: install
	.venv/bin/python demos/esl_cantilever.py --out results/esl_cantilever

test: install
	.venv/bin/python -m pytest tests

lint: install
	.venv/bin/ruff check .
