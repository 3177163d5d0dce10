"""What one page costs the tests' Chromium: CPU seconds of the browser's whole process tree (browser, renderers,
GPU and utility processes, the playwright driver) per page opened in a new context, as the tests open them.

Pages: an empty one, and one that loads plotly.js from the installed plotly package (as the reports and the
screen do); each with the browser as the tests launch it (``browser.launch_flags``: its omnibox popup WebUI
off) and with playwright's switches alone (``browser.FLAGS``).  Median of ``--pages`` pages each.

    python benchmarks/browser_page_cpu.py [--pages 6]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from browser import FLAGS, chromium_path, launch_flags
from proc_stat import TICK, process_stats


def tree_cpu_s(root: int) -> float:
    """CPU seconds of every process below ``root``, with what each has reaped of its own children."""
    children: dict[int, list[tuple[int, list[str]]]] = {}
    for pid, parent, fields in process_stats():
        children.setdefault(parent, []).append((pid, fields))
    total, stack = 0.0, [root]
    while stack:
        for pid, fields in children.get(stack.pop(), []):
            total += sum(int(x) for x in fields[11:15]) / TICK
            stack.append(pid)
    return total


def per_page(args: list[str], url: str, pages: int) -> float:
    from playwright.sync_api import sync_playwright

    costs = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=args)
        time.sleep(1.0)  # the browser's own start is not a page's
        for _ in range(pages):
            before = tree_cpu_s(os.getpid())
            page = browser.new_page()
            page.goto(url)
            page.wait_for_load_state("load")
            page.close()
            time.sleep(0.5)  # what the page left running (its renderer's exit) is the page's
            costs.append(tree_cpu_s(os.getpid()) - before)
        browser.close()
    return statistics.median(costs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pages", type=int, default=6)
    pages = parser.parse_args().pages
    from plotly.offline import get_plotlyjs

    with tempfile.TemporaryDirectory() as tmp:
        empty, plotly = Path(tmp) / "empty.html", Path(tmp) / "plotly.html"
        empty.write_text("<html><body>x</body></html>", encoding="utf-8")
        plotly.write_text(f"<html><head><script>{get_plotlyjs()}</script></head><body>x</body></html>",
                          encoding="utf-8")
        for name, path in (("empty page", empty), ("page with plotly.js", plotly)):
            quiet, plain = per_page(launch_flags(), path.as_uri(), pages), per_page(FLAGS, path.as_uri(), pages)
            print(f"{name:>20}: {quiet:.2f} CPU-s a page as the tests launch Chromium, {plain:.2f} with playwright's "
                  f"switches alone (median of {pages})")


if __name__ == "__main__":
    main()
