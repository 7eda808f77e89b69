"""Open the run and sweep reports in headless Chromium and save screenshots.

    .venv/bin/python benchmarks/screenshot_reports.py [SWEEP_DIR] [-o OUT_DIR]
    .venv/bin/python benchmarks/screenshot_reports.py --run RUN_DIR [-o OUT_DIR]

With SWEEP_DIR (a `slamlab -m` sweep), screenshots that sweep's report and its first run's
report (building them if missing); without it, a 12-run sweep is fabricated
(tests/report_fixtures.py). With --run, screenshots one run's report at full height
(`screenshot_full`). Prints the PNG paths. `page_check` asks a page, from inside Chromium,
whether its images decode and its replay works (used by the tests). Needs `chromium` (apt-get install chromium).
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
    """Render a local HTML file with headless Chromium (no network, throwaway profile) into a PNG."""
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


def screenshot_full(html: Path, png: Path, width: int = 1400, max_height: int = 16000, timeout_s: float = 120.0) -> Path:
    """A full-height screenshot: render tall, then cut the empty rows below the page's end."""
    from PIL import Image, ImageChops

    screenshot(html, png, width, max_height, timeout_s)
    with Image.open(png) as im:
        rgb = im.convert("RGB")
    bg = Image.new("RGB", rgb.size, rgb.getpixel((rgb.width - 1, rgb.height - 1)))
    bbox = ImageChops.difference(rgb, bg).getbbox()
    if bbox is not None:
        rgb.crop((0, 0, rgb.width, min(rgb.height, bbox[3] + 16))).save(png)
    return png


# Appended to a copy of the page: waits for every image (and the replay's frames) to decode,
# moves the replay slider, and writes what it found into the DOM for --dump-dom to return.
_CHECK_SCRIPT = """<script>
(async function () {
  // an image decoded when it finished loading with a size; wait for pending ones (up to 10 s)
  const loaded = (im) => (im.complete ? Promise.resolve() : new Promise((ok) => {
    im.addEventListener("load", ok); im.addEventListener("error", ok); setTimeout(ok, 10000); }))
    .then(() => im.naturalWidth > 0 && im.naturalHeight > 0);
  const res = {images: document.images.length, failed: []};
  try {
  await Promise.all([...document.images].map((im, i) => loaded(im).then((ok) => ok || res.failed.push(im.alt || String(i)))));
  const r = window.slamlabReplay;
  if (r) {
    res.replay_frames = r.count;
    await Promise.all(r.frames.map((im, i) => loaded(im).then((ok) => ok || res.failed.push("replay frame " + i))));
    const cv = document.getElementById("replay-canvas");
    r.show(0); const first = cv.toDataURL();
    r.show(r.count - 1); const last = cv.toDataURL();
    res.replay_changes = first !== last;
    res.replay_slider = document.getElementById("replay-slider") !== null;
  }
  res.sections = [...document.querySelectorAll("section[id]")].map((s) => s.id);
  } catch (e) { res.error = String(e); }
  const pre = document.createElement("pre"); pre.id = "slamlab-check"; pre.textContent = JSON.stringify(res);
  document.body.appendChild(pre);
})();
</script>"""


def page_check(html: Path, timeout_s: float = 120.0) -> dict:
    """Open a copy of `html` in headless Chromium with a checking script and return its
    findings: `images` (count), `failed` (images that did not decode), `sections` (ids),
    and for a replay `replay_frames`, `replay_slider`, `replay_changes` (the canvas differs
    between the first and last snapshot)."""
    text = Path(html).read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory(prefix="slamlab-check-") as tmp:
        page = Path(tmp) / "page.html"
        page.write_text(text.replace("</body>", _CHECK_SCRIPT + "</body>"), encoding="utf-8")
        proc = _chromium(["--virtual-time-budget=20000", "--dump-dom", page.as_uri()], timeout_s)
    start = proc.stdout.find('<pre id="slamlab-check">')
    if start < 0:
        raise RuntimeError(f"the page check did not finish on {html}: {proc.stderr[-2000:]}")
    end = proc.stdout.index("</pre>", start)
    return json.loads(html_lib.unescape(proc.stdout[start + len('<pre id="slamlab-check">'):end]))


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
    p.add_argument("--run", type=Path, default=None, help="screenshot this run's report.html at full height instead")
    p.add_argument("-o", "--out", type=Path, default=None, help="where PNGs go (default reports/screenshots/<time>)")
    args = p.parse_args(argv)

    from slamlab.report import build_sweep_report, find_run_dirs, load_run, write_run_report

    out = args.out or ROOT / "reports" / "screenshots" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    if args.run is not None:
        html = args.run / "report.html"
        if not html.is_file():
            html = write_run_report(args.run)
        print(screenshot_full(html, out / f"run_{args.run.name}.png"))
        return 0
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
