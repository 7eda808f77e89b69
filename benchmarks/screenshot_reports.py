"""Open the run and sweep reports in headless Chromium and save screenshots.

    .venv/bin/python benchmarks/screenshot_reports.py [SWEEP_DIR] [-o OUT_DIR]

With SWEEP_DIR (a `slamlab -m` sweep), screenshots that sweep's report and its first run's
report (building them if missing); without it, a 12-run sweep is fabricated
(tests/report_fixtures.py). Prints the PNG paths. Needs `chromium` (apt-get install chromium).
"""

from __future__ import annotations

import argparse
import html as html_lib
import json
import re
import shutil
import subprocess
import sys
import tempfile
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_browser() -> str | None:
    """The first headless-capable Chromium on PATH, or None."""
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def _chromium(args: list[str], timeout_s: float) -> subprocess.CompletedProcess:
    """Headless Chromium with no network and a throwaway profile (flags: docs of this machine)."""
    browser = find_browser()
    if browser is None:
        raise RuntimeError("no Chromium found: apt-get install -y chromium")
    with tempfile.TemporaryDirectory(prefix="slamlab-chromium-") as profile:
        cmd = [
            browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={profile}", *args,
        ]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)


def screenshot(html: Path, png: Path, width: int = 1400, height: int = 2000, timeout_s: float = 60.0) -> Path:
    """Render a local HTML file with headless Chromium into a PNG of width x height px."""
    png.parent.mkdir(parents=True, exist_ok=True)
    proc = _chromium([f"--screenshot={png}", f"--window-size={width},{height}", "--hide-scrollbars",
                      Path(html).resolve().as_uri()], timeout_s)
    if proc.returncode != 0 or not png.is_file() or png.stat().st_size == 0:
        raise RuntimeError(f"chromium failed ({proc.returncode}) on {html}: {proc.stderr[-2000:]}")
    return png


# Runs in the page after every image has loaded (the load event): what a reader would see.
PAGE_FACTS_JS = """
function () {
  var imgs = Array.prototype.slice.call(document.images);
  return {
    height: Math.ceil(document.documentElement.scrollHeight),
    images: imgs.length,
    broken: imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); }).map(function (i) { return i.alt; }),
    sections: Array.prototype.map.call(document.querySelectorAll("section[id]"), function (s) { return s.id; }),
    section_images: Array.prototype.reduce.call(document.querySelectorAll("section[id]"), function (acc, s) {
      acc[s.id] = s.querySelectorAll("img").length; return acc; }, {}),
    image_sizes: imgs.map(function (i) { return [i.alt, i.naturalWidth, i.naturalHeight]; }),
    headers: Array.prototype.map.call(document.querySelectorAll("#runs-table thead th"), function (t) { return t.textContent.trim(); }),
    text: document.body.innerText
  };
}
"""


def page_facts(html: Path, width: int = 1400, script: str = PAGE_FACTS_JS, timeout_s: float = 90.0) -> dict:
    """Open `html` in headless Chromium, run `script` (a JS function returning JSON-able data)
    in the page once it has loaded, and return its result. The page is copied with the
    script appended; the original is not modified."""
    html = Path(html).resolve()
    page = html.read_text(encoding="utf-8")
    probe = ("<script>window.addEventListener('load', function () {"
             f" var r = ({script})(); var pre = document.createElement('pre'); pre.id = 'slamlab-facts';"
             " pre.textContent = JSON.stringify(r); document.documentElement.appendChild(pre); });</script>")
    with tempfile.TemporaryDirectory(prefix="slamlab-facts-") as tmp:
        copy = Path(tmp) / html.name
        copy.write_text(page.replace("</body>", probe + "</body>") if "</body>" in page else page + probe,
                        encoding="utf-8")
        proc = _chromium([f"--window-size={width},1000", "--virtual-time-budget=20000", "--dump-dom",
                          copy.as_uri()], timeout_s)
    found = re.search(r'<pre id="slamlab-facts">(.*?)</pre>', proc.stdout, re.S)
    if proc.returncode != 0 or found is None:
        raise RuntimeError(f"chromium gave no page facts ({proc.returncode}) for {html}: {proc.stderr[-2000:]}")
    return json.loads(html_lib.unescape(found.group(1)))


def full_page_screenshot(html: Path, png: Path, width: int = 1400) -> Path:
    """A screenshot of the whole page: its height measured in Chromium first."""
    return screenshot(Path(html), Path(png), width, max(800, int(page_facts(Path(html), width)["height"])))


def _fabricated_sweep(root: Path) -> Path:
    from report_fixtures import make_sweep, particles_seed_grid

    sweep = root / "multirun" / "fabricated"
    make_sweep(sweep, particles_seed_grid([5, 10, 20, 50], [0, 1, 2], ["dataset.duration_s=10"]),
               ["particles=5,10,20,50", "seed=0,1,2", "dataset.duration_s=10"], failures={4: "metrics"},
               texture=True)
    return sweep


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweep", nargs="?", type=Path, help="a sweep directory (default: fabricate one)")
    p.add_argument("-o", "--out", type=Path, default=None, help="where PNGs go (default reports/screenshots/<time>)")
    args = p.parse_args(argv)

    from slamlab.report import build_sweep_report, find_run_dirs, load_run, write_run_report

    out = args.out or ROOT / "reports" / "screenshots" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    with tempfile.TemporaryDirectory(prefix="slamlab-shots-") as tmp:
        sweep = args.sweep if args.sweep is not None else _fabricated_sweep(Path(tmp))
        runs = find_run_dirs([sweep])
        for r in runs:
            if not (r / "report.html").is_file():
                write_run_report(r)
        sweep_html = build_sweep_report([sweep], out / "sweep")  # never writes into the user's sweep
        shots = [
            screenshot(runs[0] / "report.html", out / "run_report.png", 1400, 2600),
            screenshot(sweep_html, out / "sweep_report_top.png", 1400, 1600),
            full_page_screenshot(sweep_html, out / "sweep_report_full.png", 1400),
        ]
        failed = [r for r in runs if not load_run(r).ok]
        if failed:
            shots.append(screenshot(failed[0] / "report.html", out / "failed_run_report.png", 1400, 1000))
    for s in shots:
        print(s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
