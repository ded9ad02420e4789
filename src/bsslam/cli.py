"""The ``bsslam`` command line: thin verbs over library functions."""

from __future__ import annotations

import contextlib
import json
import logging
from enum import Enum
from pathlib import Path
from typing import Iterator, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from bsslam.errors import BsslamError, ConfigError

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="BS-SLAM: EKF SLAM with B-spline map features for 2D laser range finders.")
experiment_app = typer.Typer(no_args_is_help=True, help="Reproduce the paper's experiments.")
app.add_typer(experiment_app, name="experiment")
console = Console(stderr=True)

OUT_HELP = "Results folder: files go to DIR/<timestamp>/ and DIR/latest points at them."


_compile_hint_shown = False


@contextlib.contextmanager
def progress_bar(description: str, total: int | None, unit: str = "") -> Iterator:
    """A rich progress bar; yields ``update(done, total)`` for library callbacks. Before the
    first bar of a machine's first run, says why it will wait at the start."""
    global _compile_hint_shown
    if not _compile_hint_shown:
        _compile_hint_shown = True
        from bsslam.compiled import needs_compiling
        from bsslam.slam.range_kernels import linearize_beams   # one of the filter's kernels

        if needs_compiling(linearize_beams):
            console.print("[dim]first run on this machine: compiling the inner loops "
                          "(about a minute; cached for the next runs)[/dim]")
    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn()]
    with Progress(*columns, console=console) as bar:
        task = bar.add_task(description, total=total, rate="")

        def update(done: int, total_: int | None = None) -> None:
            elapsed = bar.tasks[0].elapsed or 0.0
            rate = f"{done / elapsed:.1f} {unit}/s" if unit and elapsed > 0 else ""
            bar.update(task, completed=done, total=total_ if total_ is not None else total, rate=rate)

        def restart(description_: str, total_: int | None) -> None:
            bar.reset(task, total=total_, description=description_)

        update.restart = restart  # type: ignore[attr-defined]
        yield update


def next_phase(update, description: str):
    """A progress callback that, on its first call, turns ``update``'s bar into a new phase."""
    started = False

    def progress(done: int, total: int | None) -> None:
        nonlocal started
        if not started:
            update.restart(description, total)
            started = True
        update(done, total)

    return progress


def fail(exc: Exception) -> None:
    # unwrapped and unparsed: the message names files and lines, which must stay whole (and
    # copyable) whatever the terminal width, and a "[…]" in a path is not rich markup
    console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)
    raise typer.Exit(2)


def print_summary(summary: dict, title: str) -> None:
    table = Table(title=title, show_header=False)
    for key, value in summary.items():
        if isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items()) or "-"
        table.add_row(key, str(value))
    Console().print(table)


def _load_config(config_file: Optional[Path]):
    from bsslam.config import SLAMConfig
    from bsslam.io.config_file import load_config

    return load_config(config_file) if config_file else SLAMConfig()


@app.callback()
def main(verbose: bool = typer.Option(False, "--verbose", "-v", help="Log details to stderr.")) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")


# --------------------------------------------------------------------------------------
@app.command()
def simulate(
    world: str = typer.Option("rounded-room", help="Built-in world (see --list)."),
    seed: int = typer.Option(0, help="Random seed of the simulated noise."),
    steps: Optional[int] = typer.Option(None, help="Number of scans (default: the whole double loop)."),
    out: Path = typer.Option(Path("results/simulate"), help=OUT_HELP),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML configuration of the filter."),
    list_worlds: bool = typer.Option(False, "--list", help="List the built-in worlds and exit."),
) -> None:
    """One SLAM run in a simulated world with exact ground truth."""
    from bsslam.experiments.consistency import simulation_config
    from bsslam.io.results import make_run_dir
    from bsslam.outputs import write_outputs
    from bsslam.pipeline import run_dataset
    from bsslam.sim import WORLDS, SimConfig, get_world, simulate as simulate_world

    if list_worlds:
        for name, w in WORLDS.items():
            typer.echo(f"{name:15s} {w.description}")
        return
    try:
        sim = SimConfig()
        config = simulation_config(_load_config(config_file), sim)
        data = simulate_world(get_world(world), sim, seed=seed, steps=steps)
        run_dir = make_run_dir(out)
        with progress_bar(f"SLAM in {world}", len(data.ground_truth), "scans") as update:
            result = run_dataset(data, config, progress=update, total=len(data.ground_truth))
        summary = write_outputs(result, run_dir, config, walls=data.world.polylines(0.02),
                                exact_reference=True, title=f"BS-SLAM in the simulated world '{world}' (seed {seed})")
    except BsslamError as exc:
        fail(exc)
    print_summary(summary, f"bsslam simulate --world {world}")
    console.print(f"results in [bold]{run_dir}[/bold] (map picture: {run_dir / 'map.png'})")


