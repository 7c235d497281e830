"""The user documentation describes the project as it is: no commit hashes, dates or run
history (those live in commit messages, the design records and the results ledger), a
sim-to-real page a user can read through, and an accuracy table that matches the ledger."""

import re
from pathlib import Path

import pytest

from benchmarks.sim2real_accuracy import CURRENT_ROUNDS, END, START, accuracy_table

ROOT = Path(__file__).resolve().parents[1]
USER_DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
HASH = re.compile(r"`(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}`")
DATE = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")


@pytest.mark.parametrize("path", USER_DOCS, ids=lambda p: p.name)
def test_user_docs_hold_no_commit_hashes_or_dates(path):
    text = path.read_text()
    assert HASH.findall(text) == [], f"{path.name} names commits"
    assert DATE.findall(text) == [], f"{path.name} holds dates"


def test_the_patterns_catch_what_they_are_for():
    assert HASH.findall("at `f89b587` and `1ca9e16`") == ["`f89b587`", "`1ca9e16`"]
    assert HASH.findall("`1000000` frames, `defaced` and `-1e-4`") == []
    assert DATE.findall("on 2026-12-01, not 2026-13-40") == ["2026-12-01"]


def test_the_sim2real_page_is_short_enough_to_read_through():
    assert len((ROOT / "docs" / "sim2real.md").read_text().splitlines()) < 260


def test_the_accuracy_table_is_what_the_ledger_gives():
    page = (ROOT / "docs" / "sim2real.md").read_text()
    shown = page.split(START, 1)[1].split(END, 1)[0].strip()
    assert shown == accuracy_table(list(CURRENT_ROUNDS)).strip()
