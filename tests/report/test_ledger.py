"""The docs' published numbers: the README's results table is what the ledger of recorded runs renders; no process talk."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from torchrl_mbe.report.ledger import render_results_table, render_seeds_table

REPO = Path(__file__).resolve().parents[2]
LEDGER = REPO / "docs" / "runs"
MARKERS = ("<!-- ledger: results table -->", "<!-- /ledger -->")
SEEDS_MARKERS = ("<!-- ledger: seeds table -->", "<!-- /ledger -->")
PROCESS_TALK = re.compile(r"worktree|\bsession\b|\bof mine\b|machine time|\bthe issue\b|issue's", re.IGNORECASE)


def test_the_readme_results_table_is_the_one_the_ledger_renders():
    readme = (REPO / "README.md").read_text()
    start, end = readme.index(MARKERS[0]) + len(MARKERS[0]), readme.index(MARKERS[1])
    assert readme[start:end].strip() == render_results_table(LEDGER), (
        "README.md's results table differs from the ledger; paste `python -m torchrl_mbe.report.ledger docs/runs`"
    )


def test_the_results_pages_seed_by_seed_table_is_the_one_the_ledger_renders():
    results = (REPO / "docs" / "results.md").read_text()
    start, end = results.index(SEEDS_MARKERS[0]) + len(SEEDS_MARKERS[0]), results.index(SEEDS_MARKERS[1])
    assert results[start:end].strip() == render_seeds_table(LEDGER), (
        "docs/results.md's seed table differs from the ledger; paste `python -m torchrl_mbe.report.ledger docs/runs --seeds`"
    )


def test_every_ledger_run_records_its_commit_machine_and_command():
    summaries = list(LEDGER.rglob("summary.json"))
    assert summaries
    for path in summaries:
        record = json.loads(path.read_text())["record"]
        assert len(record["commit"]) == 40 and record["cpu"] and record["cores"] >= 1, path
        assert record["command"].startswith("python train.py"), path


@pytest.mark.parametrize(
    "doc", sorted(p.relative_to(REPO).as_posix() for p in [REPO / "README.md", *REPO.glob("docs/**/*.md")])
)
def test_the_docs_say_what_was_measured_not_how_the_work_was_organized(doc):
    found = [line for line in (REPO / doc).read_text().splitlines() if PROCESS_TALK.search(line)]
    assert not found, f"{doc}: {found[:3]}"
