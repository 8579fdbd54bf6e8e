"""The README says what the code does: every setting listed, the library example runs (from
outside the repository) and shows advice being given, a screenshot of every page shown."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from app.domain.building import Building, U
from app.service.config import Settings
from tests.browser.screenshots import PAGES, TARGET
from tests.domain.test_building import TEXT as BUILDING_TEXT

README = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")


def test_readme_lists_every_setting() -> None:
    listed = set(re.findall(r"`ADVISOR_([A-Z0-9_]+)`", README))
    missing = sorted(n.upper() for n in Settings.model_fields if n.upper() not in listed)
    assert not missing, f"README.md does not list ADVISOR_{missing}"


def test_readme_library_example_runs_outside_the_repository_and_advises(tmp_path: Path) -> None:
    section = README.split("## The library", 1)[1]
    code = section.split("```python", 1)[1].split("```", 1)[0]
    run = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    first, second = run.stdout.splitlines()
    assert first == "False"
    advise, kl, p_normal, advice = second.split(" ", 3)
    assert advise == "True" and float(kl) >= 0.5 and float(p_normal) < 0.5
    shown = re.search(r"# True ([\d.]+) ([\d.]+)", code)
    assert shown is not None and (shown.group(1), shown.group(2)) == (kl, p_normal)
    assert advice.startswith("(0.0119")


def test_readme_shows_a_screenshot_of_every_page() -> None:
    """Each page's screenshot (``make screenshots`` copies them from the browser tests' run)
    is a PNG in docs/screenshots/ that the README's "Pages" section shows, and nothing else
    is kept there."""
    pages = README.split("## Pages", 1)[1].split("\n## ", 1)[0]
    shown = re.findall(r"!\[[^\]]*\]\(docs/screenshots/([\w.-]+)\.png\)", pages)
    assert shown == list(PAGES)
    for name in PAGES:
        assert (TARGET / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    assert sorted(p.stem for p in TARGET.iterdir()) == sorted(PAGES)


def test_readme_map_of_several_floors_is_the_one_the_tests_read() -> None:
    """The README's example of a map of several floors is a map, the tests' own, and what the
    README says of it holds."""
    section = README.split("**Buildings of several floors.**", 1)[1]
    text = section.split("```\n", 1)[1].split("```", 1)[0].rstrip("\n")
    assert text == BUILDING_TEXT
    b = Building.from_text(text)
    assert b.to_text() == text
    basement, first = b.state(0, 1, 1), b.state(2, 1, 1)
    assert b.step(b.step(basement, U), U) == first  # "two U"
    assert b.durations[basement, U] + b.durations[b.step(basement, U), U] == 10
