"""``gatewaylab lesson`` (issue 14, "Learn"): each lesson's output is deterministic and equals its golden file;
the docs/teaching page of each lesson carries the same sequence diagram (mermaid)."""

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.cli.lessons import LESSONS, run_lesson

GOLDEN = Path(__file__).parent / "lessons"
DOCS = Path(__file__).resolve().parents[2] / "docs" / "teaching"


def told(name: str, mermaid: bool = False) -> str:
    lines: list[str] = []
    run_lesson(name, lines.append, mermaid=mermaid)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("name", sorted(LESSONS))
def test_lesson_matches_its_golden_file(name: str) -> None:
    """Same scenario, same simulated clock: the same text every run (regenerate a golden file with
    `gatewaylab lesson NAME > tests/canopen/lessons/NAME.txt` after a deliberate change, and read the diff)."""
    assert told(name) == (GOLDEN / f"{name}.txt").read_text()


@pytest.mark.parametrize("name", sorted(LESSONS))
def test_teaching_page_shows_the_lessons_diagram(name: str) -> None:
    """docs/teaching/NAME.md embeds the mermaid diagram `gatewaylab lesson NAME --mermaid` prints."""
    text = told(name, mermaid=True)
    diagram = text[text.index("sequenceDiagram"):]
    page = (DOCS / f"{name}.md").read_text()
    assert f"```mermaid\n{diagram}```" in page
    assert "## Exercises" in page


def test_lessons_tell_what_changed() -> None:
    """The lessons' point: each step says what changed in the node (CiA 301 NMT, CiA 305 LSS, CiA 402)."""
    assert "drive 2: NMT state: Pre-operational -> Operational" in told("nmt")
    lss = told("lss")
    assert "new drive: node-ID: unconfigured -> 4" in lss and "Fastscan: bit 31 of the serial is 0" in lss
    assert "drive 2: CiA 402 state: switched on -> operation enabled" in told("cia402")
    assert "drive 2: 0x1A01:01 Mapping entry 1: 0x" in told("pdo")


def test_cli_prints_the_same() -> None:
    """`gatewaylab lesson sdo` from a shell prints the golden text."""
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "lesson", "sdo"], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout == (GOLDEN / "sdo.txt").read_text()
