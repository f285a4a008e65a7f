# Two commands on a fresh machine: `make demo` and `make test`. Everything installs from pyproject.toml.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.radarcal-installed
export MPLBACKEND := Agg
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: demo test test-slow lint bench install sysdeps clean notebooks

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@touch $(STAMP)

install: $(STAMP) sysdeps

# open3d's wheel links libusb-1.0, which a bare Debian image lacks ("libusb-1.0.so.0: cannot open shared object
# file"). Install it with apt when we can (root + apt-get), otherwise say what is missing.
sysdeps:
	@ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing libusb-1.0-0 (needed by open3d)"; \
	    apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 || { apt-get update -qq >/dev/null && apt-get install -y -qq libusb-1.0-0 >/dev/null; }; \
	  else echo "warning: libusb-1.0 is missing; open3d will not import (apt-get install libusb-1.0-0)"; fi; }
	@# the browser tests of the operator pages (radarcal run --ui, field-pnp --ui) drive Debian's headless Chromium
	@{ command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; } || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium chromium-driver (browser tests of the console pages)"; \
	    apt-get install -y -qq chromium chromium-driver >/dev/null 2>&1 || { apt-get update -qq >/dev/null && apt-get install -y -qq chromium chromium-driver >/dev/null; } \
	      || echo "warning: could not install chromium chromium-driver; the browser tests will skip"; \
	  else echo "warning: chromium/chromedriver missing; the browser tests will skip (apt-get install chromium chromium-driver)"; fi; }

demo: $(STAMP) sysdeps
	$(PY) -m radarcal.demo

test: $(STAMP) sysdeps
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check .

test-slow: $(STAMP) sysdeps
	$(PY) -m pytest -q -m slow

# The report notebooks: installs Jupyter (JupyterLab to open them) and executes each one headless into build/notebooks/
# (the same command as docs/report.md; set RADARCAL_REPORT_BUNDLE=calib.yaml to report on your own bundle).
notebooks: $(STAMP) sysdeps
	$(PY) -m pip install -q -e '.[notebooks]'
	@mkdir -p build/notebooks
	for nb in notebooks/*.ipynb; do $(VENV)/bin/jupyter nbconvert --to html --execute "$$nb" --output-dir build/notebooks || exit 1; done

bench: $(STAMP) sysdeps
	$(PY) -m benchmarks

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