@app.command()
def run(
    log: Path = typer.Argument(..., help="CARMEN log (.clf/.log), ROS 1 bag (.bag) or ROS 2 bag folder."),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML configuration of the filter."),
    out: Path = typer.Option(Path("results/run"), help=OUT_HELP),
    mode: Optional[str] = typer.Option(None, help="slam (default) or localization."),
    fmt: Optional[str] = typer.Option(None, "--format", help="carmen, ros1 or ros2 (default: from the path)."),
    strict: bool = typer.Option(False, help="Stop at the first bad input line instead of skipping it."),
    steps: Optional[int] = typer.Option(None, help="Process only the first N scans."),
    reference: Optional[Path] = typer.Option(None, help="Reference trajectory (TUM or 't x y θ') for ATE."),
    scan_topic: Optional[str] = typer.Option(None, help="ROS: LaserScan topic (default: auto)."),
    odom_topic: Optional[str] = typer.Option(None, help="ROS: Odometry topic (default: auto, else /tf)."),
) -> None:
    """Run BS-SLAM on a laser log and write trajectory, map, grid and pictures."""
    from bsslam.io import open_dataset
    from bsslam.io.results import make_run_dir
    from bsslam.io.trajectory_file import read_trajectory
    from bsslam.outputs import write_outputs
    from bsslam.pipeline import run_dataset

    try:
        if steps is not None and steps < 1:
            raise ConfigError(f"--steps must be ≥ 1, got {steps}")
        config = _load_config(config_file)
        if mode is not None:
            config = config.replace(mode=mode)
        data = open_dataset(log, format=fmt, strict=strict, scan_topic=scan_topic, odom_topic=odom_topic)
        ref = read_trajectory(reference) if reference else None
        run_dir = make_run_dir(out)
        with progress_bar(f"{log.name}", steps, "scans") as update:
            result = run_dataset(data, config, steps=steps, progress=update, total=steps,
                                 relocalize_progress=next_phase(update, f"{log.name}: relocalising"))
        summary = write_outputs(result, run_dir, config, reference=ref, title=f"BS-SLAM: {log.name}")
    except BsslamError as exc:
        fail(exc)
    print_summary(summary, f"bsslam run {log}")
    if result.skipped.total:
        console.print(f"[yellow]skipped {result.skipped.total} input item(s):[/yellow] "
                      + ", ".join(f"{k}: {v}" for k, v in result.skipped.counts.items()))
        for ex in result.skipped.examples[:5]:
            console.print(f"  {ex}")
    console.print(f"results in [bold]{run_dir}[/bold]")


