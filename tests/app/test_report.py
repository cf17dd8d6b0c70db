"""`kogei report`: one self-contained HTML file; it renders in headless Chromium with no broken image;
sections without data say what is missing and which command produces it; tampered products are
reported, never shown.

Checks: every image is a data URI that decodes to a PNG (Pillow, independently of the report code);
Chromium loads the file and an inline script counts images whose ``naturalWidth`` is 0 -- the same
check on a deliberately corrupted copy must count one, so the check can fail.
"""

from __future__ import annotations

import base64
import hashlib
import io
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from PIL import Image

from app.batch.runner import process_one
from app.batch.steps import BatchOptions
from app.cli import main
from app.report.html import build_report, write_report
from app.session import Session
from tests.app.batch_session import built_sessions, copy_session

SECTIONS = ("Object and plan", "Capture log", "Scanner calibration", "Registration and pose graph", "Mesh views",
            "Coverage and filled holes", "Colour chart", "Spectra with uncertainty vs model spectra",
            "Material map and confidences", "Renders under D65 and A", "Timing of every step")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    base = built_sessions(tmp_path_factory)
    tmp = tmp_path_factory.mktemp("report")
    processed = copy_session(base.raw, tmp / "processed")
    r = process_one(str(processed), ("geometry", "colour", "render"),
                    BatchOptions(preset="draft", calibration=str(base.cal), render_size=(96, 72)))
    assert r.status == "ok", r
    return base, processed


def _images(html: str) -> list[str]:
    return re.findall(r"<img src='([^']*)'", html)


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("Chromium is not installed (scripts/ensure-system-deps.sh installs it)")
    return exe


_PROBE = ("<script>window.addEventListener('load', () => {const imgs = [...document.images];"
          "document.body.setAttribute('data-images', imgs.length);"
          "document.body.setAttribute('data-broken', imgs.filter(i => !i.complete || i.naturalWidth === 0).length);"
          "});</script>")


def _chromium_counts(html_file: Path, tmp: Path) -> tuple[int, int]:
    """(images, broken images) after Chromium loaded the file."""
    probe = tmp / f"probe-{html_file.name}"
    probe.write_text(html_file.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    out = subprocess.run(
        [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp / 'chromium-profile'}", "--virtual-time-budget=10000", "--dump-dom",
         probe.as_uri()], capture_output=True, text=True, timeout=120)
    m = re.search(r'<body[^>]*data-images="(\d+)"[^>]*data-broken="(\d+)"', out.stdout)
    assert m, f"Chromium did not run the probe: {out.stderr[-2000:]}"
    return int(m.group(1)), int(m.group(2))


def test_report_is_self_contained_and_renders_in_chromium(sessions, tmp_path):
    _, processed = sessions
    out = write_report(processed, tmp_path / "report.html")
    html = out.read_text(encoding="utf-8")
    for title in SECTIONS:
        assert f"<h2>{title}</h2>" in html
    # nothing outside the file: no links to files or the network, every image inline
    assert not re.search(r"(src|href)=['\"](?!data:|#)", html)
    images = _images(html)
    # calibration, pose graph, 3 mesh views, coverage, holes, chart overlay, patch errors, 2 renders, timing
    assert len(images) == 12
    for uri in images:
        assert uri.startswith("data:image/png;base64,")
        img = Image.open(io.BytesIO(base64.b64decode(uri.split(",", 1)[1])))
        img.load()
        assert img.format == "PNG" and min(img.size) >= 50
    shown, broken = _chromium_counts(out, tmp_path)
    assert (shown, broken) == (12, 0)
    # the same check catches a broken image
    bad = tmp_path / "bad.html"
    bad.write_text(html.replace(images[0], "data:image/png;base64,AAAA"), encoding="utf-8")
    assert _chromium_counts(bad, tmp_path) == (12, 1)


def test_report_of_an_unprocessed_session_says_what_is_missing(sessions):
    base, _ = sessions
    html = build_report(base.raw)
    assert "<h1>hawk head (test)</h1>" in html and "T-1" in html      # the object's metadata
    for what, command in [("no scanner calibration", "kogei calibrate CAL_SESSION --sphere-radius MM"),
                          ("no registration", f"kogei process {base.raw} --calibration CAL_SESSION"),
                          ("no mesh", f"kogei process {base.raw}"),
                          ("no renders", f"kogei batch {base.raw} --steps render")]:
        assert f"<b>Not in this session:</b> {what}" in html and command in html
    assert "<b>Not in this session:</b> chart detection" in html
    assert "p01/chart" in html                       # the chart frame that was captured is listed
    # the capture log: 24 profiles of pass 1, one chart frame, one RAW frame
    assert re.search(r"<td>pass 1</td><td>complete</td><td>1</td><td>1</td><td>24</td><td>1</td>", html)


def test_tampered_product_is_reported_not_shown(sessions, tmp_path):
    _, processed = sessions
    s = copy_session(processed, tmp_path / "s")
    png = s / "products/renders/A.png"
    png.write_bytes(png.read_bytes()[:-10])
    html = build_report(s)
    assert "<h2>Problems found</h2>" in html
    assert "products/renders/A.png does not match its checksum" in html
    assert "alt='render under D65'" in html and "alt='render under A'" not in html


def test_an_unreadable_product_costs_only_its_section(sessions, tmp_path):
    _, processed = sessions
    s = copy_session(processed, tmp_path / "s")
    with Session.open(s) as session:      # a process report of another layout, checksummed as if genuine
        info = session.write_file("products/process-report.json", b'{"passes": []}')
        products = dict(session.manifest["products"])
        products["process_report"] = {"file": info.path, "sha256": info.sha256, "bytes": info.bytes}
        session.update("products", products)
    html = build_report(s)
    assert "<b>Could not be shown:</b> Registration and pose graph: the session&#x27;s data could not be shown " \
           "(KeyError: &#x27;registration&#x27;)" in html
    assert "<h2>Problems found</h2>" in html
    assert "alt='render under A'" in html and "alt='mesh front'" in html      # the other sections are there


def test_default_report_is_recorded_in_the_session(sessions, tmp_path, capsys):
    _, processed = sessions
    s = copy_session(processed, tmp_path / "s")
    assert main(["report", str(s)]) == 0
    path = Path(capsys.readouterr().out.strip())
    assert path == s / "products/report.html"
    rec = Session.read(s)["products"]["report"]
    assert rec["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("args, message", [
    (["--out", "report.txt"], "must end in .html"),
])
def test_bad_report_arguments(sessions, args, message, capsys):
    _, processed = sessions
    assert main(["report", str(processed), *args]) == 2
    assert message in capsys.readouterr().err


def test_report_of_a_missing_session_is_a_one_line_error(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "is not a kogei session" in err and err.count("\n") == 1
