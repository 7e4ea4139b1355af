"""The report: figures and tables from finished runs (``python -m torchrl_mbe.report RUNS_DIR``)."""

from torchrl_mbe.report.cli import main
from torchrl_mbe.report.runs import Run, RunFormatError, load_runs
from torchrl_mbe.report.tables import write_report

__all__ = ["Run", "RunFormatError", "load_runs", "main", "write_report"]
