# The two commands of the README (`make demo`, `make test`) create or refresh .venv themselves, with every
# extra (gui: the window, cluster: `kogei batch --dask`, dev: the tests); the stamp makes a changed
# pyproject.toml reinstall.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.kogei-installed
PYTEST_WORKERS ?= 2

.PHONY: venv test demo bench screenshots clean

$(STAMP): pyproject.toml scripts/ensure-system-deps.sh
	bash scripts/ensure-system-deps.sh
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,gui,cluster]'
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest -n $(PYTEST_WORKERS) -q

demo: $(STAMP)
	$(VENV)/bin/kogei demo --out out/demo

bench: $(STAMP)
	$(PY) -m pip install -q -e '.[bench]'
	$(PY) -m bench.run --out docs/BENCHMARKS.md
	$(PY) -m bench.unseen_figure --out docs/images/hawk-unseen.png

screenshots: $(STAMP)
	QT_QPA_PLATFORM=offscreen $(PY) -m bench.screenshots --out docs/screenshots
	QT_QPA_PLATFORM=offscreen $(PY) -m bench.screenshots --out docs/screenshots/1024x700 --size 1024x700

clean:
	rm -rf out .pytest_cache .hypothesis
