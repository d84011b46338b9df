"""Makes the run figures of docs/scenarios.md and the live map of docs/recording.md from real runs.

    python docs/figures/run_figures.py figures   # flies coverage, two_swarms, plume; copies their figures
    python docs/figures/run_figures.py web-map   # flies wildfire, opens `mrswarm gcs web` 40 s into the mission
                                                 # in headless Chromium (Playwright), saves the page

Each run goes into a temporary results folder; the PNGs go to docs/images/, reduced to 128 colours
(Pillow) so that they stay small. The web map is started late on purpose: its trails come from
the run folder's trajectories, so they begin at the start of the run all the same.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
IMAGES = ROOT / "docs" / "images"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]


def small_png(src: Path, dst: Path) -> None:
    from PIL import Image

    Image.open(src).convert("RGB").quantize(colors=128, method=Image.Quantize.FASTOCTREE,
                                            dither=Image.Dither.NONE).save(dst, optimize=True)
    print(f"{dst.relative_to(ROOT)}: {dst.stat().st_size // 1024} KB")


def run(scenario: str, out: Path, *sets: str) -> Path:
    args = [sys.executable, "-m", "mrswarm", "run", str(ROOT / "scenarios" / f"{scenario}.yaml"), "--out", str(out),
            "--no-live", *[a for s in sets for a in ("--set", s)]]
    subprocess.run(args, cwd=ROOT, check=False)
    (run_dir,) = [d for d in out.iterdir() if d.is_dir()]
    return run_dir


def figures() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in ("coverage", "two_swarms", "plume"):
            run_dir = run(scenario, Path(tmp) / scenario)
            small_png(run_dir / f"{scenario}.png", IMAGES / f"{scenario}.png")
            if scenario == "coverage":
                small_png(run_dir / "pose_age.png", IMAGES / "pose_age.png")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def web_map(after_s: float = 40.0) -> None:
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        runner = subprocess.Popen([sys.executable, "-m", "mrswarm", "run", str(ROOT / "scenarios" / "wildfire.yaml"),
                                   "--out", str(out), "--no-live"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
        try:
            assert runner.stdout is not None
            for line in runner.stdout:  # the mission's start, then `after_s` more
                if "start acknowledged" in line:
                    break
            time.sleep(after_s)
            (run_dir,) = [d for d in out.iterdir() if d.is_dir()]
            port = free_port()
            web = subprocess.Popen([sys.executable, "-m", "mrswarm", "gcs", "web", "--run", str(run_dir), "--port", str(port),
                                    "--duration", "60"], cwd=ROOT, stdout=subprocess.DEVNULL)
            try:
                time.sleep(4.0)
                with sync_playwright() as pw:
                    browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                    page = browser.new_page(viewport={"width": 1400, "height": 760})
                    page.goto(f"http://127.0.0.1:{port}/")
                    page.wait_for_timeout(4000)
                    page.evaluate("window.mrswarm.fit()")
                    page.wait_for_timeout(1000)
                    shot = out / "web-map.png"
                    page.screenshot(path=str(shot))
                    browser.close()
                small_png(shot, IMAGES / "web-map.png")
            finally:
                web.terminate()
                web.wait(15)
        finally:
            runner.terminate()
            runner.wait(120)
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "figures"
    {"figures": figures, "web-map": web_map}[what]()