@app.command()
def evaluate(
    estimate: Path = typer.Argument(..., help="Estimated trajectory (TUM or 't x y θ')."),
    reference: Path = typer.Argument(..., help="Reference trajectory (TUM or 't x y θ')."),
    relations: Optional[Path] = typer.Option(None, help="Kümmerle et al. relations file."),
    offset: float = typer.Option(0.0, help="Seconds to subtract from the relations' timestamps."),
    max_dt: float = typer.Option(0.05, help="Largest timestamp difference when matching poses (s)."),
    exact: bool = typer.Option(False, help="The reference is exact ground truth: also report NEES."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """ATE, RPE, the relations metric and NEES of a trajectory against a reference."""
    from bsslam.eval import evaluate_files

    try:
        metrics = evaluate_files(estimate, reference, relations_path=relations, offset=offset,
                                 max_dt=max_dt, exact_reference=exact)
    except BsslamError as exc:
        fail(exc)
    if as_json:
        typer.echo(json.dumps(metrics, indent=2))
    else:
        print_summary(metrics, f"{estimate} vs {reference}")


@app.command()
def bench(
    data: Path = typer.Option(Path("../shared/data"), help="Folder searched for *.clf logs (with *.gt.txt references)."),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML configuration (the same for every log)."),
    steps: Optional[int] = typer.Option(None, help="Only the first N scans of each log."),
    mode: Optional[str] = typer.Option(None, help="slam or localization (default: the configuration's)."),
) -> None:
    """Accuracy and speed on every log of a data folder, one configuration for all."""
    from bsslam.bench import bench_log, find_logs

    logs = find_logs(data)
    if not logs:
        fail(BsslamError(f"no *.clf logs under {data}"))
    try:
        config = _load_config(config_file)
        if mode is not None:
            config = config.replace(mode=mode)
    except BsslamError as exc:
        fail(exc)
    table = Table("log", "scans", "wall s", "ms/scan", "splines", "max state", "ATE m", "online ATE m",
                  "odometry ATE m", "front end ATE m", "relations (Intel)", title=f"bsslam bench ({config.mode})")
    for log in logs:
        try:
            with progress_bar(log.name, steps, "scans") as update:
                row = bench_log(log, config, steps=steps, progress=update,
                                relocalize_progress=next_phase(update, f"{log.name}: relocalising"))
        except BsslamError as exc:
            console.print(f"[red]{log}: {exc}[/red]")
            continue
        table.add_row(row.log, str(row.scans), f"{row.wall_s:.1f}", f"{row.ms_per_scan:.1f}", str(row.splines),
                      str(row.state_size), f"{row.ate_m:.3f}", f"{row.online_ate_m:.3f}", f"{row.odometry_ate_m:.3f}", f"{row.frontend_ate_m:.3f}",
                      row.relations)
    Console(width=max(Console().width, 150)).print(table)
    console.print(f"peak memory (max RSS) of this process: {row.peak_rss_mb:.0f} MB")


# --------------------------------------------------------------------------------------
def _fit_experiment(kind: str, runs: int, seed: int, resolution_deg: float, sigma: float, out: Path) -> None:
    """Shared body of fit-knots and fit-order: run, write CSV + PNG, print the table."""
    from bsslam.experiments import fit
    from bsslam.io.results import make_run_dir

    experiment, writer, column, title = {
        "knots": (fit.fit_knots_experiment, fit.write_fit_knots, "knot spacing (m)", "Fit error vs knot spacing (cubic)"),
        "order": (fit.fit_order_experiment, fit.write_fit_order, "order", "Fit error vs order (knot spacing 2.92 m)"),
    }[kind]
    run_dir = make_run_dir(out)
    with progress_bar(f"fit vs {kind}", None, "runs") as update:
        results = experiment(runs=runs, seed=seed, resolution_deg=resolution_deg, sigma_m=sigma, progress=update)
    writer(results, run_dir, seed=seed, resolution_deg=resolution_deg, sigma_m=sigma)
    table = Table(column, "MSE (m²)", title=title)
    for value, mse in results:
        table.add_row(f"{value:.3g}", f"{mse:.3e}")
    Console().print(table)
    console.print(f"results in [bold]{run_dir}[/bold]")


@experiment_app.command("fit-knots")
def fit_knots(runs: int = typer.Option(50, help="Monte Carlo runs per spacing."),
              seed: int = typer.Option(0),
              resolution_deg: float = typer.Option(1.0, help="Angle between beams (deg)."),
              sigma: float = typer.Option(0.005, help="Range noise σ (m)."),
              out: Path = typer.Option(Path("results/fit-knots"), help=OUT_HELP)) -> None:
    """Paper Fig. 2: mean squared range error of a cubic fit vs. knot spacing."""
    _fit_experiment("knots", runs, seed, resolution_deg, sigma, out)


@experiment_app.command("fit-order")
def fit_order(runs: int = typer.Option(50, help="Monte Carlo runs per order."),
              seed: int = typer.Option(0),
              resolution_deg: float = typer.Option(1.0, help="Angle between beams (deg)."),
              sigma: float = typer.Option(0.005, help="Range noise σ (m)."),
              out: Path = typer.Option(Path("results/fit-order"), help=OUT_HELP)) -> None:
    """Paper Fig. 3: mean squared range error of linear, quadratic and cubic fits."""
    _fit_experiment("order", runs, seed, resolution_deg, sigma, out)


class Variant(str, Enum):
    no_extension = "no-extension"
    inflated_r = "inflated-r"
    extension = "extension"


@experiment_app.command("consistency")
def consistency(variant: Variant = typer.Option(..., help="Which filter variant."),
                runs: int = typer.Option(50, help="Monte Carlo runs."), seed: int = typer.Option(0),
                world: str = typer.Option("rounded-room", help="Simulated world."),
                steps: Optional[int] = typer.Option(None, help="Steps per run (default: the double loop)."),
                workers: Optional[int] = typer.Option(None, help="Processes (default: every core)."),
                out: Path = typer.Option(Path("results/consistency"), help=OUT_HELP)) -> None:
    """Paper Figs. 10/12: average pose NEES over Monte Carlo runs with the 95% χ² band."""
    from bsslam.experiments.consistency import consistency_experiment, write_consistency
    from bsslam.io.results import make_run_dir

    try:
        run_dir = make_run_dir(out)
        with progress_bar(f"consistency ({variant.value})", runs, "runs") as update:
            res = consistency_experiment(variant.value, runs=runs, seed=seed, world=world, steps=steps,
                                         workers=workers, progress=update)
        write_consistency(res, run_dir)
    except BsslamError as exc:
        fail(exc)
    exit_step = res.first_exit()
    print_summary({
        "variant": res.variant, "world": res.world, "runs": runs, "steps": int(res.mean_nees.size),
        "band": f"[{res.lower:.2f}, {res.upper:.2f}]",
        "fraction of steps inside band": f"{res.fraction_inside():.2f}",
        "leaves band (optimistic) at step": exit_step if exit_step is not None else "never",
    }, "NEES consistency")
    console.print(f"results in [bold]{run_dir}[/bold]")


@experiment_app.command("heading-gain")
def heading_gain(runs: int = typer.Option(50, help="Monte Carlo runs per initial σ."),
                 updates: int = typer.Option(30, help="Scans per run."), seed: int = typer.Option(0),
                 workers: Optional[int] = typer.Option(None, help="Processes (default: every core)."),
                 out: Path = typer.Option(Path("results/heading-gain"), help=OUT_HELP)) -> None:
    """Paper Fig. 11: estimated heading σ of a stationary robot over updates."""
    from bsslam.experiments.heading import DEFAULT_SIGMAS_RAD, heading_gain_experiment, write_heading_gain
    from bsslam.io.results import make_run_dir

    run_dir = make_run_dir(out)
    with progress_bar("heading gain", runs * len(DEFAULT_SIGMAS_RAD), "runs") as update:
        res = heading_gain_experiment(runs=runs, updates=updates, seed=seed, workers=workers, progress=update)
    write_heading_gain(res, run_dir)
    table = Table("σ₀ (rad)", "σ_φ after 1 update", f"σ_φ after {updates}", title="Heading information gain")
    for s0, sig in res.items():
        table.add_row(f"{s0:g}", f"{sig[0]:.4g}", f"{sig[-1]:.4g}")
    Console().print(table)
    console.print(f"results in [bold]{run_dir}[/bold]")


if __name__ == "__main__":  # pragma: no cover
    app()
