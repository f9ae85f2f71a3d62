"""Shared by the ground station's browser tests: Debian's chromium, headless, driven through chromedriver
by Selenium (marker ``browser``: tests/conftest.py skips them without chromium, chromedriver or selenium,
or fails them with ``VSCMG_HIL_REQUIRE_ALL=1``), and small helpers to read the page."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from typing import Any

CHROMIUM = os.environ.get("VSCMG_HIL_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("VSCMG_HIL_CHROMEDRIVER", "/usr/bin/chromedriver")
FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-sync",
    "--disable-background-networking", "--disable-component-update", "--window-size=1600,1000",
)  # fmt: skip


def chromium() -> Iterator[Any]:
    """A headless chromium session (a WebDriver) with its own profile, quit and removed afterwards: the body
    of a module-scoped fixture."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS:
        options.add_argument(flag)
    profile = tempfile.mkdtemp(prefix="gcs-chromium-")
    options.add_argument(f"--user-data-dir={profile}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    driver.set_script_timeout(15)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def js(driver: Any, script: str, *args: Any) -> Any:
    return driver.execute_script(script, *args)


def page_errors(driver: Any) -> list[str]:
    """The page's own errors in the browser's console (a refused ``/api/`` request is a test's doing)."""
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"
            and "/api/" not in e["message"]]  # fmt: skip


def text(driver: Any, element_id: str) -> str:
    from selenium.webdriver.common.by import By

    return str(driver.find_element(By.ID, element_id).text)
