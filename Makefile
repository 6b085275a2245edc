# The two commands of the README: `make demo` and `make test`. Both set up .venv when needed.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.lfd-installed
# Extra pytest arguments, e.g. `make test PYTEST_ARGS="-m slow"`.
PYTEST_ARGS ?=

.PHONY: demo test test-all lint bench clean-venv

$(STAMP): setup.py constraints.txt lfd/__init__.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	# torch first, pinned: a CPU build on this machine; nothing may pull a CUDA build afterwards.
	$(PY) -m pip install --disable-pip-version-check -q -c constraints.txt torch==2.13.0
	# the distribution was called lfd before it became lfd-landmarks (the name lfd on PyPI is another project's)
	$(PY) -m pip uninstall --disable-pip-version-check -q -y lfd 2>/dev/null || true
	$(PY) -m pip install --disable-pip-version-check -q -c constraints.txt -e ".[sim,test,ray,ros]"
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m sim.demo_job

# on every core (pytest-xdist), a test module per worker so that its fixtures are built once
XDIST := -n auto --dist loadfile

test: lint
	$(PY) -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS)

test-all: lint
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS)

# ruff on both packages, the scripts and the benchmarks, mypy on the library (ruff.toml, mypy.ini)
lint: $(STAMP)
	$(PY) -m ruff check lfd sim benchmarks train.py plan.py setup.py
	$(PY) -m mypy lfd

bench: $(STAMP)
	$(PY) benchmarks/collision.py
	$(PY) benchmarks/learning.py
	$(PY) benchmarks/planning.py
	$(PY) benchmarks/reaction.py --task powder

clean-venv:
	rm -rf $(VENV)
