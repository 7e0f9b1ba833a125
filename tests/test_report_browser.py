"""The HTML reports rendered in a real browser (headless Debian Chromium driven by Playwright): every
figure loaded from the file itself, the tables present. Screenshots are kept in ``test-artifacts/``."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from vtol_impedance.cli import main

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARTIFACTS = Path(__file__).resolve().parent.parent / "test-artifacts"

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/run)")


def _render(report: Path, shot: Path) -> dict:
    from playwright.sync_api import sync_playwright

    flags = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", "--no-first-run", "--disable-quic"]  # fmt: skip
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=flags)
        try:
            page = browser.new_page()
            requests: list[str] = []
            page.on("request", lambda r: requests.append(r.url))
            page.goto(report.as_uri())
            page.wait_for_load_state("load")
            info = page.evaluate(
                """() => ({
                    images: [...document.images].map(i => ({ok: i.complete && i.naturalWidth > 100, alt: i.alt})),
                    tables: [...document.querySelectorAll('table')].map(t => t.rows.length),
                    headings: [...document.querySelectorAll('h2')].map(h => h.textContent),
                })"""
            )
            ARTIFACTS.mkdir(exist_ok=True)
            page.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    info["requests"] = requests
    return info


def _self_contained(report: Path, info: dict) -> None:
    # moved away from its folder, the page still shows everything: nothing is loaded but the file itself
    assert info["requests"] == [report.as_uri()]
    assert info["images"] and all(i["ok"] for i in info["images"]), info["images"]
    assert "Versions and seed" in info["headings"]


def test_run_report_renders(tmp_path):
    out = tmp_path / "run"
    assert main(["compare", "case-a-payload", "--duration", "2", "--out", str(out), "--quiet"]) == 0
    alone = tmp_path / "mailed" / "report.html"
    alone.parent.mkdir()
    shutil.copy(out / "report.html", alone)
    info = _render(alone, ARTIFACTS / "report-compare.png")
    _self_contained(alone, info)
    assert len(info["images"]) == 6  # errors, inputs, wrench; the margins: Bode, Nyquist, poles
    assert info["tables"][0] == 4  # header + PD, PID, PD+C


def test_estimate_report_renders(tmp_path):
    import synthflight as S

    fl = S.flight(duration=6.0)
    cols = {"t_s": fl.t, "vx": fl.v_W[:, 0], "vy": fl.v_W[:, 1], "vz": fl.v_W[:, 2], "roll": fl.eta[:, 0],
            "pitch": fl.eta[:, 1], "yaw": fl.eta[:, 2], "wx": fl.omega_B[:, 0], "wy": fl.omega_B[:, 1],
            "wz": fl.omega_B[:, 2], "thrust_n": fl.thrust}  # fmt: skip
    log = tmp_path / "flight.csv"
    np.savetxt(log, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
    out = tmp_path / "est"
    assert (
        main(["estimate", str(log), "--vehicle", "pelican", "--quiet-segment", "2,4", "--out", str(out), "--quiet"])
        == 0
    )
    info = _render(out / "report.html", ARTIFACTS / "report-estimate.png")
    _self_contained(out / "report.html", info)
    assert len(info["images"]) == 2
    assert any("Bias" in h for h in info["headings"]) and all(n >= 2 for n in info["tables"])
