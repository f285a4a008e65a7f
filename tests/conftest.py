"""Shared test fixtures. Real data sets are read from ../shared/datasets (never copied into the repo)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATASETS = Path(os.environ.get("RADARCAL_SHARED_DATASETS", REPO.parent / "shared" / "datasets"))


def shared_dataset(name: str) -> Path:
    """Path of ``../shared/datasets/<name>``; skips the test with a clear reason when it is absent."""
    path = SHARED_DATASETS / name
    if not path.is_dir():
        pytest.skip(f"real data set {name!r} not present at {path} (needs ../shared beside the repo)")
    return path


@pytest.fixture
def shared():
    return shared_dataset


@pytest.fixture
def browser(tmp_path):
    """A real headless Chromium (Debian's ``chromium`` + ``chromium-driver``) driven by selenium; skips with the reason
    when either is missing (``make`` installs them with apt when it can)."""
    import shutil

    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install -e '.[test]')")
    exe = next((p for p in ("/usr/bin/chromium", shutil.which("chromium") or "") if p and Path(p).exists()), None)
    drv = next((p for p in ("/usr/bin/chromedriver", shutil.which("chromedriver") or "") if p and Path(p).exists()), None)
    if exe is None or drv is None:
        pytest.skip("no headless Chromium + chromedriver (apt-get install chromium chromium-driver; `make` does it as root)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = exe
    for a in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
              "--disable-sync", "--no-first-run", "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'chromium-profile'}",
              "--window-size=1500,1100"):  # fmt: skip
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(drv), options=opts)
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def screenshot(tmp_path):
    """``screenshot(driver, name)``: a PNG of the page in ``tmp_path`` (and in ``$RADARCAL_SCREENSHOTS`` when set, to
    look at after the run); returns its path."""

    def take(driver, name: str) -> Path:
        out = tmp_path / f"{name}.png"
        driver.save_screenshot(str(out))
        keep = os.environ.get("RADARCAL_SCREENSHOTS")
        if keep:
            Path(keep).mkdir(parents=True, exist_ok=True)
            (Path(keep) / out.name).write_bytes(out.read_bytes())
        return out

    return take
