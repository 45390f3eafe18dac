# The two commands of the README. Each installs what it needs first (idempotently).
.PHONY: demo test install lint docs

install:
	@scripts/install.sh

demo: install
	.venv/bin/python demos/esl_cantilever.py --out results/esl_cantilever

test: install
	.venv/bin/python -m pytest tests

lint: install
	.venv/bin/ruff check .

# The documentation site, warnings as errors; the tutorials are executed. HTML: docs/_build/html/
docs: install
	.venv/bin/python -m sphinx -b html -n -W --keep-going docs docs/_build/html
	@echo "docs: open docs/_build/html/index.html"
