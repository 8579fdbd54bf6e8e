"""The screenshots of every page in docs/screenshots/, which README.md shows ("Pages").

The browser tests take them (``screenshot(page, name)`` in tests/browser/conftest.py writes
``test-artifacts/<name>.png``); this runs those tests and copies the pages' screenshots that the
run wrote into docs/screenshots/. ``make test`` writes into test-artifacts/ only.

    .venv/bin/python -m tests.browser.screenshots              # make screenshots
    .venv/bin/python -m tests.browser.screenshots --copy-only  # after a run of tests/browser
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts"
TARGET = ROOT / "docs" / "screenshots"

#: Each page's screenshot (test-artifacts/<name>.png) and what it shows, as README.md says.
PAGES: dict[str, str] = {
    "dashboard": "The dashboard (/) with the operator key: figures per domain and live "
    "sessions, a legend of the bars and lines, a unit under each heading",
    "dashboard-beliefs": "The dashboard's sessions as their strategies read them, plain words "
    "first: a paper session that looks lost in red (P(M2|H)), a guide session leading a lost "
    "visitor in amber (P(lost|H)), the destination its advice leads to by name",
    "dashboard-read-only": "The dashboard with the read-only operator key: End disabled, its "
    "tooltip saying why (with the admin key the session ends)",
    "walk-advised": "/walk after a lost-looking walk: what the advisor believes in plain words "
    "(the paper's symbols beside them), the advice at the walker's cell, its worth against "
    "its price kappa, P(M1|H) after each move, what the maze shows",
    "walk-guide-128": "/walk on a generated 128 x 128 building, the guide strategy leading a "
    "walker who follows its advice to a destination",
    "walk-big-map": "/walk on a generated 141 x 162 building with named destinations: the map "
    "scrolls and zooms in its own box, the panel stays in view, labels stay readable, the "
    "destination the advice leads to named",
    "walk-floors-lift": "/walk in a building of two floors: the walker's floor, at the lift "
    "the advice in words (take the lift up) and its share on a violet tag, PageUp to ride",
    "viewer": "The 3D viewer: the prior's arrows, the kappa shading, live sessions' paths, "
    "markers and advice, what the picked session's advisor believes in plain words, and its "
    "P(M1|H) over time",
    "viewer-legend": "The viewer's legend, at the foot of its panel",
    "viewer-floors": "The 3D viewer on a generated hospital of two floors: the floors stacked "
    "at their heights, the stairs (zigzag) and lifts (straight) between them, destinations "
    "labelled by name on their floors, an explorer on each floor, the floor filter",
    "viewer-floors-upstairs": "The same hospital's upper floor alone (the floor filter), "
    "from above: its explorer's path and the advice it was given",
    "docs": "/docs, the API's Swagger UI, served offline",
    "redoc": "/redoc, the same API in ReDoc, served offline",
}


def copy(since: float | None = None) -> list[Path]:
    """Copy every page's screenshot into docs/screenshots/; refuse one that is missing or (with
    ``since``, a time.time()) older than the run that should have made it."""
    problems = []
    for name in PAGES:
        source = ARTIFACTS / f"{name}.png"
        if not source.exists():
            problems.append(f"{source.relative_to(ROOT)} is missing")
        elif since is not None and source.stat().st_mtime < since:
            problems.append(f"{source.relative_to(ROOT)} was not written by this run")
    if problems:
        raise SystemExit("no screenshots copied: " + "; ".join(problems))
    TARGET.mkdir(parents=True, exist_ok=True)
    copied = []
    for name in PAGES:
        target = TARGET / f"{name}.png"
        shutil.copyfile(ARTIFACTS / f"{name}.png", target)
        copied.append(target)
    return copied


def main() -> None:
    parser = argparse.ArgumentParser(description="Copy every page's screenshot into docs/.")
    parser.add_argument("--copy-only", action="store_true", help="copy, do not run the tests")
    args = parser.parse_args()
    since = None
    if not args.copy_only:
        since = time.time()
        run = [sys.executable, "-m", "pytest", "tests/browser", "-q", "-p", "no:cacheprovider"]
        if subprocess.run(run, cwd=ROOT, check=False).returncode != 0:
            raise SystemExit("the browser tests failed: no screenshots copied")
    for path in copy(since):
        print(path.relative_to(ROOT))


if __name__ == "__main__":
    main()
