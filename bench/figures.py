"""Figures of ``bench/throughput.py``'s JSON: the app against the plain reference, and populations against single runs.

    python bench/figures.py bench/results/throughput-2026-11-23-1512.json   # its reference section
    python bench/figures.py bench/results/throughput-2026-12-02-0919.json   # its population section
    python bench/figures.py RESULT.json --out docs/figures                  # where the PNGs go (default: bench/results)

Each figure is named after the JSON file and the section (``<json stem>-reference.png``,
``<json stem>-population.png``), and its title carries the machine and commit the JSON
recorded. A section the JSON does not hold draws nothing.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

RESULTS_DIR = Path(__file__).parent / "results"


def reference_figure(result: dict) -> Figure | None:
    """Frames/s of ``train(cfg)`` and of the plain reference per variant, the ratio above each pair."""
    values = {m["name"]: m["value"] for m in result["measurements"] if m["section"] == "reference"}
    variants = sorted({name.split(": ")[0] for name in values})
    if not variants:
        return None
    figure = Figure(figsize=(7, 3.6), layout="constrained")
    axes = figure.subplots()
    for index, variant in enumerate(variants):
        app, plain = values[f"{variant}: train(cfg)"], values[f"{variant}: plain PyTorch reference"]
        axes.bar(index - 0.2, app, 0.4, color="tab:blue", label="train(cfg)" if index == 0 else None)
        axes.bar(index + 0.2, plain, 0.4, color="tab:gray", label="plain PyTorch reference" if index == 0 else None)
        axes.annotate(f"{app / plain:.2f}x", (index, max(app, plain)), ha="center", va="bottom", fontsize=9)
    axes.set_xticks(range(len(variants)), [variant.replace("N=", "envs=") for variant in variants])
    axes.set_ylabel("frames/s (one run, median of repeats)")
    axes.set_ylim(top=axes.get_ylim()[1] * 1.2)  # room for the ratios and the legend
    axes.legend(loc="upper right", fontsize=8)
    axes.set_title(f"train(cfg) against the plain reference\n{_machine(result)}", fontsize=9)
    return figure


def population_figure(result: dict) -> Figure | None:
    """``population=N``'s summed frames/s over N single runs', per env, against N."""
    pattern = re.compile(r"(\w+) N=(\d+): summed / N single runs")
    curves: dict[str, list[tuple[int, float]]] = {}
    for m in result["measurements"]:
        match = pattern.fullmatch(m["name"]) if m["section"] == "population" else None
        if match:
            curves.setdefault(match[1], []).append((int(match[2]), m["value"]))
    if not curves:
        return None
    figure = Figure(figsize=(6, 3.6), layout="constrained")
    axes = figure.subplots()
    for env, points in curves.items():
        sizes, ratios = zip(*sorted(points))
        axes.plot(sizes, ratios, marker="o", label=env)
    axes.axhline(1.0, color="black", linewidth=0.8, linestyle=":")
    axes.set_xscale("log")
    axes.set_xlabel("members N (population=N)")
    axes.set_ylabel("summed frames/s / N single runs")
    axes.legend(fontsize=8)
    axes.set_title(f"A population against its members run one by one\n{_machine(result)}", fontsize=9)
    return figure


def _machine(result: dict) -> str:
    machine = result["machine"]
    return f"{machine['cpu']}, {machine['nproc']} cores, commit {machine['git_commit']}, {result['date'][:10]}"


FIGURES = {"reference": reference_figure, "population": population_figure}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", nargs="+", type=Path, help="bench/throughput.py JSON files")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="folder for the PNGs (default: bench/results)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for path in args.results:
        result = json.loads(path.read_text())
        for section, draw in FIGURES.items():
            figure = draw(result)
            if figure is not None:
                out = args.out / f"{path.stem}-{section}.png"
                FigureCanvasAgg(figure).print_png(out)
                print(f"wrote {out}")


if __name__ == "__main__":
    main()
