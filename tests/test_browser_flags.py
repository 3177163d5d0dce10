"""The tests' browser itself: Debian's Chromium as playwright starts it, with what :mod:`browser` turns off
beside playwright's own switches, and nothing of playwright's lost on the way."""

from __future__ import annotations

import os
from pathlib import Path

from browser import QUIET_FEATURES, playwright_disabled_features


def descendants(pid: int) -> list[Path]:
    """The /proc entries of every process below ``pid``."""
    children: dict[int, list[Path]] = {}
    for entry in Path("/proc").iterdir():
        try:
            parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(parent, []).append(entry)
    found, stack = [], [pid]
    while stack:
        for entry in children.get(stack.pop(), []):
            found.append(entry)
            stack.append(int(entry.name))
    return found


def browser_disabled_features() -> set[str]:
    """The features this process's Chromium disables, as it passes them to its child processes (their
    command lines carry the browser's effective ``--disable-features``)."""
    found: set[str] = set()
    for entry in descendants(os.getpid()):
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if "--type=" in command:
            for word in command.split():
                if word.startswith("--disable-features="):
                    found |= set(word.split("=", 1)[1].split(","))
    return found


def test_the_browser_opens_no_omnibox_popup_page_and_keeps_playwright_s_disabled_features(session_chromium):
    page = session_chromium.new_page()
    try:
        page.goto("about:blank")
        cdp = session_chromium.new_browser_cdp_session()
        try:
            targets = cdp.send("Target.getTargets")["targetInfos"]
        finally:
            cdp.detach()
        assert not [t["url"] for t in targets if "omnibox" in t["url"]]
        theirs = playwright_disabled_features()
        assert "PaintHolding" in theirs and "HttpsUpgrades" in theirs  # read from playwright's driver
        assert set(theirs) | set(QUIET_FEATURES) <= browser_disabled_features()
    finally:
        page.close()
