"""``python -m torchrl_mbe.report RUNS_DIR``."""

from torchrl_mbe.report.cli import main

main()
