"""The docs' published numbers: the README's results table is what the ledger of recorded runs renders; no process talk."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from torchrl_mbe.report.ledger import (
    main,
    render_across_table,
    render_deepsea_table,
    render_explorers_table,
    render_results_table,
    render_seeds_table,
)

REPO = Path(__file__).resolve().parents[2]
LEDGER = REPO / "docs" / "runs"
PROCESS_TALK = re.compile(r"worktree|\bsession\b|\bof mine\b|machine time|\bthe issue\b|issue's", re.IGNORECASE)
RENDERED = [  # (doc, the table's name in its markers, what renders it, the command that prints it)
    ("README.md", "results table", render_results_table, "python -m torchrl_mbe.report.ledger docs/runs"),
    (
        "docs/results.md",
        "explorers table",
        render_explorers_table,
        "python -m torchrl_mbe.report.ledger docs/runs --explorers",
    ),
    ("docs/results.md", "seeds table", render_seeds_table, "python -m torchrl_mbe.report.ledger docs/runs --seeds"),
    ("docs/results.md", "across table", render_across_table, "python -m torchrl_mbe.report.ledger docs/runs --across"),
    (
        "docs/results.md",
        "deepsea table",
        render_deepsea_table,
        "python -m torchrl_mbe.report.ledger docs/runs --deepsea",
    ),
]


@pytest.mark.parametrize(("doc", "table", "render", "command"), RENDERED, ids=[row[1] for row in RENDERED])
def test_each_published_table_is_the_one_the_ledger_renders(doc, table, render, command):
    text = (REPO / doc).read_text()
    opening = f"<!-- ledger: {table} -->"
    start = text.index(opening) + len(opening)
    end = text.index("<!-- /ledger -->", start)
    assert text[start:end].strip() == render(LEDGER), f"{doc}'s {table} differs from the ledger; paste `{command}`"


@pytest.mark.parametrize("doc", sorted({row[0] for row in RENDERED}))
def test_every_table_of_the_results_pages_is_rendered_from_the_ledger(doc):
    typed, rendered = [], False
    for number, line in enumerate((REPO / doc).read_text().splitlines(), start=1):
        rendered = line.startswith("<!-- ledger:") or (rendered and not line.startswith("<!-- /ledger -->"))
        if line.startswith("|") and not rendered:
            typed.append(number)
    assert not typed, f"{doc}: a table typed by hand at lines {typed[:5]}; render it from docs/runs"


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


def test_runs_at_earlier_settings_stay_in_the_seed_table_and_out_of_the_readme(tmp_path):
    for folder, solved_at in (("now", 1000), ("before", None)):
        run = tmp_path / folder / "seed0"
        run.mkdir(parents=True)
        summary = {"method": "dqn+gaussian", "seed": 0, "solved": solved_at is not None, "solved_at_frames": solved_at,
                   "solved_at_wall_time_s": solved_at and 10, "final_eval_success_rate": 0.5,
                   "record": {"commit": "0" * 40, "command": "python train.py env=toy"}}  # fmt: skip
        (run / "summary.json").write_text(json.dumps(summary))
    entries = [
        {"task": "Toy-v0", "reward": "sparse", "runs": "now", "command": "python train.py env=toy"},
        {"task": "Toy-v0, before", "reward": "sparse", "runs": "before", "command": "-", "in_readme": False},
    ]
    (tmp_path / "ledger.json").write_text(json.dumps(entries))
    readme, seeds = render_results_table(tmp_path), render_seeds_table(tmp_path)
    assert "| Toy-v0 |" in readme and "Toy-v0, before" not in readme
    assert "| Toy-v0 |" in seeds and "| Toy-v0, before |" in seeds


@pytest.mark.parametrize(
    ("flag", "index"), [([], "ledger.json"), (["--explorers"], "explorers.json"), (["--deepsea"], "deepsea.json")]
)
def test_a_folder_without_the_ledgers_index_is_one_line_naming_it(tmp_path, capsys, flag, index):
    with pytest.raises(SystemExit):
        main([str(tmp_path), *flag])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{tmp_path / index} is missing" in error
